# Two commands on a fresh machine: `make demo` and `make test`.
SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.installed
DEMO_DIR ?= demo_out

.PHONY: install system-deps demo test lint typecheck pytest bench clean

install: $(STAMP)

# open3d needs libusb at import time; the browser test needs Chromium and its driver. All from Debian.
SYSTEM_PACKAGES := libusb-1.0-0 chromium chromium-driver
system-deps:
	@missing=""; for p in $(SYSTEM_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	  echo "installing system packages:$$missing"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null \
	    || echo "note: could not install$$missing (the browser test will skip without Chromium)"; \
	else echo "note: cannot apt-get; install$$missing (libusb-1.0-0 is required by open3d)"; fi

$(STAMP): pyproject.toml | system-deps
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "$(PYTHON) not found"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip wheel setuptools
	# The CPU build of torch first: a loose requirement would pull several GB of CUDA packages.
	$(PIP) install -q torch==2.13.0
	# Ray (the scale extra) too, so that the tests cover the distributed path.
	$(PIP) install -q -e '.[dev,scale]'
	# av2-api, the reference readers the tests compare against; its readers' imports are in [dev].
	$(PIP) install -q --no-deps av2==0.3.6
	# trackeval, behind av2's scenario-mining evaluator (`eval-mining`); --no-deps for the same reason.
	$(PIP) install -q --no-deps trackeval==1.3.0
	touch $(STAMP)

demo: install
	$(VENV)/bin/scenesearch demo --out $(DEMO_DIR)

lint: install
	$(VENV)/bin/ruff check .

typecheck: install
	$(VENV)/bin/mypy

pytest: install
	$(VENV)/bin/pytest

test: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy
	$(VENV)/bin/pytest

bench: install
	$(PY) -m benchmarks.run --out benchmarks/results.json

clean:
	rm -rf $(VENV) build *.egg-info .mypy_cache .ruff_cache

"""The real-data folder the tests read is the shared one beside the checkout."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.realdata import REALDATA


def test_realdata_is_the_shared_folder_beside_the_checkout() -> None:
    root = Path(__file__).resolve().parents[1]
    assert root.parent / "shared" / "realdata" == REALDATA


@pytest.mark.skipif(not REALDATA.is_dir(), reason="../shared/realdata is absent")
def test_realdata_holds_the_documented_datasets() -> None:
    assert (REALDATA / "README.md").is_file()
    assert {"av2", "kitti_tracking", "womd"} <= {p.name for p in REALDATA.iterdir()}

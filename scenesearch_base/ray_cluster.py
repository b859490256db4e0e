"""Where tasks run: serially here, on a local Ray runtime, or on a Ray cluster (:class:`Execution`).

:func:`ray_runtime` starts the runtime an :class:`Execution` asks for (or reuses one this process
started) and stops it afterwards. Joining a cluster first checks its address: nothing listening,
no answer within the timeout, something that is not a Ray head, ``auto`` without a cluster on this
machine: each is a :class:`ClusterError` saying what to do, within seconds (``ray.init`` itself
would retry for a minute or more). Ray is imported only here and only when a runtime is asked for.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import socket
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

#: Ray's default port of the head node's GCS (``ray start --head``), and of the Ray Client server.
GCS_PORT = 6379
CLIENT_PORT = 10001


class ClusterError(ValueError):
    """Ray cannot be used as asked: not installed, or the cluster address cannot be reached."""


#: Upper bounds of ``--workers`` (tasks at once) and of a task's retries.
MAX_WORKERS = 4096
MAX_RETRIES = 100


@dataclass(frozen=True)
class Execution:
    """Where tasks run.

    Attributes:
        workers: start a local Ray runtime with this many CPUs (one task per CPU); with
            ``address``, the most tasks of this run at once. None (and no address): serially, here.
        address: join the Ray cluster at ``HOST:PORT`` (its GCS; port 6379 when left out),
            ``ray://HOST:PORT`` (Ray Client) or ``auto`` (the cluster this machine belongs to).
        max_retries: how many more times a task runs after its worker died.
        progress: show a progress bar; None: when standard error is a terminal.
        connect_timeout_s: how long to wait for the cluster's address to answer.
    """

    workers: int | None = None
    address: str | None = None
    max_retries: int = 2
    progress: bool | None = None
    connect_timeout_s: float = 5.0

    def __post_init__(self) -> None:
        if self.workers is not None and not 1 <= self.workers <= MAX_WORKERS:
            raise ValueError(f"--workers must lie in [1, {MAX_WORKERS}], got {self.workers}")
        if not 0 <= self.max_retries <= MAX_RETRIES:
            raise ValueError(f"max_retries must lie in [0, {MAX_RETRIES}], got {self.max_retries}")

    @property
    def on_ray(self) -> bool:
        return self.workers is not None or self.address is not None

    def describe(self) -> str:
        if self.address is not None:
            limit = f", at most {self.workers} task(s) at once" if self.workers else ""
            return f"Ray cluster at {self.address}{limit}"
        if self.workers is not None:
            return f"Ray, {self.workers} local worker(s)"
        return "serial"

    @staticmethod
    def from_args(args: Any) -> Execution:
        """From the ``--workers`` and ``--ray-address`` flags (:func:`add_arguments`)."""
        return Execution(workers=getattr(args, "workers", None), address=getattr(args, "ray_address", None))


def add_arguments(parser: Any) -> None:
    """Add ``--workers N`` and ``--ray-address ADDR`` to an ``argparse`` parser."""
    parser.add_argument("--workers", type=int, metavar="N",
                        help="run one task per log on a local Ray runtime with N workers (default: serially, "
                             "in this process); with --ray-address, at most N at once")
    parser.add_argument("--ray-address", metavar="ADDR",
                        help="run on an existing Ray cluster: HOST:PORT of its head (`ray start --head`), "
                             "ray://HOST:PORT, or auto")


def import_ray() -> Any:
    """The ``ray`` module, or a :class:`ClusterError` saying how to install it."""
    try:
        import ray
    except ImportError as exc:
        raise ClusterError(f"--workers and --ray-address need Ray ({exc}); install it with "
                           "`pip install 'scenesearch[scale]'` (`make install` does)") from None
    return ray


@contextlib.contextmanager
def ray_runtime(execution: Execution) -> Iterator[int]:
    """A Ray runtime for ``execution``; yields how many tasks run at once.

    Reuses a runtime this process started already (and leaves it running), unless ``execution`` names
    a cluster address that runtime is not on (:func:`check_joined`); otherwise starts a local one or
    connects to the cluster, and shuts it down at the end.
    """
    ray = import_ray()
    if ray.is_initialized():
        check_joined(ray, execution)
        yield execution.workers or cluster_cpus(ray)
        return
    if execution.address is not None:
        address = check_reachable(execution.address, execution.connect_timeout_s)
        _check_gcs(address, execution.connect_timeout_s)
        try:
            ray.init(address=address, log_to_driver=False, configure_logging=False, runtime_env=_worker_env())
        except Exception as exc:  # reachable, but not a Ray head (or another Ray version)
            raise ClusterError(f"--ray-address {execution.address}: could not join the Ray cluster at {address}: "
                               f"{one_line(exc)[:500]}") from None
    else:
        ray.init(address="local", num_cpus=execution.workers, include_dashboard=False, log_to_driver=False,
                 configure_logging=False, runtime_env=_worker_env())
    try:
        yield execution.workers or cluster_cpus(ray)
    finally:
        ray.shutdown()


def check_joined(ray: Any, execution: Execution) -> None:
    """Raise a :class:`ClusterError` when this process's Ray runtime is not the cluster at
    ``execution.address`` (a ``HOST:PORT`` of a GCS): the tasks would run elsewhere than asked.

    ``auto``, Ray Client addresses (``ray://``, whose server is not the GCS) and no address accept the
    runtime there is. A loopback host means this machine: the runtime's GCS on this node matches it.
    """
    address = execution.address
    if address is None or address.strip() == "auto" or address.strip().startswith("ray://"):
        return
    host, port = split_address(address)
    gcs = str(ray.get_runtime_context().gcs_address)
    gcs_host, gcs_port = split_address(gcs)
    wanted = _host_ips(host)
    if any(ip.startswith("127.") or ip == "::1" for ip in wanted):
        wanted |= {str(ray.util.get_node_ip_address())}
    if port != gcs_port or not (wanted & (_host_ips(gcs_host) | {gcs_host})):
        raise ClusterError(f"--ray-address {address}: this process already runs on the Ray runtime at {gcs}, "
                           "not on that cluster; stop it first (`ray.shutdown()`), or leave --ray-address out "
                           "to run there")


def _host_ips(host: str) -> set[str]:
    """The addresses a host name resolves to (the name itself when it does not resolve)."""
    try:
        return {str(info[4][0]) for info in socket.getaddrinfo(host, None)}
    except OSError:
        return {host}


def _worker_env() -> dict[str, Any]:
    """The job's runtime environment: workers reuse freed memory (see :mod:`scenesearch_base.memory`) and
    their idle threads sleep early (:mod:`scenesearch_base.threads`), on this machine's runtime and on a
    cluster's nodes alike."""
    from scenesearch_base.memory import malloc_tunables
    from scenesearch_base.threads import thread_spin_env

    return {"env_vars": {"GLIBC_TUNABLES": malloc_tunables(os.environ.get("GLIBC_TUNABLES", "")),
                         **thread_spin_env()}}


@contextlib.contextmanager
def held_runtime(execution: Execution) -> Iterator[None]:
    """Hold one Ray runtime across several :func:`run_tasks` calls of a command (nothing when serial)."""
    if not execution.on_ray:
        yield
        return
    with ray_runtime(execution):
        yield


def _check_gcs(address: str, timeout_s: float) -> None:
    """Ask the address for its cluster id, as a Ray driver's first call does: something that
    accepts connections but is not a Ray head would otherwise keep ``ray.init`` retrying for
    about 20 s. (Ray Client addresses, ``ray://``, are not GCS servers and are not asked.)"""
    if address.startswith("ray://"):
        return
    host, port = split_address(address)
    not_ray = (f"--ray-address {address}: {host}:{port} answers, but not as the head of a Ray cluster "
               "(its GCS); give the head's GCS port (6379 unless `ray start --head --port` chose another)")
    if not _speaks_http2(host, port, timeout_s):
        raise ClusterError(not_ray)
    try:  # not a public API: without it, ray.init decides
        client = importlib.import_module("ray._raylet").InnerGcsClient
    except (ImportError, AttributeError):
        return
    try:
        client.standalone(f"{host}:{port}", None, int(timeout_s * 1000))
    except (AttributeError, TypeError):
        return
    except Exception as exc:
        raise ClusterError(f"{not_ray} ({one_line(exc)[:200]})") from None


#: An HTTP/2 client's connection preface and an empty SETTINGS frame (RFC 9113, 3.4 and 6.5).
_H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def _speaks_http2(host: str, port: int, timeout_s: float) -> bool:
    """Whether the server answers an HTTP/2 preface with a SETTINGS frame, as Ray's gRPC GCS does."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as conn:
            conn.sendall(_H2_PREFACE)
            header = b""
            while len(header) < 9:
                chunk = conn.recv(9 - len(header))
                if not chunk:
                    return False
                header += chunk
    except OSError:
        return False
    return header[3] == 4  # the frame type of SETTINGS


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity, as a container's CPU set limits it; else all)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def cluster_cpus(ray: Any) -> int:
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def node_cpus(ray: Any) -> list[int]:
    """CPUs of each live node of the Ray cluster this process is connected to."""
    return [int(n.get("Resources", {}).get("CPU", 0)) for n in ray.nodes() if n.get("Alive")]


def cluster_gpus() -> int:
    """GPUs of the Ray cluster this process is connected to (0 when none or not connected)."""
    ray = import_ray()
    return int(ray.cluster_resources().get("GPU", 0)) if ray.is_initialized() else 0


def _auto_address() -> str | None:
    """The address ``auto`` stands for: ``RAY_ADDRESS``, else the cluster started on this machine."""
    found = os.environ.get("RAY_ADDRESS", "").strip()
    if found and found != "auto":
        return found
    current = os.path.join(tempfile.gettempdir(), "ray", "ray_current_cluster")
    with contextlib.suppress(OSError):
        text = open(current).read().strip()  # noqa: SIM115 - one short read
        if text:
            return text.splitlines()[0].strip()
    return None


def split_address(address: str) -> tuple[str, int]:
    """``HOST:PORT``, ``ray://HOST:PORT``, ``HOST`` or ``[IPv6]:PORT`` → (host, port)."""
    rest = address.strip()
    default = GCS_PORT
    if rest.startswith("ray://"):
        rest, default = rest[len("ray://"):], CLIENT_PORT
    elif "://" in rest:
        raise ClusterError(f"--ray-address {address}: expected HOST:PORT, ray://HOST:PORT or auto")
    rest = rest.rstrip("/")
    if rest.startswith("["):
        host, _, tail = rest[1:].partition("]")
        port_text = tail.removeprefix(":")
    elif rest.count(":") == 1:
        host, _, port_text = rest.partition(":")
    else:
        host, port_text = rest, ""
    if not host:
        raise ClusterError(f"--ray-address {address}: no host")
    try:
        port = int(port_text) if port_text else default
    except ValueError:
        raise ClusterError(f"--ray-address {address}: port {port_text!r} is not a number") from None
    return host, port


def check_reachable(address: str, timeout_s: float = 5.0) -> str:
    """Resolve ``auto`` and check that the address answers a TCP connect within ``timeout_s``.

    Joining an address where nothing listens makes Ray wait a minute or more; this says so at once.

    Raises:
        ClusterError: no cluster for ``auto``, or nothing answers at the address.
    """
    resolved = address
    if address.strip() == "auto":
        found = _auto_address()
        if found is None:
            raise ClusterError("--ray-address auto: no Ray cluster runs on this machine (RAY_ADDRESS is not set "
                               "and `ray start` has not been run here); start one with `ray start --head`, give "
                               "the head's HOST:PORT, or use --workers N for a local runtime")
        resolved = found
    host, port = split_address(resolved)
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        why = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise ClusterError(
            f"--ray-address {address}: cannot reach a Ray cluster at {host}:{port} ({why} within "
            f"{timeout_s:g} s). Start its head with `ray start --head --port={port}` on that machine, check the "
            f"address and that the port is open to this machine, or use --workers N for a local runtime"
        ) from None
    return resolved


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (its type's name when it has none)."""
    return str(exc).replace("\n", "; ") or type(exc).__name__

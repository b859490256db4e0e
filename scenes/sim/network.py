"""Build the simulated city's road network with SUMO's ``netgenerate``, cached by its parameters.

Every layout has two lanes per direction, sidewalks and pedestrian crossings. Traffic lights go on
every other 3-way and every other 4-way junction (by sorted id), so both junction kinds occur both
signalised and as priority junctions. Generated networks are cached under the cache folder (never
in the source tree), keyed by the SUMO version and the full argument list.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
from pathlib import Path

from scenes.sim.config import NetworkKind
from scenes.sim.errors import SimulationError
from scenes.sim.netparse import read_net

NETGENERATE_TIMEOUT_S = 120.0

_COMMON = [
    "--default.lanenumber", "2",
    "--default.speed", "13.89",
    "--sidewalks.guess", "true",
    "--crossings.guess", "true",
    "--no-turnarounds", "true",
    "--junctions.corner-detail", "5",
    "--tls.cycle.time", "60",
    "--no-warnings", "true",
]


def sumo_home() -> Path:
    import sumo  # the eclipse-sumo wheel ships the binaries

    return Path(sumo.SUMO_HOME)


def sumo_version() -> str:
    from importlib.metadata import version

    return version("eclipse-sumo")


def layout_args(kind: NetworkKind, seed: int) -> list[str]:
    """``netgenerate`` arguments of a layout (without traffic lights and output)."""
    if kind is NetworkKind.GRID:
        # Removing the road between C1 and D1 turns two inner 4-way junctions into T-junctions.
        return ["--grid", "--grid.x-number", "5", "--grid.y-number", "4", "--grid.x-length", "110",
                "--grid.y-length", "90", "--remove-edges.explicit", "C1D1,D1C1"]
    if kind is NetworkKind.SPIDER:
        return ["--spider", "--spider.arm-number", "5", "--spider.circle-number", "3",
                "--spider.space-radius", "70"]
    return ["--rand", "--rand.iterations", "40", "--rand.min-distance", "80", "--rand.max-distance", "180",
            "--rand.min-angle", "45", "--rand.neighbor-dist1", "0", "--seed", str(seed)]


def demand_factor(kind: NetworkKind) -> float:
    """Traffic per km of road relative to the grid: every spider route funnels through the centre
    junction, which jams at grid densities."""
    return 0.35 if kind is NetworkKind.SPIDER else 1.0


def _netgenerate(args: list[str], out: Path) -> None:
    env = dict(os.environ, SUMO_HOME=str(sumo_home()))
    binary = sumo_home() / "bin" / "netgenerate"
    try:
        proc = subprocess.run(
            [str(binary), *args, "-o", str(out)], capture_output=True, text=True, env=env,
            timeout=NETGENERATE_TIMEOUT_S, check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SimulationError(f"netgenerate could not run: {exc}") from exc
    if proc.returncode != 0 or not out.is_file():
        message = (proc.stderr or proc.stdout).strip().splitlines()
        raise SimulationError(f"netgenerate failed (exit {proc.returncode}): {' | '.join(message[-5:])}")


def default_cache_dir() -> Path:
    return Path(tempfile.gettempdir()) / "scenesearch-sumo-cache"


def build_network(kind: NetworkKind, seed: int, cache_dir: Path | None = None) -> Path:
    """Path of the ``.net.xml`` of a layout, generating it on first use.

    Only the random layout depends on ``seed``; grid and spider are the same city for every seed.

    Raises:
        SimulationError: with netgenerate's message when it fails.
    """
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    base = layout_args(kind, seed) + _COMMON
    key = hashlib.sha256(("\0".join([sumo_version(), *base])).encode()).hexdigest()[:16]
    target = cache / f"{kind.value}-{key}.net.xml"
    if target.is_file():
        return target
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache, prefix=".netgen.") as tmp_dir:
        tmp = Path(tmp_dir)
        # First pass without lights to learn the junction degrees, then place lights on alternate junctions.
        _netgenerate(base, tmp / "plain.net.xml")
        net = read_net(tmp / "plain.net.xml")
        arms = net.junction_arms()
        tls: list[str] = []
        for degree in (3, 4):
            tls += sorted(j for j, a in arms.items() if a == degree)[::2]
        tls += sorted(j for j, a in arms.items() if a >= 5)
        final = tmp / "city.net.xml"
        _netgenerate([*base, "--tls.set", ",".join(sorted(tls))] if tls else base, final)
        os.replace(final, target)  # atomic: concurrent builders of one key write identical files
    return target

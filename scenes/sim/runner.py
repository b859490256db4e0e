"""Drive SUMO through libsumo and record what each ego sees during its log windows.

One run serves many logs: ``num_egos`` egos drive at once and each log is one window of one ego's
drive. Around each window a margin is recorded too, so that labels spanning a window's edge (a lane
change that began before it) are complete; the margin is cut off when the log is written.

While windows are recorded (not during warm-up) the positions of all objects are read each step;
only objects within :data:`CONTEXT_RADIUS_M` of an ego become rows and have their other
variables and their leader read.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field, fields
from itertools import chain
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scenes.sim.errors import SimulationError

#: Objects farther than this from an ego are not recorded (the annotation range is smaller).
CONTEXT_RADIUS_M = 110.0
#: Egos get a new destination, when near the end of their route, at most this often.
KEEP_DRIVING_EVERY_STEPS = 10
#: Leaders are looked for this far ahead along the route.
LEADER_LOOKAHEAD_M = 60.0
#: Recorded before and after each window (longer than a lane change).
MARGIN_S = 4.0
#: SUMO lane changes take this long (continuous lateral motion instead of a jump between lanes).
LANE_CHANGE_DURATION_S = 3.0
#: Vehicles stuck this long are teleported by SUMO, which resolves rare gridlocks.
TIME_TO_TELEPORT_S = 120.0

#: Stop-state bit set while a vehicle is parked (off its lane).
STOPSTATE_PARKING = 2


def load_libsumo() -> Any:
    """Import libsumo, silencing its start-up notice on stdout (a version note about pyarrow)."""
    with contextlib.redirect_stdout(io.StringIO()):
        import libsumo
    return libsumo


@dataclass
class ObjectRows:
    """Objects seen by one ego over one recorded span, one row per (step, object).

    Attributes:
        step: (N,) simulation step index.
        sumo_id: (N,) SUMO vehicle or person id.
        type_id: (N,) SUMO vType id.
        is_person: (N,) pedestrians.
        front_xy_m: (N, 2) front-bumper centre in the city frame (SUMO's reference point).
        angle_deg: (N,) SUMO heading: compass degrees, clockwise from north.
        speed_mps: (N,) speed.
        accel_mps2: (N,) longitudinal acceleration (0 for pedestrians).
        lane_id: (N,) SUMO lane id ("" for pedestrians).
        lane_index: (N,) lane index on its edge, 0 = rightmost (−1 for pedestrians).
        lateral_m: (N,) offset from the lane centre, positive to the left.
        stop_state: (N,) SUMO stop-state bits.
        leader_id: (N,) next vehicle ahead on the route ("" when none).
        leader_gap_m: (N,) bumper-to-bumper gap to it (inf when none).
        leader_speed_mps: (N,) the leader's speed (nan when none).
        leader_accel_mps2: (N,) the leader's acceleration (nan when none).
        lane_pos_m: (N,) distance driven along the lane from its start (0 for pedestrians).
    """

    step: NDArray[np.int64]
    sumo_id: NDArray[np.str_]
    type_id: NDArray[np.str_]
    is_person: NDArray[np.bool_]
    front_xy_m: NDArray[np.float64]
    angle_deg: NDArray[np.float64]
    speed_mps: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    lane_id: NDArray[np.str_]
    lane_index: NDArray[np.int64]
    lateral_m: NDArray[np.float64]
    stop_state: NDArray[np.int64]
    leader_id: NDArray[np.str_]
    leader_gap_m: NDArray[np.float64]
    leader_speed_mps: NDArray[np.float64]
    leader_accel_mps2: NDArray[np.float64]
    lane_pos_m: NDArray[np.float64]

    def select(self, mask: NDArray[np.bool_] | NDArray[np.int64]) -> ObjectRows:
        return ObjectRows(**{k: v[mask] for k, v in self.__dict__.items()})


@dataclass
class Recording:
    """What one ego saw during one window plus its margins.

    Attributes:
        ego_id: SUMO id of the ego.
        window: window index.
        first_step, last_step: the log's steps (inclusive), without the margins.
        ego: the ego's own rows (one per recorded step).
        objects: the other objects' rows.
    """

    ego_id: str
    window: int
    first_step: int
    last_step: int
    ego: ObjectRows
    objects: ObjectRows


@dataclass
class _Collector:
    """Row numbers (into the run's shared row list) of one ego's window: egos see the same
    objects, so each (step, object) row is read and stored once."""

    rows: list[int] = field(default_factory=list)
    ego_rows: list[int] = field(default_factory=list)


#: dtype of each :class:`ObjectRows` field, in field order: the order of the values in a stored row.
_ROW_DTYPES: tuple[type, ...] = (
    np.int64, np.str_, np.str_, np.bool_, np.float64, np.float64, np.float64, np.float64, np.str_, np.int64,
    np.float64, np.int64, np.str_, np.float64, np.float64, np.float64, np.float64,
)


def _to_rows(rows: list[tuple[Any, ...]]) -> ObjectRows:
    """Stored rows (one tuple per (step, object), values in :class:`ObjectRows` field order) as columns."""
    names = [f.name for f in fields(ObjectRows)]
    cols = list(zip(*rows)) if rows else [()] * len(names)
    arrays: dict[str, NDArray[Any]] = {
        name: np.asarray(col, dtype=dtype) for name, col, dtype in zip(names, cols, _ROW_DTYPES, strict=True)
    }
    arrays["front_xy_m"] = arrays["front_xy_m"].reshape(-1, 2)  # (N, 2): a row holds an (x, y) pair
    return ObjectRows(**arrays)


@dataclass(frozen=True)
class RunPlan:
    """When each window runs. All egos share the windows."""

    step_s: float
    warmup_steps: int
    window_steps: int
    num_windows: int
    margin_steps: int

    @property
    def total_steps(self) -> int:
        return self.warmup_steps + self.num_windows * self.window_steps + self.margin_steps + 1

    def window_span(self, w: int) -> tuple[int, int]:
        """First and last step of window ``w`` (inclusive)."""
        first = self.warmup_steps + w * self.window_steps
        return first, first + self.window_steps - 1


def run_sumo(
    net_path: Path,
    routes_xml: str,
    additional_xml: str,
    ego_ids: tuple[str, ...],
    road_edges: tuple[str, ...],
    plan: RunPlan,
    seed: int,
    work_dir: Path,
) -> list[Recording]:
    """Run SUMO and return one :class:`Recording` per (ego, window), ordered by window then ego.

    libsumo holds one simulation per process: runs in one process happen one after another
    (run several processes to simulate in parallel).

    Raises:
        SimulationError: with SUMO's message when it fails, or when an ego leaves the city.
    """
    libsumo = load_libsumo()
    routes = work_dir / "city.rou.xml"
    additional = work_dir / "city.add.xml"
    error_log = work_dir / "sumo-stderr.log"
    routes.write_text(routes_xml)
    additional.write_text(additional_xml)
    end_s = plan.total_steps * plan.step_s + 1.0
    args = [
        "sumo", "-n", str(net_path), "-r", str(routes), "-a", str(additional),
        "--step-length", f"{plan.step_s}", "--seed", str(seed), "--end", f"{end_s}",
        "--lanechange.duration", f"{LANE_CHANGE_DURATION_S}",
        "--time-to-teleport", f"{TIME_TO_TELEPORT_S}",
        "--ignore-route-errors", "true", "--no-step-log", "true", "--no-warnings", "true",
        "--xml-validation", "never", "--xml-validation.net", "never", "--xml-validation.routes", "never",
        "--duration-log.disable", "true",
    ]
    rng = np.random.default_rng([seed, 0xE60])
    collectors = {(e, w): _Collector() for w in range(plan.num_windows) for e in ego_ids}
    store: list[tuple[Any, ...]] = []
    spans = [plan.window_span(w) for w in range(plan.num_windows)]
    first_recorded = max(spans[0][0] - plan.margin_steps, 0)
    try:
        # SUMO writes its errors to the process's stderr (its error log is flushed only at exit):
        # capture the file descriptor so that a failure can carry SUMO's own words.
        with _stderr_to(error_log):
            started = False
            try:
                libsumo.start(args)
                started = True
                veh, person = libsumo.vehicle, libsumo.person
                for step in range(plan.total_steps):
                    libsumo.simulationStep()
                    if step % KEEP_DRIVING_EVERY_STEPS == 0:
                        present = set(veh.getIDList())
                        for ego in ego_ids:
                            if ego in present:
                                _keep_driving(veh, ego, road_edges, rng)
                    active = [w for w, (a, b) in enumerate(spans)
                              if a - plan.margin_steps <= step <= b + plan.margin_steps]
                    if not active or step < first_recorded:
                        continue
                    _record_step(veh, person, step, ego_ids, store,
                                 [collectors[(ego, w)] for ego in ego_ids for w in active], len(active),
                                 must_drive=step >= spans[0][0])
            finally:
                if started:
                    with contextlib.suppress(Exception):
                        libsumo.close()
    except SimulationError:
        raise
    except Exception as exc:  # libsumo raises its own exception types; surface SUMO's message
        raise SimulationError(f"SUMO failed{_sumo_errors(error_log) or f': {exc}'}") from exc
    table = _to_rows(store)
    out = []
    for w, (first, last) in enumerate(spans):
        for ego in ego_ids:
            c = collectors[(ego, w)]
            out.append(Recording(ego, w, first, last, table.select(np.asarray(c.ego_rows, dtype=np.int64)),
                                 table.select(np.asarray(c.rows, dtype=np.int64))))
    return out


@contextlib.contextmanager
def _stderr_to(path: Path) -> Iterator[None]:
    """Point file descriptor 2 (where SUMO's C++ code writes) at ``path`` for the duration."""
    sys.stderr.flush()
    saved = os.dup(2)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.dup2(fd, 2)
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)
        os.close(fd)


def _record_step(
    veh: Any,
    person: Any,
    step: int,
    ego_ids: tuple[str, ...],
    store: list[tuple[Any, ...]],
    collectors: list[_Collector],
    windows_per_ego: int,
    must_drive: bool,
) -> None:
    """Append this step's rows of the objects near any ego to ``store``, and their row numbers to
    the collectors of the egos they are near.

    ``collectors`` holds ``windows_per_ego`` consecutive entries per ego, in ``ego_ids`` order.
    Positions of all objects are read first; the other variables only for objects near an ego.
    (Direct getter calls measured cheaper than libsumo subscriptions, whose results are built
    as nested dicts every step.)
    """
    vehicle_ids = veh.getIDList()
    present = set(vehicle_ids)
    ego_xy = []
    for ego in ego_ids:
        if ego in present:
            ego_xy.append(veh.getPosition(ego))
        elif must_drive:
            raise SimulationError(f"ego {ego} is not driving at step {step} (it could not depart "
                                  f"or left the network); try another seed")
        else:
            ego_xy.append((np.inf, np.inf))
    centers = np.asarray(ego_xy, dtype=np.float64)  # (E, 2)
    leaders: dict[str, tuple[str, float, float, float]] = {}
    radius2 = CONTEXT_RADIUS_M**2
    for domain, ids, is_person in ((veh, vehicle_ids, False), (person, person.getIDList(), True)):
        if not ids:
            continue
        flat = np.fromiter(chain.from_iterable(domain.getPosition(sid) for sid in ids), np.float64, 2 * len(ids))
        xy = flat.reshape(-1, 2)  # (N, 2)
        near = ((xy[None, :, :] - centers[:, None, :]) ** 2).sum(axis=2) <= radius2  # (E, N)
        rows: dict[int, int] = {}  # object index → row number in the store
        for i in np.flatnonzero(near.any(axis=0)).tolist():
            sid = ids[i]
            rows[i] = len(store)
            if is_person:
                store.append((step, sid, domain.getTypeID(sid), True, (flat[2 * i], flat[2 * i + 1]),
                              domain.getAngle(sid), domain.getSpeed(sid), 0.0, "", -1, 0.0, 0, "", np.inf,
                              np.nan, np.nan, 0.0))
            else:
                store.append(_vehicle_row(veh, step, sid, (flat[2 * i], flat[2 * i + 1]), leaders))
        for e, ego in enumerate(ego_ids):
            seen = [rows[i] for i in np.flatnonzero(near[e]).tolist() if ids[i] != ego]
            own = rows.get(ids.index(ego)) if not is_person and ego in present else None
            for c in collectors[e * windows_per_ego:(e + 1) * windows_per_ego]:
                c.rows.extend(seen)
                if own is not None:
                    c.ego_rows.append(own)


def _sumo_errors(error_log: Path, max_lines: int = 5) -> str:
    """SUMO's distinct error lines, as a suffix for an exception message."""
    if not error_log.is_file():
        return ""
    lines = list(dict.fromkeys(line.strip() for line in error_log.read_text().splitlines() if line.strip()))
    if not lines:
        return ""
    more = f" (+{len(lines) - max_lines} more)" if len(lines) > max_lines else ""
    return ": " + " | ".join(lines[:max_lines]) + more


def _vehicle_row(
    veh: Any, step: int, sid: str, xy: tuple[float, float], leaders: dict[str, tuple[str, float, float, float]]
) -> tuple[Any, ...]:
    if sid not in leaders:
        found = veh.getLeader(sid, LEADER_LOOKAHEAD_M)
        if found and found[0]:
            leaders[sid] = (found[0], float(found[1]), veh.getSpeed(found[0]), veh.getAcceleration(found[0]))
        else:
            leaders[sid] = ("", np.inf, np.nan, np.nan)
    leader, gap, leader_speed, leader_accel = leaders[sid]
    return (step, sid, veh.getTypeID(sid), False, xy, veh.getAngle(sid), veh.getSpeed(sid),
            veh.getAcceleration(sid), veh.getLaneID(sid), veh.getLaneIndex(sid), veh.getLateralLanePosition(sid),
            veh.getStopState(sid), leader, gap, leader_speed, leader_accel, veh.getLanePosition(sid))


def _keep_driving(veh: Any, ego: str, road_edges: tuple[str, ...], rng: np.random.Generator) -> None:
    """Give an ego a new destination before it arrives, so that it drives through every window."""
    try:
        route = veh.getRoute(ego)
    except Exception as exc:  # libsumo's TraCIException: the vehicle is gone
        raise SimulationError(f"ego {ego} left the network (SUMO: {exc}); try another seed") from exc
    if veh.getRouteIndex(ego) < len(route) - 2:
        return
    for _ in range(8):
        target = road_edges[int(rng.integers(len(road_edges)))]
        if target == route[-1]:
            continue
        try:
            veh.changeTarget(ego, target)
            return
        except Exception:  # an unreachable target: draw another
            continue

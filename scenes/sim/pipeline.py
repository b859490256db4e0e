"""Simulate a city with SUMO and write its drive logs in the AV2 layout.

Per log folder (see ARCHITECTURE.md for the AV2 part)::

    annotations.feather          boxes of every object within ``range_m`` of the ego, ego frame, 10 Hz
    city_SE3_egovehicle.feather  ego poses, same timestamps
    map/log_map_archive_*.json   the city's lanes, crossings and drivable areas, city frame
    behavior_labels.feather      per (timestamp, track) behaviour labels, ego included (scenes.behavior)
    junctions.feather            3-way / 4-way / multi-way junctions, city frame
    log_metadata.json            source "sumo", appearance variables, seed and configuration

The ego frame's origin is the ego's rear axle on the ground (:data:`EGO_ORIGIN_BEHIND_FRONT_M`
behind its front bumper). With ``tracker_noise`` the annotations are what a detector and tracker
would report (:mod:`scenes.sim.noise`) while the behaviour labels stay keyed by the true track ids;
the ``jitter_share`` logs' boxes scatter from frame to frame as real labels do, their labels exact.

SUMO runs to the end before anything is written, and each log is assembled in a temporary folder
renamed into place, so a failure leaves no partial log behind.
"""

from __future__ import annotations

import shutil
import tempfile
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyarrow as pa

from scenes import av2_io
from scenes.behavior import BEHAVIOR_SCHEMA, EGO_TRACK_ID, BehaviorLabel, write_behavior_labels, write_junctions
from scenes.geometry import wrap_angle_rad
from scenes.map import VectorMap
from scenes.metadata import MAP_WITHHELD_KEY, LogMetadata
from scenes.sim.appearance import sample_appearance
from scenes.sim.config import SimulationConfig
from scenes.sim.demand import ALL_TYPES, VehicleType, make_demand
from scenes.sim.errors import SimulationError
from scenes.sim.labels import LaneInfo, compute_labels
from scenes.sim.map_export import export_map, junction_table
from scenes.sim.netparse import read_net
from scenes.sim.network import build_network, demand_factor, sumo_version
from scenes.sim.noise import apply_tracker_noise, jitter_boxes
from scenes.sim.props import PROP_TYPES, PropType, place_props, prop_rows
from scenes.sim.runner import CONTEXT_RADIUS_M, MARGIN_S, ObjectRows, Recording, RunPlan, run_sumo
from scenes.tracks import Annotations, EgoTrajectory
from scenesearch_base.folders import claimed_directory
from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_runner import run_tasks
from scenesearch_base.storage import Location, expand, is_uri, join, name_of, staged_output

#: Timestamp of simulation time 0 (2023-11-14T22:13:20Z): fixed, so that logs are reproducible.
BASE_TIMESTAMP_NS = 1_700_000_000_000_000_000
#: The ego origin (rear axle) lies this far behind the ego's front bumper.
EGO_ORIGIN_BEHIND_FRONT_M = 3.6
CITY_NAME = "SIM"
_LOG_NAMESPACE = uuid.UUID("0d9b6f4e-8a51-4c1e-b7f2-5d3e9c2a7b64")
#: Box size and AV2 label of every object type a recording holds: SUMO's and the placed ones.
OBJECT_TYPES: dict[str, VehicleType | PropType] = {**ALL_TYPES, **PROP_TYPES}

#: Called with each log folder after its tracks and map are written and before it is renamed
#: into place; what it writes there appears atomically with the log (e.g. sensor rendering).
PostLogHook = Callable[[Path], None]


@dataclass(frozen=True)
class SimulationResult:
    """What a run produced and how fast.

    Attributes:
        log_dirs: the written logs, in log order.
        simulated_s: simulated seconds SUMO stepped (warm-up and margins included).
        wall_s: wall-clock seconds of the whole call.
        sumo_wall_s: wall-clock seconds spent stepping SUMO and reading its state.
        cpu_s: CPU seconds of this process for the whole call (SUMO runs in-process).
        sumo_cpu_s: CPU seconds spent stepping SUMO and reading its state.
    """

    log_dirs: list[Location]
    simulated_s: float
    wall_s: float
    sumo_wall_s: float
    cpu_s: float = 0.0
    sumo_cpu_s: float = 0.0

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.simulated_s / max(self.wall_s, 1e-9)


def log_ids(config: SimulationConfig) -> list[str]:
    """The ids (folder names) of the logs a configuration writes."""
    return [str(uuid.uuid5(_LOG_NAMESPACE, f"{config.seed}/{config.network.value}/{i}")) for i in range(config.logs)]


def track_uuid(seed: int, sumo_id: str) -> str:
    """Stable track id of a SUMO object in a run of ``seed``."""
    return str(uuid.uuid5(_LOG_NAMESPACE, f"{seed}/track/{sumo_id}"))


def existing_logs(out_dir: Path) -> list[Path]:
    """Log folders already in ``out_dir``."""
    if not out_dir.is_dir():
        return []
    return sorted(p for p in out_dir.iterdir() if p.is_dir() and not p.name.startswith(".")
                  and ((p / av2_io.ANNOTATIONS_FILENAME).exists() or (p / av2_io.POSES_FILENAME).exists()))


def simulate(config: SimulationConfig, out_dir: Path | str, overwrite: bool = False,
             post_log: Sequence[PostLogHook] = ()) -> list[Path]:
    """Simulate and write ``config.logs`` logs into ``out_dir``; returns their folders.

    Raises:
        FileExistsError: ``out_dir`` already holds logs and ``overwrite`` is false.
        SimulationError: SUMO failed (its message included); nothing was written.
    """
    return [Path(p) for p in simulate_tracks_and_map(config, out_dir, overwrite, post_log).log_dirs]


def simulate_tracks_and_map(config: SimulationConfig, out_dir: Location, overwrite: bool = False,
                            post_log: Sequence[PostLogHook] = (),
                            execution: Execution | None = None) -> SimulationResult:
    """As :func:`simulate`, with timing figures.

    SUMO runs once, here; writing each log and its ``post_log`` hooks (sensor rendering) is one task
    per log (:func:`write_log`), serially or on Ray (``execution``). ``out_dir`` may be a
    ``pyarrow.fs`` URI: each log is then written locally and uploaded.

    Raises:
        SimulationError: also when a log's task failed (the other logs are written).
    """
    start, start_cpu = time.perf_counter(), time.process_time()
    out = out_dir if is_uri(out_dir) else Path(out_dir)
    old: list[Location] = list(existing_logs(out)) if isinstance(out, Path) else expand([f"{out}/*"])
    if old and not overwrite:
        raise FileExistsError(f"{out} already holds {len(old)} log(s) (e.g. {name_of(old[0])}); "
                              f"pass overwrite (--overwrite) to replace them")
    cache = Path(config.cache_dir) if config.cache_dir else None
    net_path = build_network(config.network, config.seed, cache)
    net = read_net(net_path)
    vector_map = export_map(net)
    junctions = junction_table(net)
    lanes = LaneInfo.from_net(net)
    step_ns = round(config.step_s * 1e9)
    plan = RunPlan(
        step_s=config.step_s,
        warmup_steps=round(config.warmup_s / config.step_s),
        window_steps=round(config.duration_s / config.step_s),
        num_windows=config.num_windows,
        margin_steps=round(MARGIN_S / config.step_s),
    )
    road_km = net.road_length_m("passenger") / 1000.0 * demand_factor(config.network)
    demand = make_demand(net, config.seed, plan.total_steps * config.step_s, config.num_egos,
                         config.vehicles_per_s_per_km * road_km, config.pedestrians_per_s_per_km * road_km,
                         config.parked_vehicles)
    sumo_start, sumo_start_cpu = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory(prefix="scenesearch-sumo-") as work:
        recordings = run_sumo(net_path, demand.routes_xml, demand.additional_xml, demand.ego_ids,
                              demand.road_edges, plan, config.seed, Path(work))
    sumo_wall_s = time.perf_counter() - sumo_start
    sumo_cpu_s = time.process_time() - sumo_start_cpu
    props = place_props(net, config.seed, config.furniture_per_km, config.standing_pedestrians_per_km)
    recordings = [replace(r, objects=_concat(r.objects, prop_rows(props, r.ego, CONTEXT_RADIUS_M)))
                  for r in recordings]

    # Every log is assembled before any is written, so that a log that cannot be valid stops the
    # run with nothing written.
    map_less, jittered = config.map_less_logs(), config.jittered_logs()
    contents = [
        _build_log(log_id, i, recordings[i], config, step_ns, lanes, has_map=i not in map_less,
                   jitter=i in jittered)
        for i, log_id in enumerate(log_ids(config))  # log i: ego i % E, window i // E
    ]
    empty = [c.log_id for c in contents if len(c.annotations) == 0]
    if empty:
        raise SimulationError(
            f"{len(empty)} log(s) would have no objects within {config.range_m:g} m of the ego "
            f"(e.g. {empty[0]}): the city is still empty; raise warmup_s (now {config.warmup_s:g} s)"
        )
    context = _WriteContext(out, overwrite, vector_map, junctions, tuple(post_log))
    run = run_tasks(write_log, contents, execution, labels=[c.log_id for c in contents], context=context)
    if run.problems():
        raise SimulationError(f"{len(run.problems())} of {len(contents)} log(s) could not be written: "
                              + "; ".join(run.problems()[:5]))
    written = [join(out, c.log_id) for c in contents]
    for stale in old:
        if stale not in written and isinstance(stale, Path):
            shutil.rmtree(stale, ignore_errors=True)
    return SimulationResult(written, plan.total_steps * config.step_s, time.perf_counter() - start, sumo_wall_s,
                            time.process_time() - start_cpu, sumo_cpu_s)


@dataclass(frozen=True)
class _WriteContext:
    """What every log's task shares: where logs go, the city's map and junctions, the hooks."""

    out: Location
    overwrite: bool
    vector_map: VectorMap
    junctions: pa.Table
    post_log: tuple[PostLogHook, ...]


def write_log(content: _LogContent, ctx: _WriteContext) -> str:
    """Write one log (and run the hooks on it) into a temporary folder renamed into place: one
    task of :func:`simulate_tracks_and_map`, in this process or on a Ray worker."""
    with staged_output(ctx.out) as local, \
            claimed_directory(local / content.log_id, av2_io.LOG_FOLDER, overwrite=ctx.overwrite) as tmp:
        content.write(tmp, ctx.vector_map, ctx.junctions)
        for hook in ctx.post_log:
            hook(tmp)
        if content.metadata.extra[MAP_WITHHELD_KEY]:
            # Withheld only now: the sensor rendering (a hook) builds the static world from the map.
            shutil.rmtree(tmp / av2_io.MAP_DIRNAME)
    return content.log_id


def _heading_rad(angle_deg: np.ndarray) -> np.ndarray:
    """SUMO's compass heading (degrees clockwise from north) → yaw (0 along +x, counter-clockwise)."""
    return wrap_angle_rad(np.pi / 2 - np.deg2rad(angle_deg))


def _concat(a: ObjectRows, b: ObjectRows) -> ObjectRows:
    return ObjectRows(**{k: np.concatenate([getattr(a, k), getattr(b, k)]) for k in a.__dict__})


@dataclass(frozen=True)
class _LogContent:
    log_id: str
    annotations: Annotations
    ego: EgoTrajectory
    labels: pa.Table
    metadata: LogMetadata

    def write(self, log_dir: Path, vector_map: VectorMap, junctions: pa.Table) -> None:
        av2_io.write_annotations(log_dir, self.annotations)
        av2_io.write_ego_poses(log_dir, self.ego)
        av2_io.write_map(log_dir, vector_map, self.log_id, CITY_NAME)
        write_behavior_labels(log_dir, self.labels)
        write_junctions(log_dir, junctions)
        av2_io.write_metadata(log_dir, self.metadata)


def _build_log(log_id: str, index: int, rec: Recording, config: SimulationConfig, step_ns: int,
               lanes: LaneInfo, has_map: bool = True, jitter: bool = False) -> _LogContent:
    # Labels need the margins (lane changes across the window's edge); everything else does not.
    all_rows = _concat(rec.ego, rec.objects)
    labels = compute_labels(all_rows, lanes)

    ego_in = (rec.ego.step >= rec.first_step) & (rec.ego.step <= rec.last_step)
    ego_rows = rec.ego.select(ego_in)
    ego_yaw = _heading_rad(ego_rows.angle_deg)
    ego_dir = np.stack([np.cos(ego_yaw), np.sin(ego_yaw)], axis=1)
    ego_xy = ego_rows.front_xy_m - EGO_ORIGIN_BEHIND_FRONT_M * ego_dir
    ego_ts = BASE_TIMESTAMP_NS + ego_rows.step * step_ns
    ego = EgoTrajectory.from_xy_yaw(ego_ts, ego_xy, ego_yaw)

    obj = rec.objects
    in_window = (obj.step >= rec.first_step) & (obj.step <= rec.last_step) & np.isin(obj.step, ego_rows.step)
    # Per-row lookups go through the few distinct values.
    types, type_of_row = np.unique(obj.type_id, return_inverse=True)
    sizes = np.array([[OBJECT_TYPES[str(t)].length_m, OBJECT_TYPES[str(t)].width_m, OBJECT_TYPES[str(t)].height_m]
                      for t in types]).reshape(-1, 3)[type_of_row]
    yaw_city = _heading_rad(obj.angle_deg)
    center_city = obj.front_xy_m - 0.5 * sizes[:, :1] * np.stack([np.cos(yaw_city), np.sin(yaw_city)], axis=1)
    frame = np.clip(np.searchsorted(ego_rows.step, obj.step), 0, max(len(ego_rows.step) - 1, 0))
    rel = center_city - ego_xy[frame] if len(ego_xy) else center_city
    c, s = np.cos(ego_yaw[frame]), np.sin(ego_yaw[frame])
    x_ego = c * rel[:, 0] + s * rel[:, 1]
    y_ego = -s * rel[:, 0] + c * rel[:, 1]
    in_range = np.hypot(x_ego, y_ego) <= config.range_m
    keep = in_window & in_range

    sumo_ids, id_of_row = np.unique(obj.sumo_id, return_inverse=True)
    track_ids = np.array([track_uuid(config.seed, str(sid)) for sid in sumo_ids], dtype=np.str_)[id_of_row]
    categories = np.array([OBJECT_TYPES[str(t)].av2_label for t in types], dtype=np.str_)[type_of_row]
    annotations = Annotations.from_yaw(
        timestamp_ns=BASE_TIMESTAMP_NS + obj.step[keep] * step_ns,
        track_id=track_ids[keep],
        category=categories[keep],
        center_xyz_m=np.stack([x_ego[keep], y_ego[keep], 0.5 * sizes[keep, 2]], axis=1),
        size_lwh_m=sizes[keep],
        yaw_rad=wrap_angle_rad(yaw_city[keep] - ego_yaw[frame][keep]),
    ).sorted()
    if config.tracker_noise:
        noise_rng = np.random.default_rng([config.seed, index, 0x7AC])
        annotations = apply_tracker_noise(annotations, ego, config.noise, noise_rng)
    elif jitter:
        annotations = jitter_boxes(annotations, config.noise, np.random.default_rng([config.seed, index, 0x717]))

    # Label rows: the ego's and the annotated objects' rows of the window (true ids, before noise).
    label_keep = np.r_[ego_in, keep]
    label_ids = np.r_[np.full(rec.ego.step.shape[0], EGO_TRACK_ID, dtype=object), track_ids.astype(object)]
    labels_table = _labels_table(all_rows, labels.flags, labels.leader_id, labels.junction_id, label_ids,
                                 label_keep, step_ns, config.seed)

    visible_tracks = sorted(set(annotations.track_id.tolist()))
    appearance = sample_appearance(np.random.default_rng([config.seed, index, 0xA99]),
                                   [EGO_TRACK_ID, *visible_tracks])
    metadata = LogMetadata(
        log_id=log_id,
        source="sumo",
        city_name=CITY_NAME,
        appearance=appearance,
        extra={
            "seed": config.seed,
            "network": config.network.value,
            "log_index": index,
            "ego_sumo_id": rec.ego_id,
            "window": rec.window,
            "start_s": rec.first_step * config.step_s,
            "sumo_version": sumo_version(),
            "sensors": config.sensors,
            "tracker_noise": config.tracker_noise,
            "box_jitter": jitter,
            MAP_WITHHELD_KEY: not has_map,
            # Everything that shapes the log; the network cache's location does not.
            "config": {k: v for k, v in config.to_dict().items() if k != "cache_dir"},
        },
    )
    return _LogContent(log_id, annotations, ego, labels_table, metadata)


def _labels_table(rows: ObjectRows, flags: dict[BehaviorLabel, np.ndarray], leader_id: np.ndarray,
                  junction_id: np.ndarray, track_ids: np.ndarray, keep: np.ndarray, step_ns: int,
                  seed: int) -> pa.Table:
    idx = np.flatnonzero(keep)
    ts = BASE_TIMESTAMP_NS + rows.step[idx] * step_ns
    tid = track_ids[idx].astype(np.str_)
    order = np.lexsort((tid, ts))
    idx, ts, tid = idx[order], ts[order], tid[order]
    leader_uuid = {str(v): track_uuid(seed, str(v)) for v in np.unique(leader_id[idx]) if v}
    leaders = [leader_uuid.get(str(v)) for v in leader_id[idx]]
    junctions = [str(v) if v else None for v in junction_id[idx]]
    columns: dict[str, pa.Array] = {
        "timestamp_ns": pa.array(ts, pa.int64()),
        "track_id": pa.array(tid.tolist(), pa.string()),
    }
    for label in BehaviorLabel:
        columns[label.value] = pa.array(flags[label][idx], pa.bool_())
    columns["speed_mps"] = pa.array(rows.speed_mps[idx], pa.float64())
    columns["leader_id"] = pa.array(leaders, pa.string())
    columns["junction_id"] = pa.array(junctions, pa.string())
    return pa.table(columns, schema=BEHAVIOR_SCHEMA)

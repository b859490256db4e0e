"""Speed of the city simulator: simulated seconds per wall-clock (and CPU) second, tracks + map only.

Three runs of the same city and traffic in one process:

- ``pipeline``: :func:`scenes.sim.simulate_tracks_and_map`, the whole path from network to written
  logs (annotations, poses, map, behaviour labels, junctions, metadata), and its recording part
  (SUMO stepping plus reading state back);
- ``step_only`` (lower bound): SUMO stepped through the same time, nothing read back;
- ``naive_polling`` (reference): SUMO stepped while every vehicle and pedestrian in the city is read
  with one getter call per variable each step during the windows (rows kept in memory, nothing
  derived or written): the straightforward way to record a simulation.

CPU seconds are reported beside wall seconds because the machine may be shared: the target
(≥ 50× real time on one core) is about CPU time on one core.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from scenes.sim import SimulationConfig, simulate_tracks_and_map
from scenes.sim.demand import make_demand
from scenes.sim.netparse import read_net
from scenes.sim.network import build_network, demand_factor
from scenes.sim.runner import MARGIN_S, RunPlan, load_libsumo


def _plan(config: SimulationConfig) -> RunPlan:
    return RunPlan(config.step_s, round(config.warmup_s / config.step_s), round(config.duration_s / config.step_s),
                   config.num_windows, round(MARGIN_S / config.step_s))


def _reference_run(config: SimulationConfig, cache: Path, poll: bool) -> tuple[float, float]:
    """(wall_s, cpu_s) of SUMO alone over the same time, optionally polling every object naively."""
    libsumo = load_libsumo()
    net_path = build_network(config.network, config.seed, cache)
    net = read_net(net_path)
    plan = _plan(config)
    km = net.road_length_m("passenger") / 1000.0 * demand_factor(config.network)
    demand = make_demand(net, config.seed, plan.total_steps * config.step_s, config.num_egos,
                         config.vehicles_per_s_per_km * km, config.pedestrians_per_s_per_km * km,
                         config.parked_vehicles)
    with tempfile.TemporaryDirectory() as work:
        routes, additional = Path(work) / "r.rou.xml", Path(work) / "a.add.xml"
        routes.write_text(demand.routes_xml)
        additional.write_text(demand.additional_xml)
        wall0, cpu0 = time.perf_counter(), time.process_time()
        libsumo.start(["sumo", "-n", str(net_path), "-r", str(routes), "-a", str(additional),
                       "--step-length", str(config.step_s), "--seed", str(config.seed), "--no-step-log", "true",
                       "--no-warnings", "true", "--ignore-route-errors", "true", "--lanechange.duration", "3",
                       "--xml-validation", "never"])
        first_window = plan.window_span(0)[0] - plan.margin_steps
        veh, person = libsumo.vehicle, libsumo.person
        rows: list[Any] = []
        for step in range(plan.total_steps):
            libsumo.simulationStep()
            if not poll or step < first_window:
                continue
            for v in veh.getIDList():
                rows.append((step, v, veh.getPosition(v), veh.getAngle(v), veh.getSpeed(v), veh.getAcceleration(v),
                             veh.getLaneID(v), veh.getLaneIndex(v), veh.getTypeID(v), veh.getStopState(v),
                             veh.getLateralLanePosition(v), veh.getLeader(v, 60.0)))
            for p in person.getIDList():
                rows.append((step, p, person.getPosition(p), person.getAngle(p), person.getSpeed(p),
                             person.getTypeID(p)))
        libsumo.close()
        return time.perf_counter() - wall0, time.process_time() - cpu0


def run(quick: bool) -> dict[str, Any]:
    if quick:
        config = SimulationConfig(logs=4, duration_s=10.0, seed=0, warmup_s=20.0)
    else:
        config = SimulationConfig(logs=8, duration_s=25.0, seed=0)  # the embedded demo's size
    cache = Path(tempfile.mkdtemp(prefix="bench-sim-cache-"))
    out = Path(tempfile.mkdtemp(prefix="bench-sim-out-"))
    try:
        config = SimulationConfig(**{**config.__dict__, "cache_dir": str(cache)})
        simulate_tracks_and_map(config, out / "warm")  # builds the network, loads SUMO: not timed
        result = simulate_tracks_and_map(config, out / "timed")
        pipeline_cpu_s = result.cpu_s
        step_wall_s, step_cpu_s = _reference_run(config, cache, poll=False)
        naive_wall_s, naive_cpu_s = _reference_run(config, cache, poll=True)
    finally:
        shutil.rmtree(cache, ignore_errors=True)
        shutil.rmtree(out, ignore_errors=True)
    sim_s = result.simulated_s
    return {
        "config": {"logs": config.logs, "duration_s": config.duration_s, "warmup_s": config.warmup_s,
                   "network": config.network.value, "egos_per_run": config.egos_per_run},
        "simulated_s": round(sim_s, 1),
        "log_seconds_written": config.logs * config.duration_s,
        "pipeline_wall_s": round(result.wall_s, 3),
        "pipeline_cpu_s": round(pipeline_cpu_s, 3),
        "pipeline_sumo_wall_s": round(result.sumo_wall_s, 3),
        "pipeline_sumo_cpu_s": round(result.sumo_cpu_s, 3),
        "realtime_factor_wall": round(sim_s / result.wall_s, 1),
        "realtime_factor_cpu": round(sim_s / pipeline_cpu_s, 1),
        "step_only_cpu_s": round(step_cpu_s, 3),
        "step_only_wall_s": round(step_wall_s, 3),
        "naive_polling_cpu_s": round(naive_cpu_s, 3),
        "naive_polling_wall_s": round(naive_wall_s, 3),
        "pipeline_vs_step_only_cpu": round(pipeline_cpu_s / step_cpu_s, 2),
        # Recording only (SUMO stepping + reading state): ours over naive polling (< 1: ours cheaper).
        "recording_cpu_vs_naive_polling": round(result.sumo_cpu_s / naive_cpu_s, 2),
        "target_realtime_factor": 50.0,
    }

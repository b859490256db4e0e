"""Seeded traffic demand for the simulated city: vehicle types, trips, walks, parked vehicles, egos.

Sizes are typical of the vehicles they stand for (length × width × height in metres); SUMO routes
each trip itself when it departs. Everything here depends only on the network and the seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

from scenes.categories import CATEGORY_TO_AV2, Category
from scenes.sim.netparse import SumoNet


@dataclass(frozen=True)
class VehicleType:
    """A SUMO vType with its box size and the AV2 label its tracks get."""

    id: str
    vclass: str
    category: Category
    length_m: float
    width_m: float
    height_m: float
    max_speed_mps: float
    #: Share of the generated vehicle trips (pedestrians and egos are generated separately).
    share: float

    @property
    def av2_label(self) -> str:
        return CATEGORY_TO_AV2[self.category]


VEHICLE_TYPES: tuple[VehicleType, ...] = (
    VehicleType("car", "passenger", Category.CAR, 4.6, 1.85, 1.5, 16.0, 0.68),
    VehicleType("truck", "truck", Category.TRUCK, 7.5, 2.4, 3.2, 13.0, 0.08),
    VehicleType("bus", "bus", Category.BUS, 12.0, 2.55, 3.2, 13.0, 0.05),
    VehicleType("motorcycle", "motorcycle", Category.MOTORCYCLE, 2.2, 0.8, 1.5, 16.0, 0.07),
    VehicleType("bicycle", "bicycle", Category.CYCLIST, 1.8, 0.65, 1.7, 5.5, 0.12),
)
PEDESTRIAN_TYPE = VehicleType("pedestrian", "pedestrian", Category.PEDESTRIAN, 0.5, 0.6, 1.75, 1.4, 0.0)
EGO_TYPE = VehicleType("ego", "passenger", Category.CAR, 4.6, 1.85, 1.5, 16.0, 0.0)
ALL_TYPES: dict[str, VehicleType] = {t.id: t for t in (*VEHICLE_TYPES, PEDESTRIAN_TYPE, EGO_TYPE)}

#: Parking bays: this far from each end of the lane, this long per vehicle.
PARKING_MARGIN_M = 15.0
PARKING_BAY_M = 8.0
MIN_PARKING_LANE_M = 50.0
#: SUMO ids of the vehicles parked for the whole run start with this.
PARKED_PREFIX = "parked_"


def ego_ids(count: int) -> list[str]:
    return [f"ego_{k}" for k in range(count)]


def _vtype_xml(t: VehicleType) -> str:
    common = (f'id="{t.id}" vClass="{t.vclass}" length="{t.length_m}" width="{t.width_m}" '
              f'height="{t.height_m}" maxSpeed="{t.max_speed_mps}"')
    if t.vclass == "pedestrian":
        return f"    <vType {common}/>"
    # Eager lane changing for speed gain: more lane changes and overtakes of cyclists.
    # Some impatience: drivers accept shorter gaps after waiting, as real ones do at busy junctions.
    behaviour = 'lcSpeedGain="2.0" lcKeepRight="0.5" speedDev="0.1" impatience="0.7" jmTimegapMinor="0.5"'
    return f"    <vType {common} {behaviour}/>"


@dataclass(frozen=True)
class Demand:
    """SUMO input files as text, plus the ids of the egos."""

    routes_xml: str
    additional_xml: str
    ego_ids: tuple[str, ...]
    road_edges: tuple[str, ...]


def make_demand(
    net: SumoNet,
    seed: int,
    end_s: float,
    num_egos: int,
    vehicles_per_s: float,
    pedestrians_per_s: float,
    parked_vehicles: int,
) -> Demand:
    """Trips, walks, parked vehicles and egos for a run of ``end_s`` simulated seconds."""
    rng = np.random.default_rng([seed, 0x5EED])
    # Trips start and end in the largest strongly connected part: no trip is unroutable and no
    # vehicle (an ego least of all) ends up in a dead end.
    car_edges = net.connected_edges("passenger")
    if len(car_edges) < 2:
        raise ValueError("the network has fewer than two connected roads open to cars")
    reachable = set(car_edges)
    walk_edges = [e for e in net.road_edges("pedestrian") if e in reachable]
    entries: list[tuple[float, str]] = []

    for k, ego in enumerate(ego_ids(num_egos)):
        a, b = rng.choice(len(car_edges), size=2, replace=False)
        entries.append((0.0, f'    <trip id="{ego}" type="ego" depart="0.00" from={quoteattr(car_edges[a])} '
                             f'to={quoteattr(car_edges[b])} departLane="best" departPos="{10 + 5 * k}"/>'))

    connected = {t.vclass: net.connected_edges(t.vclass) or car_edges for t in VEHICLE_TYPES}
    shares = np.array([t.share for t in VEHICLE_TYPES])
    n_veh = int(rng.poisson(vehicles_per_s * end_s))
    departs = np.sort(rng.uniform(0.0, end_s, n_veh))
    kinds = rng.choice(len(VEHICLE_TYPES), size=n_veh, p=shares / shares.sum())
    for i, (depart, kind) in enumerate(zip(departs, kinds)):
        vtype = VEHICLE_TYPES[kind]
        edges = connected[vtype.vclass]
        a, b = rng.choice(len(edges), size=2, replace=False)
        entries.append((float(depart), f'    <trip id="v{i}" type="{vtype.id}" depart="{depart:.2f}" '
                                       f'from={quoteattr(edges[a])} to={quoteattr(edges[b])} '
                                       f'departLane="best" departPos="random" departSpeed="max"/>'))

    if len(walk_edges) >= 2:
        n_ped = int(rng.poisson(pedestrians_per_s * end_s))
        departs = np.sort(rng.uniform(0.0, end_s, n_ped))
        for i, depart in enumerate(departs):
            a, b = rng.choice(len(walk_edges), size=2, replace=False)
            entries.append((float(depart), f'    <person id="p{i}" type="pedestrian" depart="{depart:.2f}" '
                                           f'departPos="random"><walk from={quoteattr(walk_edges[a])} '
                                           f'to={quoteattr(walk_edges[b])} arrivalPos="random"/></person>'))

    # Parking: bays beside the rightmost car lane of randomly chosen long roads; vehicles start parked.
    additional = ["<additional>"]
    candidates = []
    for lane in sorted(net.lanes.values(), key=lambda ln: ln.id):
        if lane.edge_function != "" or "passenger" not in lane.allowed or lane.edge_id not in reachable:
            continue
        same_edge = [ln for ln in net.lanes.values() if ln.edge_id == lane.edge_id and "passenger" in ln.allowed]
        if lane.index != min(ln.index for ln in same_edge):
            continue
        length = lane.length_m
        if length >= MIN_PARKING_LANE_M:
            candidates.append((lane, length))
    parked = 0
    if candidates and parked_vehicles > 0:
        order = rng.permutation(len(candidates))
        for j in order:
            if parked >= parked_vehicles:
                break
            lane, length = candidates[j]
            capacity = int((length - 2 * PARKING_MARGIN_M) // PARKING_BAY_M)
            if capacity < 1:
                continue
            pa_id = f"pa_{lane.id}"
            additional.append(f'    <parkingArea id={quoteattr(pa_id)} lane={quoteattr(lane.id)} '
                              f'startPos="{PARKING_MARGIN_M}" endPos="{length - PARKING_MARGIN_M:.2f}" '
                              f'roadsideCapacity="{capacity}"/>')
            fill = int(rng.integers(1, capacity + 1))
            for bay in range(min(fill, parked_vehicles - parked)):
                vtype = "truck" if rng.random() < 0.1 else "car"
                # Each vehicle starts beside its own bay, inside the stop's range, a moment after the
                # previous one: it parks at once instead of queueing behind the others for insertion.
                depart_pos = PARKING_MARGIN_M + (bay + 1) * PARKING_BAY_M - 0.5
                depart_s = 0.5 * bay
                entries.append((depart_s, f'    <trip id="{PARKED_PREFIX}{parked}" type="{vtype}" '
                                          f'depart="{depart_s:.2f}" from={quoteattr(lane.edge_id)} '
                                          f'to={quoteattr(lane.edge_id)} departPos="{depart_pos:.2f}">'
                                          f'<stop parkingArea={quoteattr(pa_id)} duration="1000000"/></trip>'))
                parked += 1
    additional.append("</additional>")

    entries.sort(key=lambda e: e[0])  # SUMO wants departures in order; the sort is stable
    lines = ["<routes>", *(_vtype_xml(t) for t in ALL_TYPES.values()), *(e[1] for e in entries), "</routes>"]
    return Demand("\n".join(lines) + "\n", "\n".join(additional) + "\n", tuple(ego_ids(num_egos)),
                  tuple(car_edges))

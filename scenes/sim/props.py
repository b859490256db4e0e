"""What stands still in the simulated city: street furniture and people waiting on the pavement.

SUMO moves traffic; it has no cones, bollards, barrels or signs, and its pedestrians walk from the
moment they depart. Real logs are full of both: in AV2 the ``other`` category (street furniture,
road works) and pedestrians who stand are a large share of the tracks, and a model that never saw
them in training reads them as nothing it knows. So they are placed here, seeded, on the sidewalks
of the network, and enter each ego's recording as rows like SUMO's own (speed 0, no lane), within
the same context radius. Their behaviour labels follow from those rows: they stand (``stopped``).

Furniture comes in groups along the curb (a row of bollards, cones around works); people stand
alone or in small groups anywhere across the sidewalk, facing any way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scenes.categories import Category
from scenes.geometry import FloatArray
from scenes.sim.netparse import SumoLane, SumoNet
from scenes.sim.runner import ObjectRows

#: SUMO-style ids of the placed objects start with this (their track ids derive from it).
PROP_PREFIX = "prop_"
#: No object stands closer than this to either end of a sidewalk (the junction's corner).
END_MARGIN_M = 4.0
#: Furniture stands this far inside the sidewalk from its curb edge.
CURB_INSET_M = 0.35


@dataclass(frozen=True)
class PropType:
    """One kind of standing object: its box, the AV2 label its tracks get and how it is placed.

    Attributes:
        id: the ``type_id`` of its rows.
        category: public category.
        av2_label: label written in ``annotations.feather``.
        length_m, width_m, height_m: box size.
        group_min, group_max: objects per group (inclusive).
        spacing_m: distance between neighbours of a group, along the sidewalk.
        at_curb: along the curb edge of the sidewalk (furniture); else anywhere across it (people).
        share: share of the groups of its kind (within furniture, or within people).
    """

    id: str
    category: Category
    av2_label: str
    length_m: float
    width_m: float
    height_m: float
    group_min: int
    group_max: int
    spacing_m: float
    at_curb: bool
    share: float


#: Street furniture, sizes typical of AV2's boxes of each label.
FURNITURE_TYPES: tuple[PropType, ...] = (
    PropType("cone", Category.OTHER, "CONSTRUCTION_CONE", 0.4, 0.4, 0.7, 2, 6, 2.0, True, 0.3),
    PropType("bollard", Category.OTHER, "BOLLARD", 0.25, 0.25, 1.0, 2, 5, 1.5, True, 0.25),
    PropType("barrel", Category.OTHER, "CONSTRUCTION_BARREL", 0.6, 0.6, 1.0, 1, 3, 1.2, True, 0.15),
    PropType("sign", Category.OTHER, "SIGN", 0.15, 0.7, 2.3, 1, 1, 0.0, True, 0.3),
)
STANDING_PEDESTRIAN_TYPE = PropType("standing_pedestrian", Category.PEDESTRIAN, "PEDESTRIAN",
                                    0.5, 0.6, 1.75, 1, 3, 0.8, False, 1.0)
PROP_TYPES: dict[str, PropType] = {t.id: t for t in (*FURNITURE_TYPES, STANDING_PEDESTRIAN_TYPE)}


@dataclass(frozen=True)
class Props:
    """Every placed object of a run, city frame.

    Attributes:
        sumo_id: (P,) id (:data:`PROP_PREFIX` + number).
        type_id: (P,) :data:`PROP_TYPES` key.
        center_xy_m: (P, 2) box centre.
        yaw_rad: (P,) heading, 0 along +x, counter-clockwise.
    """

    sumo_id: NDArray[np.str_]
    type_id: NDArray[np.str_]
    center_xy_m: FloatArray
    yaw_rad: FloatArray

    def __len__(self) -> int:
        return int(self.sumo_id.shape[0])


def sidewalks(net: SumoNet) -> list[SumoLane]:
    """Lanes of normal edges open to pedestrians only, sorted by id (the placement's order)."""
    return sorted((lane for lane in net.lanes.values() if lane.edge_function == "" and lane.allowed == {"pedestrian"}),
                  key=lambda lane: lane.id)


def _point_on(shape_xy_m: FloatArray, s_m: float, left_m: float) -> tuple[FloatArray, float]:
    """The point ``s_m`` along a polyline and ``left_m`` to its left, and the polyline's heading there."""
    seg = np.diff(shape_xy_m, axis=0)  # (S, 2)
    seg_len = np.linalg.norm(seg, axis=1)
    ends = np.cumsum(seg_len)
    i = min(int(np.searchsorted(ends, s_m)), len(seg) - 1)
    along = s_m - (ends[i] - seg_len[i])
    direction = seg[i] / max(float(seg_len[i]), 1e-9)
    normal = np.array([-direction[1], direction[0]])
    return shape_xy_m[i] + along * direction + left_m * normal, float(np.arctan2(direction[1], direction[0]))


def place_props(net: SumoNet, seed: int, furniture_per_km: float, standing_per_km: float) -> Props:
    """Groups of street furniture and of standing people on the network's sidewalks.

    The number of groups of each is Poisson with mean ``*_per_km`` × the sidewalks' length in km;
    each group lies on a sidewalk drawn in proportion to its length. A sidewalk is the rightmost
    lane of its edge, so its curb (the road side) is its left edge. Depends only on the network
    and the seed.
    """
    rng = np.random.default_rng([seed, 0x960])
    lanes = [lane for lane in sidewalks(net) if lane.length_m > 2 * END_MARGIN_M]
    lengths = np.array([lane.length_m for lane in lanes])
    ids: list[str] = []
    types: list[str] = []
    centers: list[FloatArray] = []
    yaws: list[float] = []
    if not lanes:
        return Props(np.zeros(0, np.str_), np.zeros(0, np.str_), np.zeros((0, 2)), np.zeros(0))
    km = float(lengths.sum()) / 1000.0
    furniture_share = np.array([t.share for t in FURNITURE_TYPES])
    groups: list[PropType] = [
        FURNITURE_TYPES[k] for k in rng.choice(len(FURNITURE_TYPES), size=int(rng.poisson(furniture_per_km * km)),
                                               p=furniture_share / furniture_share.sum())
    ]
    groups += [STANDING_PEDESTRIAN_TYPE] * int(rng.poisson(standing_per_km * km))
    for kind in groups:
        j = int(rng.choice(len(lanes), p=lengths / lengths.sum()))
        lane, length = lanes[j], float(lengths[j])
        size = int(rng.integers(kind.group_min, kind.group_max + 1))
        span = kind.spacing_m * (size - 1)
        if span > length - 2 * END_MARGIN_M:
            size, span = 1, 0.0
        start = float(rng.uniform(END_MARGIN_M, length - END_MARGIN_M - span))
        half_width = 0.5 * lane.width_m
        for m in range(size):
            if kind.at_curb:
                left = half_width - CURB_INSET_M
                yaw_offset = 0.0
            else:
                left = float(rng.uniform(-half_width + 0.3, half_width - 0.3))
                yaw_offset = float(rng.uniform(-np.pi, np.pi))
            xy, heading = _point_on(lane.shape_xy_m, start + m * kind.spacing_m, left)
            ids.append(f"{PROP_PREFIX}{len(ids)}")
            types.append(kind.id)
            centers.append(xy)
            yaws.append(heading + yaw_offset)
    return Props(np.asarray(ids, dtype=np.str_), np.asarray(types, dtype=np.str_),
                 np.asarray(centers, dtype=np.float64).reshape(-1, 2), np.asarray(yaws, dtype=np.float64))


def prop_rows(props: Props, ego: ObjectRows, radius_m: float) -> ObjectRows:
    """Rows of the placed objects within ``radius_m`` of the ego, at each of the ego's steps.

    As SUMO reports its objects: the front of the box (``front_xy_m``), a compass heading in degrees
    clockwise from north, speed 0, no lane and no leader. People are persons (``is_person``).
    """
    if len(props) == 0 or ego.step.shape[0] == 0:
        return ego.select(np.zeros(0, dtype=np.int64))
    near = np.linalg.norm(props.center_xy_m[None, :, :] - ego.front_xy_m[:, None, :], axis=2) <= radius_m  # (S, P)
    step_idx, prop_idx = np.nonzero(near)
    n = prop_idx.shape[0]
    length = np.array([PROP_TYPES[str(t)].length_m for t in props.type_id])[prop_idx]
    yaw = props.yaw_rad[prop_idx]
    front = props.center_xy_m[prop_idx] + 0.5 * length[:, None] * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    is_person = np.array([PROP_TYPES[str(t)].category == Category.PEDESTRIAN for t in props.type_id])[prop_idx]
    return ObjectRows(
        step=ego.step[step_idx],
        sumo_id=props.sumo_id[prop_idx],
        type_id=props.type_id[prop_idx],
        is_person=is_person,
        front_xy_m=front,
        angle_deg=np.mod(90.0 - np.rad2deg(yaw), 360.0),
        speed_mps=np.zeros(n),
        accel_mps2=np.zeros(n),
        lane_id=np.full(n, "", dtype=np.str_),
        lane_index=np.full(n, -1, dtype=np.int64),
        lateral_m=np.zeros(n),
        stop_state=np.zeros(n, dtype=np.int64),
        leader_id=np.full(n, "", dtype=np.str_),
        leader_gap_m=np.full(n, np.inf),
        leader_speed_mps=np.full(n, np.nan),
        leader_accel_mps2=np.full(n, np.nan),
        lane_pos_m=np.zeros(n),
    )

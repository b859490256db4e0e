"""The vocabulary of spatio-temporal tagging: attributes, their kinds, and scene regions.

Attributes (:class:`Attribute`, the string values are the public vocabulary of files and queries)
after Segal et al., "Universal Embeddings for Spatio-Temporal Tagging of Self-Driving Logs":

=====================  ==========  ==================================================================
attribute              kind        ground truth per BEV cell (rasterised from the log's boxes and
                                   the simulator's behaviour labels, see :mod:`encoders.tagging.targets`)
=====================  ==========  ==================================================================
vehicle_density        continuous  fraction of the cell covered by vehicle boxes (car, truck, bus,
                                   motorcycle), in [0, 1]
pedestrian_density     continuous  fraction of the cell covered by pedestrian boxes, in [0, 1] (learned
                                   as presence, see :data:`FOOTPRINT_M2`)
vehicle_speed          continuous  speed (m/s) of the vehicle whose box holds the cell centre, 0 elsewhere
parked … braking_for   discrete    1 inside the box of a vehicle with that behaviour label
three_way, four_way    discrete    1 in the area of a junction of that kind (``junctions.feather``): its
                                   outline and the last 20 m of the lanes entering it, where the
                                   behaviour labels put a vehicle at the junction
=====================  ==========  ==================================================================

Regions (:class:`Region`), in the ego frame (x forward, y left, metres; the ego origin is the
rear axle, as everywhere in the project):

- ``full``: the whole BEV grid.
- ``front``: ahead of the ego, 0 m < x ≤ 50 m and |y| ≤ 10 m (about three lanes to each side).
- ``behind``: −20 m ≤ x < 0 m and |y| ≤ 10 m.
- ``around``: within 15 m of the ego origin (a disc).
- ``intersection``: cells on the map's junction lanes (the ``intersection`` map channel).
- ``crosswalk``: cells on the map's pedestrian crossings (the ``crossing`` map channel).

The last two need the log's map; the ego-relative ones always work.
"""

from __future__ import annotations

from enum import StrEnum
from typing import TypeVar

from scenes.behavior import BehaviorLabel, JunctionKind
from scenesearch_base import config as base_config

_Choice = TypeVar("_Choice", bound=StrEnum)


class TagError(ValueError):
    """Bad tagging input: unknown attribute or region, malformed composition, missing map or labels."""


class AttributeKind(StrEnum):
    """How an attribute is predicted, trained, pooled and evaluated."""

    #: Regressed per cell (smooth L1), pooled with sum (densities) or max (speed), scored by L1.
    CONTINUOUS = "continuous"
    #: A per-cell logit (cross entropy with hard negatives), pooled with max of sigmoid, scored by F1.
    DISCRETE = "discrete"


class Attribute(StrEnum):
    """Tagging attributes; the values are the public vocabulary.

    The behaviour and junction attributes take their words from :mod:`scenes.behavior` (the
    columns of the behaviour labels and the junction kinds), so a label renamed there is renamed
    here too.
    """

    VEHICLE_DENSITY = "vehicle_density"
    PEDESTRIAN_DENSITY = "pedestrian_density"
    VEHICLE_SPEED = "vehicle_speed"
    PARKED = BehaviorLabel.PARKED.value
    STOPPED = BehaviorLabel.STOPPED.value
    BRAKING = BehaviorLabel.BRAKING.value
    KEEPING_LANE = BehaviorLabel.KEEPING_LANE.value
    LEFT_TURN = BehaviorLabel.LEFT_TURN.value
    RIGHT_TURN = BehaviorLabel.RIGHT_TURN.value
    LEFT_LANE_CHANGE = BehaviorLabel.LEFT_LANE_CHANGE.value
    RIGHT_LANE_CHANGE = BehaviorLabel.RIGHT_LANE_CHANGE.value
    BLOCKED_BY = BehaviorLabel.BLOCKED_BY.value
    BRAKING_FOR = BehaviorLabel.BRAKING_FOR.value
    THREE_WAY = JunctionKind.THREE_WAY.value
    FOUR_WAY = JunctionKind.FOUR_WAY.value

    @property
    def kind(self) -> AttributeKind:
        return AttributeKind.CONTINUOUS if self in CONTINUOUS else AttributeKind.DISCRETE

    @property
    def is_density(self) -> bool:
        return self in DENSITIES


class Region(StrEnum):
    """Scene regions for pooling tag tensors (metre definitions in the module docstring)."""

    FULL = "full"
    FRONT = "front"
    BEHIND = "behind"
    AROUND = "around"
    INTERSECTION = "intersection"
    CROSSWALK = "crosswalk"

    @property
    def needs_map(self) -> bool:
        return self in (Region.INTERSECTION, Region.CROSSWALK)


CONTINUOUS: frozenset[Attribute] = frozenset(
    {Attribute.VEHICLE_DENSITY, Attribute.PEDESTRIAN_DENSITY, Attribute.VEHICLE_SPEED}
)
DENSITIES: frozenset[Attribute] = frozenset({Attribute.VEHICLE_DENSITY, Attribute.PEDESTRIAN_DENSITY})
#: Attributes taken from the behaviour-label columns of the same name, in the labels' order.
BEHAVIOR_ATTRIBUTES: tuple[Attribute, ...] = tuple(Attribute(label.value) for label in BehaviorLabel)
#: Attributes marking the area of a junction of the kind of the same name.
JUNCTION_ATTRIBUTES: tuple[Attribute, ...] = (Attribute.THREE_WAY, Attribute.FOUR_WAY)
#: All attributes in the order of the rows of A and of the target channels.
ATTRIBUTES: tuple[Attribute, ...] = tuple(Attribute)

#: Regions that are boxes in the ego frame: (x_min_m, x_max_m, y_abs_max_m); ``around`` is a disc.
FRONT_X_M = (0.0, 50.0)
BEHIND_X_M = (-20.0, 0.0)
SIDE_Y_ABS_M = 10.0
AROUND_RADIUS_M = 15.0

#: Densities of objects much smaller than a cell of E, learned as *presence*: the head's row is a logit that
#: such an object is in the cell (cross entropy with hard negatives, as for discrete attributes, in a loss
#: term of its own), read as its probability p where p ≥ :data:`PRESENCE_THRESHOLD` (0 elsewhere) times the
#: object's footprint, a share of the cell. Why: a pedestrian covers about 6 % of a 2.5 m cell of E, in
#: very few of the cells, so regressing the covered fraction (smooth L1 over every cell) left the row at noise
#: whatever its scale, and the sum of that noise over a region drowned the few pedestrians. The demo's
#: tower trained for tags alone on the demo's clips: regressed, the validation calibration kept a constant,
#: above the statistics' L1; as presence, below the statistics in all six regions
#: (``docs/research/tagging.md``). Joint training (beside the contrastive losses) learns it so too,
#: with a stronger presence term (``TagTrainConfig.joint_presence_weight``) on a tower whose first stage
#: has 16 channels (``BevConfig.widths``).
FOOTPRINT_M2: dict[str, float] = {Attribute.PEDESTRIAN_DENSITY.value: 0.36}  # a 0.6 m × 0.6 m pedestrian box
#: A cell counts an object learned as presence where its probability is at least this.
PRESENCE_THRESHOLD = 0.5

#: Output scale of continuous attributes: the head regresses target / scale (speed in units of 10 m/s).
OUTPUT_SCALE: dict[str, float] = {Attribute.VEHICLE_SPEED.value: 10.0}


def attribute_kind(name: str) -> AttributeKind:
    """Kind of a built-in attribute, or ``discrete`` for attributes added later (see :mod:`.extend`)."""
    try:
        return Attribute(name).kind
    except ValueError:
        return AttributeKind.DISCRETE


def is_density(name: str) -> bool:
    return name in {a.value for a in DENSITIES}


def parse_attribute(name: str, valid: tuple[str, ...] | list[str] | None = None) -> str:
    """Check an attribute name against ``valid`` (default: the built-in vocabulary).

    Raises:
        TagError: listing the valid attributes.
    """
    names = list(valid) if valid is not None else [a.value for a in Attribute]
    key = str(name).strip()
    if key not in names:
        raise TagError(f"unknown attribute {name!r}; valid attributes: {', '.join(names)}")
    return key


def parse_choice(choices: type[_Choice], value: str | _Choice, what: str, valid: str) -> _Choice:
    """The member of ``choices`` named ``value`` (surrounding spaces ignored).

    Raises:
        TagError: ``unknown <what> ...; <valid>: <the valid names>``.
    """
    return base_config.parse_choice(choices, str(value).strip(), what, valid, error=TagError)


def parse_region(name: str) -> Region:
    """``Region`` from its name.

    Raises:
        TagError: listing the valid regions.
    """
    return parse_choice(Region, name, "region", "valid regions")

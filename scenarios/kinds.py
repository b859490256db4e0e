"""Kinds of objects a program names: dataset labels, the public categories, and groups of them.

A kind is matched against both an object's dataset label (AV2's vocabulary, which real logs carry)
and its public category (:class:`scenes.categories.Category`, which every log has), so ``bus`` finds
AV2's ``BUS``, ``ARTICULATED_BUS`` and ``SCHOOL_BUS`` and a simulated bus alike, while ``school_bus``
needs a log that says so. Groups follow RefAV's: ``vehicle`` is every motor vehicle but motorcycles,
``vulnerable_road_user`` everyone outside a vehicle's shell.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scenarios.program import Node, Objects
from scenes.categories import AV2_TO_CATEGORY, EGO_VEHICLE_LABEL

#: kind → (dataset labels, public categories) it covers.
KINDS: dict[str, tuple[frozenset[str], frozenset[str]]] = {}


def _kind(name: str, labels: set[str], categories: frozenset[str] | set[str] = frozenset()) -> None:
    KINDS[name] = (frozenset(labels), frozenset(categories))


for _label in AV2_TO_CATEGORY:  # every AV2 label is a kind of its own: regular_vehicle, school_bus, ...
    _kind(_label.lower(), {_label})
_VEHICLES = {"REGULAR_VEHICLE", "LARGE_VEHICLE", "BUS", "BOX_TRUCK", "TRUCK", "VEHICULAR_TRAILER", "TRUCK_CAB",
             "SCHOOL_BUS", "ARTICULATED_BUS", "MESSAGE_BOARD_TRAILER", "RAILED_VEHICLE"}
_kind("vehicle", _VEHICLES, {"car", "truck", "bus"})
_kind("car", {"REGULAR_VEHICLE"}, {"car"})
_kind("truck", {"BOX_TRUCK", "TRUCK", "TRUCK_CAB", "LARGE_VEHICLE"}, {"truck"})
_kind("bus", {"BUS", "ARTICULATED_BUS", "SCHOOL_BUS"}, {"bus"})
_kind("pedestrian", {"PEDESTRIAN", "OFFICIAL_SIGNALER"}, {"pedestrian"})
_kind("cyclist", {"BICYCLIST", "BICYCLE", "WHEELED_RIDER"}, {"cyclist"})
_kind("motorcycle", {"MOTORCYCLIST", "MOTORCYCLE"}, {"motorcycle"})
_kind("vulnerable_road_user", {"PEDESTRIAN", "OFFICIAL_SIGNALER", "BICYCLIST", "BICYCLE", "WHEELED_RIDER",
                               "MOTORCYCLIST", "MOTORCYCLE", "WHEELCHAIR", "STROLLER", "WHEELED_DEVICE"},
      {"pedestrian", "cyclist", "motorcycle"})
_kind("construction", {"CONSTRUCTION_CONE", "CONSTRUCTION_BARREL", "BOLLARD", "MESSAGE_BOARD_TRAILER"})
_kind("animal", {"ANIMAL", "DOG"})  # a dog is an animal too
_kind("any", set(AV2_TO_CATEGORY), {"car", "truck", "bus", "pedestrian", "cyclist", "motorcycle", "other"})
_kind("ego", {EGO_VEHICLE_LABEL}, {"ego"})

#: Names of the kinds, sorted (the vocabulary of the program syntax).
KIND_NAMES: tuple[str, ...] = tuple(sorted(KINDS))


def within_kinds(kind: str, group: tuple[str, ...]) -> bool:
    """Whether every dataset label of ``kind`` is one of ``group``'s kinds' ("car" is within "vehicle")."""
    covered = frozenset().union(*(KINDS[g][0] for g in group))
    return bool(KINDS[kind][0]) and KINDS[kind][0] <= covered


def within_vehicles(node: Node) -> bool:
    """Whether ``node`` names objects of a vehicle kind (a bus, "vehicle"; not "any")."""
    return isinstance(node, Objects) and node.kind != "any" and within_kinds(node.kind, ("vehicle",))


def kind_mask(kind: str, labels: NDArray[np.str_], categories: NDArray[np.str_]) -> NDArray[np.bool_]:
    """(K,) the objects of ``kind`` among objects with these (K,) labels and (K,) public categories.

    ``any`` never includes the ego: the ego is named as ``ego``.

    Raises:
        KeyError: ``kind`` is not among :data:`KIND_NAMES`.
    """
    covered_labels, covered_categories = KINDS[kind]
    mask = np.isin(labels, list(covered_labels)) | np.isin(categories, list(covered_categories))
    # A log that carries dataset labels names its objects by them: its public category only stands in
    # for a label the log does not have (a simulated or KITTI log labels every car REGULAR_VEHICLE).
    known = np.isin(labels, list(AV2_TO_CATEGORY)) | (labels == EGO_VEHICLE_LABEL)
    by_label = np.isin(labels, list(covered_labels))
    return np.where(known, by_label, mask) if kind != "any" else mask & (labels != EGO_VEHICLE_LABEL)

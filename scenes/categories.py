"""Object categories: the small public vocabulary used in captions, filters and files.

Raw dataset labels (AV2 categories, KITTI types, simulator vehicle classes) map onto
:class:`Category`. Unknown labels map to ``other`` and are counted by the caller, never dropped.
"""

from __future__ import annotations

from enum import StrEnum


class Category(StrEnum):
    """Public object categories. The string values are the vocabulary of files and queries."""

    CAR = "car"
    TRUCK = "truck"
    BUS = "bus"
    PEDESTRIAN = "pedestrian"
    CYCLIST = "cyclist"
    MOTORCYCLE = "motorcycle"
    OTHER = "other"


#: The public vocabulary in its fixed order (files, filters, and the rows of the model's category table).
CATEGORY_NAMES: tuple[str, ...] = tuple(c.value for c in Category)

#: The ego's own box in some AV2 annotation tables. It is never a neighbour.
EGO_VEHICLE_LABEL = "EGO_VEHICLE"

AV2_TO_CATEGORY: dict[str, Category] = {
    "REGULAR_VEHICLE": Category.CAR,
    "LARGE_VEHICLE": Category.TRUCK,
    "BOX_TRUCK": Category.TRUCK,
    "TRUCK": Category.TRUCK,
    "TRUCK_CAB": Category.TRUCK,
    "VEHICULAR_TRAILER": Category.TRUCK,
    "RAILED_VEHICLE": Category.BUS,
    "BUS": Category.BUS,
    "ARTICULATED_BUS": Category.BUS,
    "SCHOOL_BUS": Category.BUS,
    "PEDESTRIAN": Category.PEDESTRIAN,
    "OFFICIAL_SIGNALER": Category.PEDESTRIAN,
    "BICYCLIST": Category.CYCLIST,
    "BICYCLE": Category.CYCLIST,
    "WHEELED_RIDER": Category.CYCLIST,
    "MOTORCYCLIST": Category.MOTORCYCLE,
    "MOTORCYCLE": Category.MOTORCYCLE,
    "WHEELED_DEVICE": Category.OTHER,
    "STROLLER": Category.OTHER,
    "WHEELCHAIR": Category.OTHER,
    "DOG": Category.OTHER,
    "BOLLARD": Category.OTHER,
    "CONSTRUCTION_CONE": Category.OTHER,
    "CONSTRUCTION_BARREL": Category.OTHER,
    "STOP_SIGN": Category.OTHER,
    "SIGN": Category.OTHER,
    "MESSAGE_BOARD_TRAILER": Category.OTHER,
    "MOBILE_PEDESTRIAN_CROSSING_SIGN": Category.OTHER,
    "MOBILE_PEDESTRIAN_SIGN": Category.OTHER,
    "ANIMAL": Category.OTHER,
}

KITTI_TO_CATEGORY: dict[str, Category] = {
    "Car": Category.CAR,
    "Van": Category.CAR,
    "Truck": Category.TRUCK,
    "Tram": Category.BUS,
    "Pedestrian": Category.PEDESTRIAN,
    "Person_sitting": Category.PEDESTRIAN,
    "Person": Category.PEDESTRIAN,
    "Cyclist": Category.CYCLIST,
    "Misc": Category.OTHER,
}

#: The AV2 label written for each public category when a log is converted into the AV2 layout.
CATEGORY_TO_AV2: dict[Category, str] = {
    Category.CAR: "REGULAR_VEHICLE",
    Category.TRUCK: "BOX_TRUCK",
    Category.BUS: "BUS",
    Category.PEDESTRIAN: "PEDESTRIAN",
    Category.CYCLIST: "BICYCLIST",
    Category.MOTORCYCLE: "MOTORCYCLIST",
    Category.OTHER: "WHEELED_DEVICE",
}

VEHICLE_CATEGORIES: frozenset[Category] = frozenset(
    {Category.CAR, Category.TRUCK, Category.BUS, Category.MOTORCYCLE}
)


def category_from_label(label: str) -> Category | None:
    """Map a raw AV2 or KITTI label (or a public category name) onto the public vocabulary.

    Returns ``None`` for labels that are not known; callers map those to ``other`` and count them.
    """
    if label in AV2_TO_CATEGORY:
        return AV2_TO_CATEGORY[label]
    if label != label.strip():  # "PEDESTRIAN " from a hand-made table: the label it plainly is
        return category_from_label(label.strip())
    if label.upper() in AV2_TO_CATEGORY:  # AV2's labels written in another case
        return AV2_TO_CATEGORY[label.upper()]
    if label in KITTI_TO_CATEGORY:
        return KITTI_TO_CATEGORY[label]
    try:
        return Category(label.lower())
    except ValueError:
        return None

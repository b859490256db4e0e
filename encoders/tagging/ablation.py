"""Input ablation: which BEV inputs a model sees (Segal et al., Table 2).

``none`` (no inputs: what dataset statistics alone predict), ``map`` (map channels only), ``lidar``
(LiDAR occupancy only) or ``both``. A masked input is replaced by zeros, in training and at query
time alike, so the architecture (and E's shape) never changes.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import torch

from encoders.tagging.attributes import parse_choice


class Inputs(StrEnum):
    """Which BEV inputs reach the backbone."""

    NONE = "none"
    MAP = "map"
    LIDAR = "lidar"
    BOTH = "both"

    @property
    def uses_lidar(self) -> bool:
        return self in (Inputs.LIDAR, Inputs.BOTH)

    @property
    def uses_map(self) -> bool:
        return self in (Inputs.MAP, Inputs.BOTH)


def parse_inputs(value: str | Inputs) -> Inputs:
    """``Inputs`` from its name.

    Raises:
        TagError: listing the valid inputs.
    """
    return parse_choice(Inputs, value, "inputs", "valid")


def mask_inputs(batch: dict[str, Any], inputs: str | Inputs) -> dict[str, Any]:
    """A shallow copy of ``batch`` with the unused BEV inputs zeroed.

    Args:
        batch: collated clips with ``bev_lidar`` (B, T, Cl, H, W) and ``bev_map`` (B, T, Cm, H, W).
        inputs: ``none``, ``map``, ``lidar`` or ``both``.
    """
    which = parse_inputs(inputs)
    if which == Inputs.BOTH:
        return batch
    out = dict(batch)
    if not which.uses_lidar:
        out["bev_lidar"] = torch.zeros_like(torch.as_tensor(batch["bev_lidar"]))
    if not which.uses_map:
        out["bev_map"] = torch.zeros_like(torch.as_tensor(batch["bev_map"]))
    return out

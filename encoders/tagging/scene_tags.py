"""Scene tags: tag tensors pooled over regions, and compositions of attributes (pure numpy).

- :func:`tag_tensor`: V = E · A[τ], the dot product over D_e (the head adds its bias and scale).
- :func:`region_masks`: the regions of :class:`~encoders.tagging.attributes.Region` on a grid.
- :func:`pool`: f_p over a region: **sum** for densities (times the cell area: m² covered), **max**
  for everything else (for discrete attributes over probabilities sigmoid(V); ``vehicle_speed``: the
  fastest vehicle in the region, m/s; a density learned as presence: its probability where at least
  0.5, times the object's share of the cell). An empty region pools to 0.
- :func:`compose`: g_AND = Π h(V_τ), g_OR = Σ h − AND for two operands (inclusion–exclusion
  1 − Π(1 − h) for any number, the same for two), with h the identity or the indicator 1{V ≥ κ}.
  Compositions are formed per cell, then pooled: "blocked_by & four_way" in front is the largest,
  over the cells in front, of P(blocked vehicle here) × P(4-way junction here).
- :func:`parse_tag_expression`: ``"blocked_by & four_way"``, ``"stopped | braking"``, ``"parked"``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from encoders.tagging.attributes import (
    AROUND_RADIUS_M,
    BEHIND_X_M,
    FRONT_X_M,
    PRESENCE_THRESHOLD,
    SIDE_Y_ABS_M,
    AttributeKind,
    Region,
    TagError,
    attribute_kind,
    is_density,
    parse_attribute,
    parse_region,
)
from scenes.bev import BevGrid

FloatArray = NDArray[np.float32]
#: Map channels (of the clip stage's ``bev_map``) behind the map-based regions, by the names the clip
#: stage has used for them.
REGION_MAP_CHANNELS: dict[Region, tuple[str, ...]] = {
    Region.INTERSECTION: ("intersections", "intersection"),
    Region.CROSSWALK: ("crosswalks", "crossing"),
}


def map_channel_index(map_channels: Sequence[str], region: Region) -> int:
    """Index of the map channel behind a map region.

    Raises:
        TagError: no channel of the region among ``map_channels``.
    """
    for name in REGION_MAP_CHANNELS[region]:
        if name in map_channels:
            return list(map_channels).index(name)
    raise TagError(f"region {region.value!r} needs a map channel named one of {list(REGION_MAP_CHANNELS[region])}; "
                   f"the channels are {list(map_channels)}")
OPS = ("and", "or")
TRANSFORMS = ("identity", "indicator")


def sigmoid(x: NDArray[np.floating]) -> FloatArray:
    return np.asarray(0.5 * (1.0 + np.tanh(0.5 * np.asarray(x, dtype=np.float32))), dtype=np.float32)


def tag_tensor(e: NDArray[np.floating], a: NDArray[np.floating], attribute: int) -> FloatArray:
    """V = E · A[τ].

    Args:
        e: (..., D_e, h, w) the universal embedding, e.g. (T, D_e, h, w).
        a: (|T|, D_e) attribute embeddings.
        attribute: τ, a row of ``a``.

    Returns:
        (..., h, w) float32.
    """
    return np.asarray(np.einsum("...dhw,d->...hw", np.asarray(e, np.float32), np.asarray(a, np.float32)[attribute]),
                      dtype=np.float32)


def coarse_grid(grid: BevGrid, factor: int) -> BevGrid:
    """The grid of E: the same extent with cells ``factor`` times larger."""
    return BevGrid(grid.x_min_m, grid.x_max_m, grid.y_min_m, grid.y_max_m, grid.resolution_m * factor)


def downsample_max(layers: NDArray[np.floating], factor: int) -> FloatArray:
    """(..., H, W) → (..., H/r, W/r) max over each r × r block."""
    x = np.asarray(layers, dtype=np.float32)
    if factor == 1:
        return x
    h, w = x.shape[-2] // factor, x.shape[-1] // factor
    x = x[..., : h * factor, : w * factor].reshape(*x.shape[:-2], h, factor, w, factor)
    return np.asarray(x.max(axis=(-3, -1)), dtype=np.float32)


def ego_region_mask(grid: BevGrid, region: Region) -> NDArray[np.bool_]:
    """(H, W) cells whose centre lies in an ego-relative region (see the attributes module)."""
    xy = grid.cell_centers_xy()
    x, y = xy[..., 0], xy[..., 1]
    if region == Region.FULL:
        return np.ones(grid.shape, bool)
    if region == Region.FRONT:
        return (x > FRONT_X_M[0]) & (x <= FRONT_X_M[1]) & (np.abs(y) <= SIDE_Y_ABS_M)
    if region == Region.BEHIND:
        return (x >= BEHIND_X_M[0]) & (x < BEHIND_X_M[1]) & (np.abs(y) <= SIDE_Y_ABS_M)
    if region == Region.AROUND:
        return np.hypot(x, y) <= AROUND_RADIUS_M
    raise TagError(f"region {region.value!r} is not ego-relative")


def region_masks(
    grid: BevGrid,
    map_layers: NDArray[np.floating] | None = None,
    map_channels: Sequence[str] = ("drivable_area", "lane_boundaries", "lane_direction_cos", "lane_direction_sin",
                                   "crosswalks", "intersections"),
) -> dict[Region, NDArray[np.bool_]]:
    """Every region on ``grid``.

    Args:
        grid: the grid of the tensors to pool (E's grid: :func:`coarse_grid`).
        map_layers: (..., Cm, H, W) the clip stage's map channels on ``grid`` (values in [0, 1] or
            uint8), e.g. (F, Cm, H, W); None for a log without a map.
        map_channels: names of the Cm channels.

    Returns:
        Region → bool mask: (H, W) for ego-relative regions, (..., H, W) for map regions, which are
        absent when ``map_layers`` is None.
    """
    out = {r: ego_region_mask(grid, r) for r in (Region.FULL, Region.FRONT, Region.BEHIND, Region.AROUND)}
    if map_layers is not None:
        layers = np.asarray(map_layers)
        if layers.shape[-2:] != grid.shape:
            raise TagError(f"map layers are {layers.shape[-2:]} cells, the grid is {grid.shape}")
        for region in REGION_MAP_CHANNELS:
            out[region] = layers[..., map_channel_index(map_channels, region), :, :] > 0
    return out


def region_mask(masks: dict[Region, NDArray[np.bool_]], region: Region | str, where: str = "") -> NDArray[np.bool_]:
    """One region of :func:`region_masks`.

    Raises:
        TagError: unknown region, or a map region of a log without a map.
    """
    r = parse_region(region) if isinstance(region, str) else region
    if r not in masks:
        raise TagError(f"{where + ': ' if where else ''}region {r.value!r} needs the log's map, and the log has "
                       f"none; regions that work without a map: {', '.join(x.value for x in masks)}")
    return masks[r]


def values_of(v: NDArray[np.floating], attribute: str, kind: AttributeKind | None = None,
              footprint_share: float | None = None) -> FloatArray:
    """What is pooled and composed: sigmoid(V) for discrete attributes, V itself for continuous ones.

    ``footprint_share`` (a density learned as presence, :meth:`TagHeadConfig.footprint_share`): V is the
    logit that such an object is in the cell; the value is the covered share of the cell expected from
    it, p · share where p ≥ :data:`PRESENCE_THRESHOLD`, else 0 (summing every cell's small p over a
    region would add up to objects that are not there).
    """
    if footprint_share is not None:
        p = sigmoid(v)
        return np.asarray(np.where(p >= PRESENCE_THRESHOLD, p * footprint_share, 0.0), dtype=np.float32)
    k = kind if kind is not None else attribute_kind(attribute)
    return sigmoid(v) if k == AttributeKind.DISCRETE else np.asarray(v, dtype=np.float32)


def pool_values(x: NDArray[np.floating], mask: NDArray[np.bool_], reduce: str, cell_area_m2: float = 1.0) -> FloatArray:
    """f_p of per-cell values.

    Args:
        x: (..., H, W) values (probabilities or continuous values).
        mask: (H, W) or (..., H, W) region.
        reduce: ``sum`` (× ``cell_area_m2``) or ``max`` (0 over an empty region).

    Returns:
        (...) float32.
    """
    xx = np.asarray(x, dtype=np.float32)
    m = np.broadcast_to(np.asarray(mask, bool), xx.shape)
    if reduce == "sum":
        return np.asarray(np.where(m, xx, 0.0).sum(axis=(-2, -1)) * cell_area_m2, dtype=np.float32)
    if reduce == "max":
        return _max_or_zero(xx, m)
    raise TagError(f"reduce must be 'sum' or 'max', got {reduce!r}")


def _max_or_zero(xx: FloatArray, m: NDArray[np.bool_]) -> FloatArray:
    out = np.where(m, xx, -np.inf).max(axis=(-2, -1), initial=-np.inf)
    return np.asarray(np.where(np.isfinite(out), out, 0.0), dtype=np.float32)


def reduction_of(attributes: Sequence[str]) -> str:
    """Pooling of an attribute or a composition: ``sum`` when a density takes part, else ``max``."""
    return "sum" if any(is_density(a) for a in attributes) else "max"


def pool(v: NDArray[np.floating], mask: NDArray[np.bool_], attribute: str, cell_area_m2: float = 1.0,
         kind: AttributeKind | None = None, footprint_m2: float | None = None) -> FloatArray:
    """Scene tag of one attribute: (..., H, W) tag tensor V (logits for discrete) → (...) pooled over ``mask``.

    ``footprint_m2``: one object's footprint, for a density learned as presence.
    """
    share = None if footprint_m2 is None else footprint_m2 / cell_area_m2
    return pool_values(values_of(v, attribute, kind, share), mask, reduction_of([attribute]), cell_area_m2)


def compose(tensors: Sequence[NDArray[np.floating]], op: str = "and", h: str = "identity",
            kappa: float = 0.5) -> FloatArray:
    """Compositional tag of per-cell values (probabilities or continuous values), all the same shape.

    ``and``: Π h(x_i); ``or``: 1 − Π (1 − h(x_i)) (= h1 + h2 − h1·h2 for two); h: identity or 1{x ≥ κ}.
    """
    if op not in OPS:
        raise TagError(f"unknown operator {op!r}; valid: {', '.join(OPS)}")
    if h not in TRANSFORMS:
        raise TagError(f"unknown transform {h!r}; valid: {', '.join(TRANSFORMS)}")
    if not tensors:
        raise TagError("compose needs at least one tensor")
    hs = [np.asarray(t, np.float32) if h == "identity" else (np.asarray(t) >= kappa).astype(np.float32)
          for t in tensors]
    out = hs[0].copy()
    if op == "and":
        for x in hs[1:]:
            out = out * x
        return out
    for x in hs[1:]:
        out = out + x - out * x
    return out


@dataclass(frozen=True)
class TagExpression:
    """A parsed tag query: attributes joined by one operator (``and`` for a single attribute)."""

    attributes: tuple[str, ...]
    op: str = "and"

    def __str__(self) -> str:
        return f" {'&' if self.op == 'and' else '|'} ".join(self.attributes)


def parse_tag_expression(text: str, valid: Sequence[str] | None = None) -> TagExpression:
    """``"blocked_by & four_way"`` (AND), ``"stopped | braking"`` (OR), ``"parked"``; ``and`` / ``or`` words work too.

    Raises:
        TagError: empty expression, unknown attribute (listing the valid ones), an attribute named
            twice, or ``&`` and ``|`` mixed.
    """
    s = str(text).strip()
    if not s:
        raise TagError("empty tag expression; write e.g. 'blocked_by & four_way' or 'stopped | braking'")
    s = re.sub(r"\s+(and|AND)\s+", " & ", s)
    s = re.sub(r"\s+(or|OR)\s+", " | ", s)
    has_and, has_or = "&" in s, "|" in s
    if has_and and has_or:
        raise TagError(f"tag expression {text!r} mixes '&' and '|'; use one operator")
    op = "or" if has_or else "and"
    parts = [p.strip() for p in re.split(r"[&|]", s)]
    if any(not p for p in parts):
        raise TagError(f"tag expression {text!r} has an empty operand")
    names = tuple(parse_attribute(p, list(valid) if valid is not None else None) for p in parts)
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise TagError(f"tag expression {text!r} names attribute {n!r} twice")
        seen.add(n)
    return TagExpression(names, op)

"""Attribute embeddings: the tag tensor of every attribute from the universal BEV embedding E.

    E (B, T, D_e, h, w) ── V_τ = s_τ · (E · A[τ] + b_τ) ──> V (B, T, |T|, h, w)

``A`` (|T|, D_e) holds one learned embedding per attribute; the dot product over D_e is
parameter-free, so every attribute shares the backbone (Segal et al.). ``b`` (|T|,) is a learned
per-attribute bias (equivalently a constant channel of E), which absorbs each attribute's base rate
so that A only has to encode *where*. ``s`` is a fixed output scale (1, or 10 for ``vehicle_speed``
so that V is in m/s while the dot product stays near unit range); the head's config records every
attribute's scale, so a saved head means what it meant when it was trained whatever the defaults
(:data:`~encoders.tagging.attributes.OUTPUT_SCALE`) become.

For discrete attributes V is a logit (probability = sigmoid(V)); for continuous ones V is the value,
except for densities learned as presence (``footprints``, see
:data:`~encoders.tagging.attributes.FOOTPRINT_M2`), whose V is the logit that such an object is in the cell.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from torch import nn

from encoders.tagging.attributes import (
    ATTRIBUTES,
    FOOTPRINT_M2,
    OUTPUT_SCALE,
    AttributeKind,
    TagError,
    attribute_kind,
    is_density,
)
from scenesearch_base.config import check_at_least


@dataclass(frozen=True)
class TagHeadConfig:
    """The attribute head.

    Attributes:
        attributes: attribute names, one row of A each (built-in vocabulary first; later additions
            are appended by :func:`encoders.tagging.extend.add_attributes`).
        embed_channels: D_e, channels of E.
        kinds: kind per added attribute not in the built-in vocabulary (name → ``discrete`` or
            ``continuous``); built-ins take theirs from :class:`~encoders.tagging.attributes.Attribute`.
        init_std: standard deviation of the initial rows of A.
        scales: output scale s per attribute; an attribute not named takes its default
            (:data:`~encoders.tagging.attributes.OUTPUT_SCALE`, else 1). Filled in for every attribute
            on construction, so ``tagging.json`` records them (files written before it had them read
            back with the defaults, which they were trained with).
        footprints: densities learned as presence, name → footprint (m²) of one object; None takes
            :data:`~encoders.tagging.attributes.FOOTPRINT_M2` for the attributes the head has. Files
            written before it read back with none (their densities were regressed).
    """

    attributes: tuple[str, ...] = tuple(a.value for a in ATTRIBUTES)
    embed_channels: int = 64
    kinds: dict[str, str] = field(default_factory=dict)
    init_std: float = 0.02
    scales: dict[str, float] = field(default_factory=dict)
    footprints: dict[str, float] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "attributes", tuple(str(a) for a in self.attributes))
        if not self.attributes:
            raise TagError("TagHeadConfig.attributes must not be empty")
        if len(set(self.attributes)) != len(self.attributes):
            raise TagError(f"TagHeadConfig.attributes repeats a name: {list(self.attributes)}")
        check_at_least("TagHeadConfig", 1, error=TagError, embed_channels=self.embed_channels)
        for name, kind in self.kinds.items():
            if kind not in (AttributeKind.CONTINUOUS.value, AttributeKind.DISCRETE.value):
                raise TagError(f"TagHeadConfig.kinds[{name!r}] must be 'continuous' or 'discrete', got {kind!r}")
        stray = sorted(set(self.scales) - set(self.attributes))
        if stray:
            raise TagError(f"TagHeadConfig.scales names attributes the head does not have: {stray}")
        scales = {a: float(self.scales.get(a, OUTPUT_SCALE.get(a, 1.0))) for a in self.attributes}
        bad = sorted(a for a, v in scales.items() if not (math.isfinite(v) and v > 0))
        if bad:
            raise TagError(f"TagHeadConfig.scales must be finite and > 0, got {[(a, scales[a]) for a in bad]}")
        object.__setattr__(self, "scales", scales)
        footprints = ({a: FOOTPRINT_M2[a] for a in self.attributes if a in FOOTPRINT_M2}
                      if self.footprints is None else {str(a): float(v) for a, v in self.footprints.items()})
        wrong = sorted(a for a in footprints if a not in self.attributes or not is_density(a))
        if wrong:
            raise TagError(f"TagHeadConfig.footprints must name densities the head has, got {wrong}")
        bad = sorted(a for a, v in footprints.items() if not (math.isfinite(v) and v > 0))
        if bad:
            raise TagError(f"TagHeadConfig.footprints must be finite and > 0 m², "
                           f"got {[(a, footprints[a]) for a in bad]}")
        object.__setattr__(self, "footprints", footprints)

    def kind(self, name: str) -> AttributeKind:
        if name in self.kinds:
            return AttributeKind(self.kinds[name])
        return attribute_kind(name)

    def footprint_share(self, name: str, cell_area_m2: float) -> float | None:
        """The share of a cell of ``cell_area_m2`` one object covers, for a density learned as presence; else None."""
        footprint = (self.footprints or {}).get(name)  # filled in on construction
        return None if footprint is None else footprint / cell_area_m2

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["attributes"] = list(self.attributes)
        return d

    @staticmethod
    def from_dict(data: dict[str, Any]) -> TagHeadConfig:
        known = {"attributes", "embed_channels", "kinds", "init_std", "scales", "footprints"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise TagError(f"TagHeadConfig: unknown keys {unknown}")
        args: dict[str, Any] = {k: (tuple(v) if k == "attributes" else v) for k, v in data.items()}
        args.setdefault("footprints", {})  # written before presence densities: all densities were regressed
        return TagHeadConfig(**args)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)


class TagHead(nn.Module):
    """A (|T|, D_e) attribute embeddings + b (|T|,) biases; ``forward(E) -> V``."""

    def __init__(self, config: TagHeadConfig) -> None:
        super().__init__()
        self.config = config
        n = len(config.attributes)
        self.attributes = nn.Parameter(torch.randn(n, config.embed_channels) * config.init_std)  # A
        self.bias = nn.Parameter(torch.zeros(n))
        scale = [config.scales[a] for a in config.attributes]
        self.scale: torch.Tensor
        self.register_buffer("scale", torch.tensor(scale, dtype=torch.float32), persistent=False)

    @property
    def names(self) -> tuple[str, ...]:
        return self.config.attributes

    def index(self, name: str) -> int:
        if name not in self.config.attributes:
            raise TagError(f"unknown attribute {name!r}; valid attributes: {', '.join(self.config.attributes)}")
        return self.config.attributes.index(name)

    def discrete_mask(self) -> torch.Tensor:
        """(|T|,) bool, true for discrete attributes."""
        return torch.tensor([self.config.kind(a) == AttributeKind.DISCRETE for a in self.config.attributes],
                            device=self.attributes.device)

    def presence_mask(self) -> torch.Tensor:
        """(|T|,) bool, true for densities learned as presence."""
        presence = self.config.footprints or {}
        return torch.tensor([a in presence for a in self.config.attributes], device=self.attributes.device)

    def forward(self, e: torch.Tensor) -> torch.Tensor:
        """e: (B, T, D_e, h, w) → V (B, T, |T|, h, w)."""
        v = torch.einsum("btdhw,ad->btahw", e, self.attributes)  # (B, T, |T|, h, w)
        return (v + self.bias[:, None, None]) * self.scale[:, None, None]

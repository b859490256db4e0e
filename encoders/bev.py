"""BEV tower: the universal spatio-temporal embedding E and the object's clip embedding pooled from it.

After Segal et al., "Universal Embeddings for Spatio-Temporal Tagging of Self-Driving Logs" (CoRL 2020):

    bev_lidar (B, T, Cl, H, W) ─ LiDAR backbone ─┐ stage features at strides 2, 4, 8, …
    bev_map   (B, T, Cm, H, W) ─ map backbone  ──┤ each upsampled to (H/r, W/r), all concatenated
                                                 └─ header: 1×1 conv, depthwise 3×3 conv, depthwise
                                                    temporal conv → E (B, T, D_e, H/r, W/r)

:meth:`BevTower.embed_map` computes E alone: it is fully convolutional in space and in time (any H, W,
T) and is what attribute tagging builds on. :meth:`BevTower.forward` pools E under the object's mask in
each frame, adds the mask's geometry (and its change since the previous frame) and the ego motion,
and runs the :class:`TemporalEncoder` over the frames to give the object's clip embedding.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from encoders.camera import conv_block, mask_geometry, unit_ego_motion, unit_pixels, with_motion
from encoders.config import BevConfig
from encoders.fusion import TemporalEncoder
from encoders.timeline import clip_head, read_clip

#: What ``BevConfig.track_velocity`` adds: the velocity relative to the ego and the range rates along x and y.
VELOCITY_FEATURES = ("vx", "vy", "range_rate_x", "range_rate_y")
#: m/s brought to about unit range.
VELOCITY_SCALE_MPS = 10.0
#: What ``BevConfig.track_rates`` adds (:func:`encoders.clips.views.object_rates_and_velocity`), and the
#: scales that bring them to about unit range.
RATES_SCALE = (10.0, 2.0, 0.5)


def distinct_frames(*views: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """views: each (N, ...), frame i of each view belonging together → (first (U,), inverse (N,)).

    ``first``: the index of each distinct frame's first occurrence, in order; ``inverse[i]``: the
    position in ``first`` of frame i's equal. Frames are equal when every view is bit-equal. A hash of
    each frame's bytes groups candidates (equal frames hash alike); each frame is then compared in full
    with its group's first, and one that differs (a hash collision) stands alone, so different frames
    are never merged.

    Both steps read each frame as 64-bit words, 8 bytes at a time: several times faster than a float
    projection and a byte-by-byte comparison of the same rasters (``docs/research/training-speed.md``).
    """
    n = views[0].shape[0]
    words = [_words(v.reshape(n, -1)) for v in views]  # each (N, M_i) int64
    gen = torch.Generator(device="cpu").manual_seed(0)
    # A random linear hash over the 64-bit words; integer products and sums wrap around, which keeps
    # the hash exact (the same for equal frames whatever the summation order).
    keys = torch.stack([(w * torch.randint(-2**62, 2**62, (w.shape[1],), generator=gen).to(w.device)).sum(dim=1)
                        for w in words], dim=1)  # (N, V)
    _, group = torch.unique(keys, dim=0, return_inverse=True)  # (N,) candidate group of each frame
    index = torch.arange(n, device=group.device)
    lead = torch.full((n,), n, dtype=torch.long, device=group.device).scatter_reduce(0, group, index, "amin")
    rep = lead[group]  # (N,) the group's first frame
    # Only frames that are not their group's first need the full comparison.
    checked = torch.nonzero(rep != index).squeeze(1)  # (C,)
    same = torch.ones_like(checked, dtype=torch.bool)
    for w in words:
        same &= (w.index_select(0, checked) == w.index_select(0, rep[checked])).all(dim=1)
    rep = rep.index_put((checked[~same],), checked[~same])  # a collision stands alone
    first, inverse = torch.unique(rep, return_inverse=True)  # sorted: first occurrences
    return first, inverse


def _words(rows: torch.Tensor) -> torch.Tensor:
    """rows: (N, M) of any dtype → (N, ⌈M·bytes/8⌉) int64: each row's bytes, zero-padded to whole words."""
    raw = rows.contiguous().view(torch.uint8)  # (N, M·bytes)
    if raw.shape[1] % 8:
        raw = F.pad(raw, (0, -raw.shape[1] % 8))
    return raw.view(torch.int64)


def pool_frames(s: torch.Tensor, weights: torch.Tensor, inverse: torch.Tensor | None = None) -> torch.Tensor:
    """s: (N, C, P) frames' features; weights: (M, P, K) pooling weights of M frames; inverse: (M,) frame
    i's row of ``s`` (None: M = N, row i) → (M, C, K): ``s[inverse[i]] @ weights[i]``.

    With ``inverse``, each distinct frame's features meet the weights of all its frames in one product,
    instead of being copied once per frame that shares them. The loop runs once per distinct frame of
    the batch, and still wins when few frames are shared (``docs/research/training-speed.md``).
    """
    if inverse is None:
        return torch.bmm(s, weights)
    m, p, k = weights.shape
    order = torch.argsort(inverse, stable=True)  # frames grouped by their row of s
    counts = torch.bincount(inverse, minlength=s.shape[0]).tolist()
    out: torch.Tensor | None = None  # in the products' dtype (bfloat16 under autocast)
    for row, frames in enumerate(torch.split(order, counts)):
        if len(frames):
            together = weights.index_select(0, frames).permute(1, 0, 2).reshape(p, -1)  # (P, n·K)
            part = (s[row] @ together).reshape(-1, len(frames), k).transpose(0, 1)  # (n, C, K)
            out = part.new_empty(m, s.shape[1], k) if out is None else out
            out[frames] = part
    return out if out is not None else weights.new_empty(m, s.shape[1], k)


class Residual(nn.Module):
    """x + a 3×3 convolution block (optionally dilated) at the same resolution: (N, C, h, w) → the same."""

    def __init__(self, channels: int, dilation: int = 1) -> None:
        super().__init__()
        self.block = conv_block(channels, channels, 3, 1, dilation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.block(x)


class Backbone(nn.Module):
    """(N, C, H, W) → list of stage features, stage i at stride 2**(i+1).

    Each stage is a strided 3×3 convolution followed by ``blocks_per_stage - 1`` residual 3×3
    convolutions. With one block per stage, four stages see about 31 input cells; every extra block
    widens the view by 2 cells of its stage (a second block per stage: about 91 cells, 45 m at 0.5 m).
    ``context_blocks`` residual 3×3 convolutions with dilation 2 follow the last stage, where they are
    cheap: each widens the view by 4 cells of that stage (two after four stages: +128 cells, 64 m).
    """

    def __init__(self, in_channels: int, widths: tuple[int, ...], blocks_per_stage: int = 1,
                 context_blocks: int = 0) -> None:
        super().__init__()
        chans = (in_channels, *widths)
        self.stages = nn.ModuleList(conv_block(a, b, 3, 2) for a, b in zip(chans[:-1], chans[1:]))
        # Kept apart from ``stages`` so that one block per stage has the same state_dict as before.
        self.refine = nn.ModuleList(
            nn.Sequential(*(Residual(w) for _ in range(blocks_per_stage - 1))) for w in widths
        )
        self.context = nn.Sequential(*(Residual(widths[-1], dilation=2) for _ in range(context_blocks)))

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        out = []
        for stage, refine in zip(self.stages, self.refine):
            x = refine(stage(x))
            out.append(x)
        out[-1] = self.context(out[-1])
        return out


class Lateral(nn.Module):
    """Per-stage 1×1 projections to D_e of the LiDAR and the map backbones."""

    def __init__(self, widths: tuple[int, ...], channels: int) -> None:
        super().__init__()
        self.lidar = nn.ModuleList(nn.Conv2d(w, channels, 1, bias=False) for w in widths)
        self.map = nn.ModuleList(nn.Conv2d(w, channels, 1) for w in widths)


def shift_time(x: torch.Tensor, offset: int) -> torch.Tensor:
    """x: (B, T, ...) → y of the same shape with y[:, t] = x[:, t + offset], zero outside the clip."""
    t = x.shape[1]
    lo, hi = max(0, -offset), t - max(0, offset)  # the frames t whose t + offset lies in the clip
    if hi <= lo:
        return torch.zeros_like(x)
    return F.pad(x[:, lo + offset : hi + offset], (0, 0) * (x.dim() - 2) + (lo, t - hi))


class TimeConv(nn.Module):
    """x + a depthwise convolution over time, zero-padded: (B, T, C, ...) → the same; starts as identity."""

    def __init__(self, kernel: int, channels: int) -> None:
        super().__init__()
        self.kernel = kernel
        self.weight = nn.Parameter(torch.zeros(kernel, channels))
        #: Tap j reads frame t + offsets[j].
        self.offsets = tuple(j - kernel // 2 for j in range(kernel))

    def _weight(self, j: int, dims: int) -> torch.Tensor:
        """Tap j's (C,) weights shaped to broadcast over a (B, T, C, ...) tensor of ``dims`` dimensions."""
        return self.weight[j].reshape(-1, *([1] * (dims - 3)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        k, t = self.kernel, x.shape[1]
        if k == 1:
            return x + self._weight(0, x.dim()) * x
        pad = F.pad(x, (0, 0) * (x.dim() - 2) + (k // 2, k // 2))  # (B, T + k - 1, C, ...)
        return x + sum(self._weight(j, x.dim()) * pad[:, j : j + t] for j in range(k))

    def mix(self, at_offset: Callable[[int], torch.Tensor]) -> torch.Tensor:
        """The convolution of a quantity linear in x, from ``at_offset(d)``, that quantity with x shifted
        by d frames (:func:`shift_time`), for d in −k//2 … k − 1 − k//2: (B, T, C, ...) → the same.

        For a linear f applied frame by frame, f(self(x)) = self.mix(lambda d: f(shift_time(x, d))),
        so pooling the features of every frame needs no convolved (B, T, C, h, w) tensor at all.
        """
        out = at_offset(0)
        for j, offset in enumerate(self.offsets):
            out = out + self._weight(j, out.dim()) * at_offset(offset)
        return out


class BevTower(nn.Module):
    """BEV clip (LiDAR, map, object mask, ego motion) → E and the object's clip embedding (B, D)."""

    def __init__(self, config: BevConfig, embed_dim: int, time_slots: int = 0, slot_dim: int = 0) -> None:
        super().__init__()
        self.config = config
        d_e = config.embed_channels
        self.lidar = Backbone(config.lidar_channels, config.widths, config.blocks_per_stage,
                              config.context_blocks)
        self.map = Backbone(config.map_channels, config.widths, config.blocks_per_stage,
                              config.context_blocks)
        # A 1×1 convolution of the concatenated upsampled features equals the sum of per-stage 1×1
        # projections, upsampled (upsampling is linear). Projecting first, at each stage's own
        # resolution, and upsampling coarse to fine (FPN order) is the same header at a fraction of the cost.
        self.lateral = Lateral(config.widths, d_e)
        self.header_space = nn.Sequential(
            nn.Conv2d(d_e, d_e, 3, padding=1, groups=d_e, bias=False), nn.BatchNorm2d(d_e), nn.ReLU(inplace=True)
        )
        self.header_time = TimeConv(config.temporal_kernel, d_e)
        self.temporal = TemporalEncoder(config.temporal, 2 * d_e + 8 + config.ego_features)
        self.head = clip_head(config.temporal.width, embed_dim, time_slots, slot_dim)
        # The object's own track, read by its own temporal model: (T, 2 F + E) → (B, D), added to the
        # raster stream's vector (see BevConfig.track_features).
        self.track: TemporalEncoder | None = None
        self.track_head: nn.Module | None = None
        if config.track_features:
            per_frame = (config.track_features + (len(VELOCITY_FEATURES) if config.track_velocity else 0)
                         + (len(RATES_SCALE) if config.track_rates else 0))
            self.track = TemporalEncoder(config.track, 2 * per_frame + config.ego_features)
            self.track_head = clip_head(config.track.width, embed_dim, time_slots, slot_dim)
        self.rates_scale: torch.Tensor
        self.register_buffer("rates_scale", torch.tensor(RATES_SCALE), persistent=False)

    #: state_dict prefixes of the parameters that compute E (the rest pools E into the clip embedding).
    EMBEDDING_PREFIXES = ("lidar.", "map.", "lateral.", "header_space.", "header_time.")

    def embed_map(self, bev_lidar: torch.Tensor, bev_map: torch.Tensor) -> torch.Tensor:
        """bev_lidar: (B, T, Cl, H, W); bev_map: (B, T, Cm, H, W) → E (B, T, D_e, H/r, W/r)."""
        return self.header_time(self.embed_space(bev_lidar, bev_map))

    def embed_space(self, bev_lidar: torch.Tensor, bev_map: torch.Tensor) -> torch.Tensor:
        """bev_lidar: (B, T, Cl, H, W); bev_map: (B, T, Cm, H, W), float in [0, 1] or uint8 0–255 (see
        :func:`encoders.camera.unit_pixels`) → S (B, T, D_e, H/r, W/r), E before its convolution over
        time (E = ``header_time(S)``): each frame on its own."""
        b, t = bev_lidar.shape[:2]
        x, inverse = self.embed_distinct(bev_lidar, bev_map)
        if inverse is not None:
            x = x.index_select(0, inverse)  # (B*T, D_e, h, w)
        return x.reshape(b, t, *x.shape[1:])

    def embed_distinct(self, bev_lidar: torch.Tensor,
                       bev_map: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """As :meth:`embed_space`, but each distinct frame once: → (S of the U distinct frames (U, D_e,
        H/r, W/r), inverse (B*T,): frame i's row in it), or (S (B*T, D_e, H/r, W/r), None).

        In eval mode, frames that are equal in both rasters go through the backbones once: the
        rasters are centred on the ego, so every clip of a log at a frame holds the same ones (a
        batch of 32 clips in table order holds about 5 times fewer distinct frames than frames).
        With batch norm's running statistics each frame's features do not depend on the others,
        so S is the same. The equal frames are found on the rasters as they come (bytes, from
        ``ClipDataset(as_uint8=True)``), and only the distinct ones are converted to float. In
        training each clip's rasters are warped on their own and batch norm reads the batch, so
        every frame runs.
        """
        h, w = bev_lidar.shape[-2:]
        r = self.config.downsample
        size = (h // r, w // r)
        lidar_in, map_in = bev_lidar.flatten(0, 1), bev_map.flatten(0, 1)  # (B*T, Cl, H, W), (B*T, Cm, H, W)
        inverse: torch.Tensor | None = None
        if not self.training:
            first, inverse = distinct_frames(lidar_in, map_in)  # (U,), (B*T,)
            if len(first) < len(inverse):
                lidar_in, map_in = lidar_in.index_select(0, first), map_in.index_select(0, first)
            else:
                inverse = None
        lidar = self.lidar(unit_pixels(lidar_in))  # stages of (N, C_i, H / 2**(i+1), W / 2**(i+1))
        maps = self.map(unit_pixels(map_in))
        x: torch.Tensor | None = None
        for i in reversed(range(len(lidar))):
            p = self.lateral.lidar[i](lidar[i]) + self.lateral.map[i](maps[i])  # (N, D_e, h_i, w_i)
            x = p if x is None else p + F.interpolate(x, size=p.shape[-2:], mode="bilinear")
        assert x is not None
        if x.shape[-2:] != size:
            x = F.interpolate(x, size=size, mode="bilinear")
        x = F.relu(x)  # (N, D_e, h, w)
        return x + self.header_space(x), inverse  # (N, D_e, h, w)

    def frame_features(self, s: torch.Tensor, bev_object: torch.Tensor, ego_motion: torch.Tensor,
                       inverse: torch.Tensor | None = None) -> torch.Tensor:
        """s: (B, T, D_e, h, w), :meth:`embed_space`'s S, or with ``inverse`` (B*T,) the (U, D_e, h, w) S of
        the distinct frames and each frame's row in it (:meth:`embed_distinct`); bev_object: (B, T, 1, H, W);
        ego_motion: (B, T, 4) → (B, T, 2 D_e + 8 + E): E = ``header_time(S)`` pooled under the object's
        mask and over the whole grid, the mask's geometry and the ego motion.

        Both means are linear in E, and E is S convolved over time, so they are taken of S and
        convolved after (:meth:`TimeConv.mix`): no convolved (B, T, D_e, h, w) tensor is made, nor its
        gradient, which were most of the tower's cost. Given the distinct frames, S is read once per
        distinct frame: no (B*T, D_e, h, w) copy of it is made either.
        """
        b, t = bev_object.shape[:2]
        c, h, w = s.shape[-3:]
        obj = bev_object.flatten(0, 1)  # (B*T, 1, H, W)
        small = F.adaptive_avg_pool2d(obj, (h, w)).reshape(b, t, h * w)  # (B, T, hw)
        under = small / small.sum(dim=-1, keepdim=True).clamp_min(1e-6)  # (B, T, hw): the masked mean's weights
        offsets = self.header_time.offsets
        # masks[:, u, :, i] = frame u − offsets[i]'s mask: frame u's S under it is what frame u − offsets[i]
        # pools at that offset. One batched product reads S once for every offset.
        masks = torch.stack([shift_time(under, -d) for d in offsets], dim=-1)  # (B, T, hw, K)
        flat = s.reshape(-1, c, h * w)  # (B*T or U, D_e, hw)
        pooled = pool_frames(flat, masks.flatten(0, 1), inverse).reshape(b, t, c, len(offsets))  # (B, T, D_e, K)
        masked = self.header_time.mix(lambda d: shift_time(pooled[..., offsets.index(d)], d))  # (B, T, D_e)
        mean = flat.mean(dim=-1)  # (B*T or U, D_e)
        if inverse is not None:
            mean = mean.index_select(0, inverse)
        mean = self.header_time(mean.reshape(b, t, c))  # (B, T, D_e)
        geometry = with_motion(mask_geometry(obj).reshape(b, t, -1))  # (B, T, 8)
        ego = unit_ego_motion(ego_motion, self.config.ego_features)  # (B, T, E)
        return torch.cat([masked, mean, geometry, ego], dim=-1)  # (B, T, 2 D_e + 8 + E)

    def track_features(self, object_track: torch.Tensor, ego_motion: torch.Tensor,
                       object_velocity: torch.Tensor | None = None,
                       object_rates: torch.Tensor | None = None) -> torch.Tensor:
        """object_track: (B, T, F); ego_motion: (B, T, 6); object_velocity: (B, T, 2) m/s; object_rates:
        (B, T, 3) → (B, T, 2 F' + E): the track (with :data:`VELOCITY_FEATURES` under ``track_velocity``
        and the object's own rates under ``track_rates``), its change since the previous frame, and the
        ego motion."""
        ego = unit_ego_motion(ego_motion, self.config.ego_features)  # (B, T, E)
        x, y = object_track[..., 0], object_track[..., 1]  # (B, T) ego-relative position / 50 m
        parts = [object_track]
        if self.config.track_velocity:
            if object_velocity is None:
                raise ValueError("this BEV tower reads the object's velocity: the batch needs "
                                 "'object_velocity' (B, T, 2)")
            v = object_velocity / VELOCITY_SCALE_MPS  # (B, T, 2)
            rates = torch.stack([torch.sign(x) * v[..., 0], torch.sign(y) * v[..., 1]], dim=-1)  # (B, T, 2)
            parts += [v, rates]
        if self.config.track_rates:
            if object_rates is None:
                raise ValueError("this BEV tower reads the object's own rates: the batch needs "
                                 "'object_rates' (B, T, 3)")
            parts.append(object_rates / self.rates_scale)
        return torch.cat([with_motion(torch.cat(parts, dim=-1)), ego], dim=-1)

    def forward(
        self, bev_lidar: torch.Tensor, bev_map: torch.Tensor, bev_object: torch.Tensor, ego_motion: torch.Tensor,
        object_track: torch.Tensor | None = None, frames: dict[str, torch.Tensor] | None = None,
        object_velocity: torch.Tensor | None = None, object_rates: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """(B, T, Cl, H, W), (B, T, Cm, H, W), (B, T, 1, H, W), (B, T, 4), (B, T, F) → (B, D); the two
        rasters float in [0, 1] or uint8 0–255 (:meth:`embed_distinct` converts them).

        ``object_track`` is required when the tower has a track stream (``track_features`` > 0),
        ``object_velocity`` (B, T, 2) when it reads velocities (``track_velocity``), ``object_rates``
        (B, T, 3) when it reads the object's own rates (``track_rates``). With a
        ``frames`` dict, the temporal models' frame tokens (B, T, W) go to ``frames["bev"]`` and
        ``frames["track"]`` (dense supervision, :mod:`encoders.dense`).
        """
        space, inverse = self.embed_distinct(bev_lidar, bev_map)  # (U, D_e, h, w), (B*T,) or (B*T, …), None
        features = self.frame_features(space, bev_object, ego_motion, inverse)  # (B, T, 2 D_e + 8 + E)
        clip, tokens = self.temporal.encode(features)  # (B, W), (B, T, W)
        x = read_clip(self.head, clip, tokens)  # (B, D)
        if frames is not None:
            frames["bev"] = tokens
        if self.track is not None and self.track_head is not None:
            if object_track is None:
                raise ValueError("this BEV tower reads the object's track: the batch needs 'object_track' (B, T, "
                                 f"{self.config.track_features})")
            clip, tokens = self.track.encode(self.track_features(object_track, ego_motion, object_velocity,
                                                                 object_rates))
            x = x + read_clip(self.track_head, clip, tokens)  # (B, D)
            if frames is not None:
                frames["track"] = tokens
        return x

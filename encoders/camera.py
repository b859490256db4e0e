"""Camera tower: object-masked camera clips (B, T, 4, H, W) → clip embedding (B, D).

A strided per-frame CNN (the stem divides the resolution by 4 at once, which keeps CPU training fast)
reads RGB and the object mask; each frame is summarised by pooling its feature map twice, under the
object mask (what the object looks like and where it is) and globally (its surroundings), plus the
mask's area and centroid (where it is in the image, how large) and their change since the previous
frame (how it moves); the :class:`TemporalEncoder` then reads
the T frame vectors with learned time positions, so the output depends on frame order.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from encoders.clips.views import CAMERA_BOX_FEATURES
from encoders.config import CameraConfig
from encoders.fusion import TemporalEncoder
from encoders.timeline import clip_head, read_clip

#: Scales that bring ego_motion (x_m, y_m, yaw_rad, speed_mps, accel_mps2, yaw_rate_rps) to about unit range.
EGO_MOTION_SCALE = (50.0, 50.0, 3.14159, 20.0, 2.0, 0.5)


def unit_ego_motion(ego_motion: torch.Tensor, features: int) -> torch.Tensor:
    """ego_motion: (B, T, 6) → (B, T, ``features``): its first columns divided by :data:`EGO_MOTION_SCALE`,
    what every temporal model that reads the ego's motion reads."""
    return ego_motion[..., :features] / ego_motion.new_tensor(EGO_MOTION_SCALE[:features])


def unit_pixels(x: torch.Tensor) -> torch.Tensor:
    """An image-like view as the towers read it: uint8 0–255 (``ClipDataset(as_uint8=True)``, moved as
    bytes) → float32 in [0, 1], the dataset's float items bit for bit; float views pass through."""
    return x.to(torch.float32).mul_(1.0 / 255.0) if x.dtype == torch.uint8 else x


def conv_block(c_in: int, c_out: int, kernel: int, stride: int, dilation: int = 1) -> nn.Sequential:
    """Convolution ("same" padding for stride 1), batch norm, ReLU."""
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=dilation * (kernel // 2), dilation=dilation, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


def mask_geometry(mask: torch.Tensor) -> torch.Tensor:
    """mask: (N, 1, H, W) in [0, 1] → (N, 4): area fraction, centroid x and y in [-1, 1], visible flag."""
    _, _, h, w = mask.shape
    area = mask.sum(dim=(1, 2, 3))  # (N,)
    ys = torch.linspace(-1.0, 1.0, h, device=mask.device, dtype=mask.dtype)
    xs = torch.linspace(-1.0, 1.0, w, device=mask.device, dtype=mask.dtype)
    cy = (mask.sum(dim=(1, 3)) * ys).sum(dim=-1) / area.clamp_min(1e-6)  # (N,)
    cx = (mask.sum(dim=(1, 2)) * xs).sum(dim=-1) / area.clamp_min(1e-6)  # (N,)
    visible = (area > 0).to(mask.dtype)
    return torch.stack([area / (h * w), cx, cy, visible], dim=-1)  # (N, 4)


def with_motion(geometry: torch.Tensor) -> torch.Tensor:
    """geometry: (B, T, G) per-frame mask geometry → (B, T, 2G): with its change since the previous frame.

    The change is scaled by T (so it reads as the displacement over a whole clip) and is 0 in the
    first frame; shuffled frames turn it into noise, which is what makes it an order feature.
    """
    t = geometry.shape[1]
    delta = torch.zeros_like(geometry)
    delta[:, 1:] = (geometry[:, 1:] - geometry[:, :-1]) * t
    return torch.cat([geometry, delta], dim=-1)


def mask_scale(mask: torch.Tensor) -> torch.Tensor:
    """mask: (N, 1, H, W) in [0, 1] → (N, 1): log(1 + pixels under the mask) / log(1 + H·W), in [0, 1].

    A camera object at demo resolution covers a few pixels (``docs/research/camera-ego-size.md``): as a
    fraction, its size and how that changes (approaching, moving away) are invisible next to unit-range
    inputs; on a log scale one pixel and a tenth of the image both count.
    """
    _, _, h, w = mask.shape
    return torch.log1p(mask.sum(dim=(1, 2, 3)))[:, None] / math.log1p(h * w)  # (N, 1)


def _frames(clip: torch.Tensor) -> torch.Tensor:
    """(B, T, C, H, W) → (B*T, C, H, W)."""
    return clip.reshape(-1, *clip.shape[2:])


def masked_mean(features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """features: (N, C, h, w); mask: (N, 1, h, w) weights → (N, C) mean under the mask (0 where empty)."""
    weight = mask.sum(dim=(2, 3)).clamp_min(1e-6)  # (N, 1)
    return (features * mask).sum(dim=(2, 3)) / weight  # (N, C)


def _pool(cnn: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """x: (N, C, H, W) frames, object mask last → (N, 2F): the CNN's features under the mask and overall."""
    f = cnn(x)  # (N, F, h, w)
    small = F.adaptive_avg_pool2d(x[:, -1:], (f.shape[-2], f.shape[-1]))  # (N, 1, h, w)
    return torch.cat([masked_mean(f, small), f.mean(dim=(2, 3))], dim=-1)


class CameraTower(nn.Module):
    """(B, T, C, H, W) camera clip with object-mask channel last → (B, D)."""

    def __init__(self, config: CameraConfig, embed_dim: int, time_slots: int = 0, slot_dim: int = 0) -> None:
        super().__init__()
        self.config = config
        widths = config.widths
        stages = [conv_block(config.in_channels, widths[0], 5, 4)]
        stages += [conv_block(a, b, 3, 2) for a, b in zip(widths[:-1], widths[1:])]
        self.cnn = nn.Sequential(*stages)
        crop_features = 0
        if config.object_crop:
            # The object fills the crop: a finer stem (stride 2, not 4) keeps the few pixels it has.
            crop_stages = [conv_block(config.in_channels, widths[0], 3, 2)]
            crop_stages += [conv_block(a, b, 3, 2) for a, b in zip(widths[:-1], widths[1:])]
            self.crop_cnn = nn.Sequential(*crop_stages)
            crop_features = 2 * widths[-1] + 2 * CAMERA_BOX_FEATURES
        self.temporal = TemporalEncoder(config.temporal, 2 * widths[-1] + 8 + 2 * config.mask_scale
                                        + config.ego_features + crop_features)
        self.head = clip_head(config.temporal.width, embed_dim, time_slots, slot_dim)

    def frame_features(self, camera: torch.Tensor, ego_motion: torch.Tensor | None = None,
                       crop: torch.Tensor | None = None, box: torch.Tensor | None = None) -> torch.Tensor:
        """camera: (B, T, C, H, W), in [0, 1] or as bytes (:func:`unit_pixels`, converted where read);
        ego_motion: (B, T, 6), read when ``config.ego_features`` > 0; crop: (B, T, C, H, W) as the camera
        and box: (B, T, 4), read with ``config.object_crop``
        → (B, T, 2 * widths[-1] + 8 (+ 2) + E (+ 2 * widths[-1] + 8)) per-frame vectors (+ 2 with
        ``config.mask_scale``)."""
        b, t = camera.shape[:2]
        mask = unit_pixels(_frames(camera)[:, -1:])  # (B*T, 1, H, W)
        parts = [self._pooled(self.cnn, camera), with_motion(mask_geometry(mask).reshape(b, t, -1))]  # 2F, 8
        if self.config.mask_scale:
            parts.append(with_motion(mask_scale(mask).reshape(b, t, 1)))  # (B, T, 2)
        if self.config.ego_features:
            if ego_motion is None:
                raise ValueError("CameraTower: ego_features > 0 needs the clips' ego_motion")
            parts.append(unit_ego_motion(ego_motion, self.config.ego_features))  # (B, T, E)
        if self.config.object_crop:
            if crop is None or box is None:
                raise ValueError("CameraTower: object_crop needs the clips' camera_crop and camera_box (clips "
                                 "rendered with object crops)")
            parts += [self._pooled(self.crop_cnn, crop), with_motion(box)]  # (B, T, 2F), (B, T, 8)
        return torch.cat(parts, dim=-1)  # (B, T, 2F + 8 (+ 2) + E (+ 2F + 8))

    def _pooled(self, cnn: nn.Module, frames: torch.Tensor) -> torch.Tensor:
        """frames: (B, T, C, H, W), object mask last → (B, T, 2F): the CNN's features under the mask and overall.

        In eval mode the clips whose frames are all zero (those the camera never saw) share one zero
        frame's features: batch norm then reads no batch statistics, so each frame's features depend on
        that frame alone, and most clips of a log without camera would run the CNN on blank frames.
        Frames given as bytes are converted after that choice, only those the CNN reads.
        """
        b, t = frames.shape[:2]
        if not self.training:
            blank = ~frames.flatten(1).any(dim=1).bool()  # (B,); any() of bytes gives bytes
            if bool(blank.any()):
                seen = (~blank).nonzero().flatten()  # (S,)
                x = unit_pixels(torch.cat([_frames(frames.index_select(0, seen)), frames[blank.nonzero()[0, 0], :1]]))
                pooled = _pool(cnn, x)  # (S*T + 1, 2F): the seen clips' frames, then the zero frame
                out = pooled[-1].expand(b, t, -1).clone()  # (B, T, 2F)
                out[seen] = pooled[:-1].reshape(seen.numel(), t, pooled.shape[-1])
                return out
        return _pool(cnn, unit_pixels(_frames(frames))).reshape(b, t, -1)

    def forward(self, camera: torch.Tensor, frames: dict[str, torch.Tensor] | None = None,
                ego_motion: torch.Tensor | None = None, crop: torch.Tensor | None = None,
                box: torch.Tensor | None = None) -> torch.Tensor:
        """camera: (B, T, C, H, W); ego_motion, crop, box: see :meth:`frame_features` → (B, D); the
        temporal model's frame tokens (B, T, W) go to ``frames["camera"]`` when a dict is given (dense
        supervision, :mod:`encoders.dense`)."""
        clip, tokens = self.temporal.encode(self.frame_features(camera, ego_motion, crop, box))  # (B, W), (B, T, W)
        if frames is not None:
            frames["camera"] = tokens
        return read_clip(self.head, clip, tokens)

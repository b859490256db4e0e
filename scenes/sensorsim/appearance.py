"""How a simulated log looks: time of day, weather and object colours, and the camera palette.

Read from the ``appearance`` dict of ``log_metadata.json`` (see :class:`scenes.metadata.LogMetadata`):
``{"time_of_day": "day" | "dusk" | "night", "weather": "clear" | "rain" | "fog",
"vehicle_colors": {track_id: [r, g, b]}}``; anything missing takes the default (day, clear, a
colour drawn from the track id).
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from scenes.categories import Category
from scenes.geometry import FloatArray
from scenes.metadata import TimeOfDay, Weather
from scenes.sensorsim.ground import GroundMaterial


@dataclass(frozen=True)
class Appearance:
    """Scene look of one log.

    Attributes:
        time_of_day: lighting.
        weather: visibility, rain streaks and road colour.
        vehicle_colors: track id → (r, g, b) body colour.
    """

    time_of_day: TimeOfDay = TimeOfDay.DAY
    weather: Weather = Weather.CLEAR
    vehicle_colors: Mapping[str, tuple[int, int, int]] = field(default_factory=dict)

    @staticmethod
    def from_metadata(appearance: Mapping[str, Any], source: str = "log_metadata.json") -> Appearance:
        """Parse a metadata ``appearance`` dict; raises ``ValueError`` naming the bad field."""
        try:
            tod = TimeOfDay(str(appearance.get("time_of_day", "day")))
        except ValueError:
            raise ValueError(f"{source}: field 'appearance.time_of_day': unknown value "
                             f"{appearance.get('time_of_day')!r} (day, dusk or night)") from None
        try:
            weather = Weather(str(appearance.get("weather", "clear")))
        except ValueError:
            raise ValueError(f"{source}: field 'appearance.weather': unknown value {appearance.get('weather')!r} "
                             "(clear, rain or fog)") from None
        colors: dict[str, tuple[int, int, int]] = {}
        for tid, rgb in dict(appearance.get("vehicle_colors") or {}).items():
            values = list(rgb) if isinstance(rgb, list | tuple) else []
            if len(values) != 3 or not all(isinstance(v, int | float) and 0 <= v <= 255 for v in values):
                raise ValueError(f"{source}: field 'appearance.vehicle_colors.{tid}': expected [r, g, b] in 0–255, "
                                 f"got {rgb!r}")
            colors[str(tid)] = (int(values[0]), int(values[1]), int(values[2]))
        return Appearance(tod, weather, colors)


@dataclass(frozen=True)
class Palette:
    """Colours (BGR, 0–255 floats) and lighting the camera uses for one appearance.

    Attributes:
        sky_top: colour at the top of the image.
        sky_horizon: colour at the horizon (also the haze colour).
        ground: (len(GroundMaterial), 3) colour of each ground material.
        facades: (F, 3) building colours.
        ambient: light on faces turned away from the sun.
        diffuse: extra light on faces facing the sun.
        sun_dir: (3,) unit vector toward the sun, city frame.
        visibility_m: distance at which haze hides 63 % of a colour.
        headlight: colour of lit headlights.
        taillight: colour of taillights.
        noise_std: standard deviation of the sensor noise.
        rain_streaks: number of rain streaks per frame.
        light: overall brightness (and tint, BGR) applied to object colours.
        lights_on: whether vehicle lights glow (dusk, night).
    """

    sky_top: FloatArray
    sky_horizon: FloatArray
    ground: FloatArray
    facades: FloatArray
    ambient: float
    diffuse: float
    sun_dir: FloatArray
    visibility_m: float
    headlight: FloatArray
    taillight: FloatArray
    noise_std: float
    rain_streaks: int
    light: FloatArray
    lights_on: bool


def _bgr(r: float, g: float, b: float) -> FloatArray:
    return np.array([b, g, r], dtype=np.float64)


def make_palette(appearance: Appearance) -> Palette:
    """The palette of a time of day and weather."""
    ground = np.zeros((len(GroundMaterial), 3))
    ground[GroundMaterial.TERRAIN] = _bgr(96, 122, 80)
    ground[GroundMaterial.SIDEWALK] = _bgr(168, 165, 158)
    ground[GroundMaterial.ROAD] = _bgr(92, 92, 96)
    ground[GroundMaterial.WHITE_PAINT] = _bgr(236, 236, 232)
    ground[GroundMaterial.YELLOW_PAINT] = _bgr(230, 196, 60)
    ground[GroundMaterial.CROSSWALK] = _bgr(228, 228, 224)
    facades = np.array([_bgr(196, 178, 150), _bgr(160, 92, 72), _bgr(150, 150, 155), _bgr(205, 200, 188),
                        _bgr(120, 110, 100)])
    sun = np.array([-0.45, 0.35, 0.82])
    tod, weather = appearance.time_of_day, appearance.weather
    if tod == TimeOfDay.DAY:
        sky_top, sky_horizon, light, ambient, diffuse, visibility = (
            _bgr(110, 160, 225), _bgr(205, 222, 240), 1.0, 0.55, 0.5, 1500.0)
        headlight, noise = _bgr(235, 235, 225), 2.0
    elif tod == TimeOfDay.DUSK:
        sky_top, sky_horizon, light, ambient, diffuse, visibility = (
            _bgr(70, 70, 130), _bgr(240, 150, 90), 0.7, 0.5, 0.45, 900.0)
        sun = np.array([0.8, -0.3, 0.2])
        headlight, noise = _bgr(255, 245, 210), 3.0
    else:
        sky_top, sky_horizon, light, ambient, diffuse, visibility = (
            _bgr(8, 10, 24), _bgr(34, 38, 56), 0.32, 0.7, 0.15, 500.0)
        headlight, noise = _bgr(255, 250, 225), 5.0
    tint = _bgr(1.0, 0.93, 0.85) if tod == TimeOfDay.DUSK else np.ones(3)
    ground = ground * light * tint
    facades = facades * light * tint
    rain_streaks = 0
    if weather == Weather.RAIN:
        ground[GroundMaterial.ROAD] *= 0.7
        gray = ground.mean(axis=1, keepdims=True)
        ground = 0.6 * ground + 0.4 * gray
        sky_top = 0.3 * sky_top + 0.7 * _bgr(150, 152, 158) * light
        sky_horizon = 0.3 * sky_horizon + 0.7 * _bgr(185, 187, 190) * light
        diffuse *= 0.3
        visibility = min(visibility, 250.0)
        rain_streaks = 160
    elif weather == Weather.FOG:
        sky_horizon = _bgr(200, 202, 205) * max(light, 0.45)
        sky_top = sky_horizon.copy()
        diffuse *= 0.2
        visibility = 55.0
    return Palette(sky_top, sky_horizon, ground, facades, ambient, diffuse, sun / np.linalg.norm(sun), visibility,
                   headlight, _bgr(230, 30, 25), noise, rain_streaks, light * tint, tod != TimeOfDay.DAY)


_DEFAULT_PAINT = np.array([_bgr(*c) for c in (
    (200, 200, 205), (30, 30, 35), (150, 25, 30), (40, 60, 130), (230, 230, 230), (110, 115, 120), (60, 90, 60),
    (190, 160, 60))])
_CLOTHES = np.array([_bgr(*c) for c in (
    (40, 50, 90), (150, 40, 40), (60, 60, 60), (200, 180, 60), (40, 110, 70), (220, 220, 220), (120, 70, 140))])


def object_colors(track_ids: list[str], categories: list[str], appearance: Appearance) -> FloatArray:
    """(K, 3) BGR base colour of every track: the log's vehicle colour, else one picked from the id."""
    out = np.zeros((len(track_ids), 3))
    for k, (tid, cat) in enumerate(zip(track_ids, categories)):
        pick = zlib.crc32(tid.encode("utf-8"))
        if tid in appearance.vehicle_colors:
            out[k] = _bgr(*appearance.vehicle_colors[tid])
        elif cat in (Category.PEDESTRIAN.value, Category.CYCLIST.value):
            out[k] = _CLOTHES[pick % len(_CLOTHES)]
        else:
            out[k] = _DEFAULT_PAINT[pick % len(_DEFAULT_PAINT)]
    return out

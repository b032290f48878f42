"""Procedural textures for the simulated world: seeded NumPy, no image files.

Surfaces are tiled in world coordinates; the grain is fine enough (about 2 mm
per texel on the road) that a camera 19 cm above the ground finds corners on
the tarmac just ahead of it, which is where a small kart's stereo VO gets its
nearest, best-constrained points.
"""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np

from kartpilot.core import glyphs
from kartpilot.core.types import Image

__all__ = ["HAZE_BGR", "HORIZON_BAND_DEG", "SURFACE_TILE_M", "barrier_texture", "car_texture", "facade_texture",
           "horizon_band", "person_texture", "sky_bgr", "speed_sign_texture", "surface_texture", "tyre_wall_texture"]

SURFACE_TILE_M = 4.0
"""World size of one tile of a ground texture, in metres."""

_BASE_BGR = {
    "asphalt": (92.0, 90.0, 88.0),
    "worn_asphalt": (138.0, 135.0, 140.0),  # the venue's pale, weathered asphalt (its frames: grey 128 overcast)
    "tartan": (50.0, 62.0, 150.0),
    "grass": (45.0, 105.0, 70.0),
    "paint": (232.0, 236.0, 236.0),
}


def _blurred_noise(rng: np.random.Generator, size: int, sigma_px: float) -> np.ndarray:
    return _wrap_blur(rng.standard_normal((size, size)).astype(np.float32), sigma_px, sigma_px)


def _wrap_blur(image: np.ndarray, sigma_x: float, sigma_y: float) -> np.ndarray:
    """Gaussian blur that wraps around the edges (so the texture tiles seamlessly), unit variance."""
    pad = math.ceil(4 * max(sigma_x, sigma_y)) + 1
    padded = np.pad(image, pad, mode="wrap")
    out = cv2.GaussianBlur(padded, (0, 0), sigma_x, sigmaY=sigma_y)[pad:-pad, pad:-pad]
    return out / max(float(out.std()), 1e-6)


@lru_cache(maxsize=24)  # a renderer asks for three (road, ground, paint); a worker draws several tracks
def surface_texture(kind: str, size_px: int = 2048, seed: int = 0) -> Image:
    """A seamless BGR texture for ``asphalt``, ``worn_asphalt``, ``tartan``, ``grass`` or ``paint``."""
    if kind not in _BASE_BGR:
        raise ValueError(f"unknown surface {kind!r}")
    rng = np.random.default_rng(seed)
    fine = _blurred_noise(rng, size_px, 0.8)
    medium = _blurred_noise(rng, size_px, 6.0)
    coarse = _blurred_noise(rng, size_px, 40.0)
    if kind in ("asphalt", "worn_asphalt"):
        stones = (rng.random((size_px, size_px)) > 0.985).astype(np.float32)
        stones = cv2.dilate(stones, np.ones((3, 3), np.uint8)) * rng.choice([-1.0, 1.0], (size_px, size_px))
        shade = 16 * fine + 8 * medium + 2 * coarse + 12 * _wrap_blur(stones, 0.8, 0.8)
    elif kind == "tartan":
        shade = 14 * fine + 5 * medium + 4 * coarse
    elif kind == "grass":
        blades = _wrap_blur(rng.standard_normal((size_px, size_px)).astype(np.float32), 0.6, 2.5)
        shade = 18 * blades + 10 * medium + 10 * coarse
    else:
        shade = 5 * fine + 3 * coarse
    base = np.asarray(_BASE_BGR[kind], np.float32)
    image = base + shade[..., None]
    return np.clip(image, 0, 255).astype(np.uint8)


@lru_cache(maxsize=2)
def tyre_wall_texture(seed: int = 0) -> Image:
    """Side view of a wall of stacked tyres: 0.6 m wide, three tyres high (BGR, 256x128)."""
    rng = np.random.default_rng(seed)
    image = np.full((128, 256, 3), 28, np.uint8)
    for row in range(3):
        top = 4 + row * 41
        for col in range(2):
            left = col * 128 + int(rng.integers(-6, 6))
            cv2.rectangle(image, (left + 6, top), (left + 122, top + 36), (18, 18, 18), -1)
            cv2.rectangle(image, (left + 6, top + 4), (left + 122, top + 8), (62, 62, 64), -1)
            cv2.rectangle(image, (left + 6, top + 28), (left + 122, top + 31), (48, 48, 50), -1)
    noise = rng.normal(0, 6, image.shape)
    return np.clip(image + noise, 0, 255).astype(np.uint8)


@lru_cache(maxsize=2)
def barrier_texture(stripes: int = 4) -> Image:
    """The face of a red-and-white barrier block: ``stripes`` red and as many white vertical bands (BGR)."""
    image = np.empty((64, 64 * 2 * stripes, 3), np.uint8)
    for k in range(2 * stripes):
        image[:, 64 * k:64 * (k + 1)] = (40, 40, 200) if k % 2 == 0 else (235, 235, 235)
    return image


@lru_cache(maxsize=8)
def speed_sign_texture(value_kmh: int, size_px: int = 256) -> Image:
    """A round Dutch speed-limit sign (a red ring, a white disc, the number in black) on a square; the disc
    touches the square's sides (BGR). The digits are a heavy, narrow sans-serif, as a real sign's are: DejaVu Sans
    Bold narrowed to 0.85 (:mod:`kartpilot.core.glyphs`), a font the sign reader has no template of, so the
    rendered frames measure its reading of a font it does not know."""
    image = np.full((size_px, size_px, 3), 235, np.uint8)
    centre, radius = (size_px // 2, size_px // 2), size_px // 2 - 1
    cv2.circle(image, centre, radius, (35, 30, 200), -1, cv2.LINE_AA)
    cv2.circle(image, centre, int(radius * 0.78), (240, 240, 240), -1, cv2.LINE_AA)
    # the digits as a real sign has them: about a third of the disc high, well inside the ring
    ink = glyphs.text_mask(str(value_kmh), "dejavu-sans-bold", round(0.36 * size_px), 0.85)
    if ink.shape[1] > 0.55 * size_px:
        ink = cv2.resize(ink, (round(0.55 * size_px), ink.shape[0]), interpolation=cv2.INTER_AREA)
    h, w = ink.shape
    y0, x0 = centre[1] - h // 2, centre[0] - w // 2
    alpha = ink[..., None].astype(np.float32) / 255.0
    patch = image[y0:y0 + h, x0:x0 + w].astype(np.float32)
    image[y0:y0 + h, x0:x0 + w] = np.round(patch * (1.0 - alpha) + 20.0 * alpha).astype(np.uint8)
    return image


@lru_cache(maxsize=8)
def person_texture(seed: int = 0) -> Image:
    """A standing person seen from any side: a head, a jacket of a random colour, dark trousers (BGR, 64x256,
    top row the head)."""
    rng = np.random.default_rng(seed)
    image = np.full((256, 64, 3), 40, np.uint8)
    image[:36, 16:48] = (120, 150, 190)  # the head
    image[36:140] = np.clip(rng.uniform(30, 220, 3), 0, 255).astype(np.uint8)  # the jacket
    image[140:] = (50, 45, 45)  # trousers
    image[140:, 30:34] = 30
    return image


@lru_cache(maxsize=2)
def car_texture() -> Image:
    """The event's inflatable car from behind or the side: white, a dark window band, red lights, a number
    plate (BGR, 256x128)."""
    image = np.full((128, 256, 3), 235, np.uint8)
    image[12:50, 30:226] = (110, 80, 60)  # the window
    image[66:82, 20:50] = image[66:82, 206:236] = (40, 40, 210)  # the lights
    image[80:94, 96:160] = (40, 170, 235)  # the plate
    image[108:, :] = (30, 30, 30)  # the tyres' shadow
    return image


HORIZON_BAND_DEG = (-1.0, 4.0)
"""Elevations covered by :func:`horizon_band` (bottom, top); the sky above it is a plain gradient."""


def sky_bgr(elevation_deg: float, overcast: bool = False) -> tuple[float, float, float]:
    """Sky colour (BGR, 0-255) at an elevation: pale at the horizon, deeper blue above; under an overcast sky
    (the venue's frames) a bright grey that darkens a little upward."""
    t = min(max(elevation_deg / 35.0, 0.0), 1.0)
    if overcast:
        return 238.0 - 40.0 * t, 236.0 - 40.0 * t, 232.0 - 42.0 * t
    return 235.0 - 45.0 * t, 218.0 - 68.0 * t, 200.0 - 105.0 * t


HAZE_BGR = (150.0, 160.0, 150.0)


@lru_cache(maxsize=4)
def horizon_band(seed: int = 0, width_px: int = 2048, height_px: int = 64, overcast: bool = False) -> Image:
    """A 360-degree band around the horizon: a tree line with a few buildings against the sky.

    Rows span :data:`HORIZON_BAND_DEG` of elevation, top row first; columns go once around.
    """
    rng = np.random.default_rng(seed)
    lo, hi = HORIZON_BAND_DEG
    elevation = hi - (np.arange(height_px) + 0.5) / height_px * (hi - lo)
    image = np.empty((height_px, width_px, 3), np.float32)
    for r, e in enumerate(elevation):
        image[r] = sky_bgr(e, overcast) if e >= 0 else HAZE_BGR
    profile = np.cumsum(rng.normal(0, 0.5, width_px))
    profile = np.convolve(np.r_[profile[-30:], profile, profile[:30]], np.ones(21) / 21, "same")[30:-30]
    top_deg = 0.8 + 1.6 * (profile - profile.min()) / max(float(np.ptp(profile)), 1e-6)
    for _ in range(10):
        x0 = int(rng.integers(0, width_px - 60))
        top_deg[x0:x0 + int(rng.integers(20, 60))] = rng.uniform(1.5, 3.5)
    texture = rng.normal(0, 12, (height_px, width_px))
    trees = np.stack([50 + texture, 78 + texture, 58 + texture], axis=-1)
    mask = (elevation[:, None] <= top_deg[None, :]) & (elevation[:, None] >= -0.2)
    image[mask] = trees[mask]
    return np.clip(image, 0, 255).astype(np.uint8)


@lru_cache(maxsize=16)
def facade_texture(seed: int, size_px: int = 256) -> Image:
    """The face of a roadside building or board: a coloured base with windows, panels and stripes in
    random colours, so each differs from the others (BGR, square)."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(60, 220, 3)
    image = np.empty((size_px, size_px, 3), np.float32)
    image[:] = base
    for _ in range(int(rng.integers(4, 12))):
        x0, y0 = (int(v) for v in rng.integers(0, size_px - 16, 2))
        w, h = (int(v) for v in rng.integers(12, size_px // 2, 2))
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), rng.uniform(20, 240, 3).tolist(), -1)
    rows, cols = int(rng.integers(2, 5)), int(rng.integers(2, 7))
    shade = rng.uniform(20, 90, 3).tolist()
    for r in range(rows):
        for c in range(cols):
            if rng.random() < 0.8:
                x0 = int((c + 0.2) * size_px / cols)
                y0 = int((r + 0.25) * size_px / rows)
                cv2.rectangle(image, (x0, y0), (x0 + int(0.55 * size_px / cols), y0 + int(0.45 * size_px / rows)),
                              shade, -1)
    noise = rng.normal(0, 5, image.shape)
    return np.clip(image + noise, 0, 255).astype(np.uint8)

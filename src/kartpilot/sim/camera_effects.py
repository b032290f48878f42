"""What a real camera does to the light a perfect renderer draws: pure functions the simulator applies after
rendering, each on its own named switch (``sim.effects``).

A rendering is a perfect pinhole's instant. A real camera on a moving kart is none of that:

- **its rows are read one after another** (rolling shutter): a row read later sees the scene from where the kart
  is then, so a turning kart's verticals lean and the near road stretches or shrinks;
- **it exposes for a while** (motion blur): the image is the average over the exposure;
- **it meters the light** (auto-exposure and gain): the brightness follows the view with a lag, so the same road
  is not the same grey in two frames, and a step in the light takes a few frames to settle;
- **it counts photons** (shot noise, :func:`add_shot_noise`) and its USB stream is **JPEG** (:func:`jpeg_roundtrip`);
- **its rectification is not perfect**: the two images of a calibrated stereo pair keep a vertical offset of a few
  tenths of a pixel (measured on KITTI 06 and EuRoC MH_01 by ``benchmarks/honest_camera.py``), and every rectified
  image has been resampled once (:func:`shift_rows`).

The motion of a camera between two instants is known to the simulator; what a pixel saw then is found where it
matters most for a kart, on the ground (a point of the flat road) and, above the horizon, at infinity (a
rotation). Walls and props near the track are treated as far: their motion is under-estimated, never invented.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array, arc_2d, planar_pose
from kartpilot.core.types import Image

__all__ = ["add_shot_noise", "apply_gain", "auto_exposure_gain", "body_motion", "jpeg_roundtrip", "mean_level",
           "motion_maps", "moving_exposure", "shift_rows"]

# the coarse grid the motion maps are computed on (pixels); the maps are smooth, and bilinear between grid points
_GRID_PX = 8


def add_shot_noise(image: Image, strength: float, unit_noise: np.ndarray, read_sigma: float = 0.0) -> Image:
    """``image`` with noise whose variance is ``strength`` times each pixel's level plus ``read_sigma`` squared
    (grey levels; photon shot noise on top of the read noise: a sunlit road is noisier in absolute terms than its
    shade), drawn from ``unit_noise`` (unit normal float32, of the image's shape). Rounded to the nearest level."""
    sigma = np.sqrt(read_sigma ** 2 + strength * np.arange(256, dtype=np.float32)).astype(np.float32)
    spread = cv2.multiply(cv2.LUT(image, sigma), unit_noise, dtype=cv2.CV_32F)
    return cv2.add(image, spread, dtype=cv2.CV_8U)


def apply_gain(image: Image, gain: float) -> Image:
    """``image`` times ``gain``, cut at 255 and truncated: an exposure's gain (a table of the 256 levels)."""
    table = np.clip(np.arange(256, dtype=np.float32) * np.float32(gain), 0, 255).astype(np.uint8)
    return cv2.LUT(image, table)


def jpeg_roundtrip(image: Image, quality: int) -> Image:
    """``image`` compressed as JPEG at ``quality`` (1 to 100) and decompressed: what an MJPG camera delivers."""
    ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ConfigError(f"JPEG could not encode a {image.shape} image")
    return cv2.imdecode(encoded, cv2.IMREAD_UNCHANGED)


def body_motion(speed_mps: float, yaw_rate_radps: float, dt_s: float) -> Array:
    """The 4x4 pose of the body ``dt_s`` later (negative: earlier) in its frame now, for a planar motion at a
    constant speed along the body's x axis and a constant yaw rate (an arc; a line when the yaw rate is 0)."""
    return planar_pose(*arc_2d(speed_mps, yaw_rate_radps, dt_s))


def motion_maps(camera: PinholeCamera, speed_mps: float, yaw_rate_radps: float,
                row_offsets_s: Array) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap`` maps that turn the image rendered now into the image whose row ``v`` was exposed
    ``row_offsets_s[v]`` seconds from now: for each pixel, where the scene point it saw then is in the image now.

    The camera rides on the body at ``camera.pose_body_cam`` (the body frame on the ground, z up); the scene point
    is the flat ground's where the pixel's ray meets it, and the point at infinity above the horizon. The maps are
    computed on a grid every few pixels and interpolated (they are smooth)."""
    width, height = camera.width_px, camera.height_px
    offsets = np.asarray(row_offsets_s, float)
    if offsets.shape != (height,):
        raise ConfigError(f"motion_maps needs one time per row ({height}), got {offsets.shape}")
    cols, rows = math.ceil(width / _GRID_PX), math.ceil(height / _GRID_PX)
    # grid points where cv2.resize's bilinear interpolation puts them, so that it reproduces them exactly
    us = (np.arange(cols) + 0.5) * width / cols - 0.5
    vs = (np.arange(rows) + 0.5) * height / rows - 0.5
    k = camera.matrix
    mount = camera.pose_body_cam_array
    mount_inv = np.linalg.inv(mount)
    row_times = np.interp(vs, np.arange(height), offsets)
    # the camera at each grid row's time, in the body now (every row at once: body_motion's arc, vectorised)
    turn = yaw_rate_radps * row_times
    straight = np.abs(turn) < 1e-9
    radius = speed_mps / yaw_rate_radps if yaw_rate_radps != 0 else 0.0
    dx = np.where(straight, speed_mps * row_times, radius * np.sin(turn))
    dy = np.where(straight, 0.0, radius * (1.0 - np.cos(turn)))
    c, s = np.cos(turn), np.sin(turn)
    yaw = np.zeros((rows, 3, 3))
    yaw[:, 0, 0], yaw[:, 0, 1], yaw[:, 1, 0], yaw[:, 1, 1], yaw[:, 2, 2] = c, -s, s, c, 1.0
    rotation = yaw @ mount[:3, :3]  # (rows, 3, 3)
    origin = yaw @ mount[:3, 3] + np.stack([dx, dy, np.zeros(rows)], axis=1)  # (rows, 3)
    pixels = np.stack(np.broadcast_arrays(us[None, :], vs[:, None], 1.0), axis=1)  # (rows, 3, cols)
    rays = rotation @ (np.linalg.inv(k) @ pixels)  # (rows, 3, cols) in the body frame now
    down = rays[:, 2] < -1e-9
    lam = np.where(down, -origin[:, 2:3] / np.where(down, rays[:, 2], -1.0), 0.0)
    points = origin[:, :, None] + lam[:, None] * rays
    in_cam = np.where(down[:, None], mount_inv[:3, :3] @ points + mount_inv[:3, 3:4], mount_inv[:3, :3] @ rays)
    ahead = in_cam[:, 2] > 1e-9
    projected = k @ np.where(ahead[:, None], in_cam, pixels)
    depth = np.where(ahead, projected[:, 2], 1.0)
    map_x = np.where(ahead, projected[:, 0] / depth - us[None, :], 0.0).astype(np.float32)
    map_y = np.where(ahead, projected[:, 1] / depth - vs[:, None], 0.0).astype(np.float32)
    # the displacement is what is smooth: interpolated, and added to each pixel's own coordinates
    size = (width, height)
    full_x = cv2.resize(map_x, size, interpolation=cv2.INTER_LINEAR)
    full_y = cv2.resize(map_y, size, interpolation=cv2.INTER_LINEAR)
    full_x += np.arange(width, dtype=np.float32)[None, :]
    full_y += np.arange(height, dtype=np.float32)[:, None]
    return full_x, full_y


def moving_exposure(image: Image, camera: PinholeCamera, speed_mps: float, yaw_rate_radps: float,
                    readout_s: float = 0.0, exposure_s: float = 0.0, samples: int = 4) -> Image:
    """What a camera moving at ``speed_mps`` and ``yaw_rate_radps`` records of the scene rendered now: its rows
    read top to bottom over ``readout_s`` (rolling shutter; the middle row is read now), each exposed over
    ``exposure_s`` centred on its read-out (motion blur, ``samples`` instants averaged). Both 0: the image as
    it is."""
    if readout_s < 0 or exposure_s < 0:
        raise ConfigError("a camera's read-out and exposure times must not be negative")
    if (readout_s == 0 and exposure_s == 0) or (speed_mps == 0 and yaw_rate_radps == 0):
        return image
    height = camera.height_px
    rows = (np.arange(height) / max(height - 1, 1) - 0.5) * readout_s
    instants = [0.0] if exposure_s == 0 or samples < 2 else list(np.linspace(-0.5, 0.5, samples) * exposure_s)
    total = None
    for instant in instants:
        map_x, map_y = motion_maps(camera, speed_mps, yaw_rate_radps, rows + instant)
        warped = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if len(instants) == 1:
            return warped
        total = warped.astype(np.uint16) if total is None else cv2.add(total, warped, dtype=cv2.CV_16U)
    return cv2.convertScaleAbs(total, alpha=1.0 / len(instants))  # the mean, rounded to the nearest level


def mean_level(image: Image) -> float:
    """The grey level a camera's auto-exposure meters: the mean over the image, every fourth pixel."""
    return float(np.mean(image[::4, ::4]))


def auto_exposure_gain(gain: float, level: float, target_level: float, dt_s: float, time_constant_s: float,
                       limits: tuple[float, float] = (0.25, 4.0)) -> float:
    """The auto-exposure's gain after a frame ``dt_s`` long that it metered at ``level`` (grey, at gain 1): a first
    order approach, with ``time_constant_s``, to the gain that brings the level to ``target_level``, within the
    sensor's ``limits``."""
    wanted = min(max(target_level / max(level, 1e-3), limits[0]), limits[1])
    if time_constant_s <= 0:
        return wanted
    return gain + (1.0 - math.exp(-dt_s / time_constant_s)) * (wanted - gain)


def shift_rows(image: Image, dy_px: float) -> Image:
    """``image`` moved down by ``dy_px`` (a fraction of a pixel, typically) with bilinear resampling: a stereo
    pair's rectification residual (at 0 the image as it is)."""
    shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, dy_px]], np.float32)
    return cv2.warpAffine(image, shift, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)

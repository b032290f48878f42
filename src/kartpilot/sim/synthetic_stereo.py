"""A synthetic stereo sequence with exact ground truth, rendered without a GPU.

The scene is a straight road between two walls, all planes textured with seeded
multi-scale noise and blobs (so corners exist at every distance). Each plane is
cut into tiles; a tile is clipped against the near plane and drawn with the exact
homography from its texture to the image (``H = K [R e1, R e2, R o + t]``),
far tiles first. The camera drives forward with a constant yaw rate.

This is the demo's fallback when no dataset is present, and the tests' source of
images with perfectly known motion. It is not the closed-loop simulator.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.geometry import Array, invert_pose, pose_from_rt
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import Image, StereoFrame
from kartpilot.sensors.base import StereoSource

__all__ = ["SyntheticStereoConfig", "SyntheticStereoSource", "make_texture"]


@dataclass(frozen=True)
class SyntheticStereoConfig:
    """Scene and motion of the synthetic sequence (defaults: a small kart's stereo rig)."""

    frames: int = 40
    rate_hz: float = 10.0
    speed_mps: float = 2.0
    yaw_rate_dps: float = 6.0
    width_px: int = 640
    height_px: int = 360
    focal_px: float = 400.0
    baseline_m: float = 0.14
    camera_height_m: float = 0.6
    road_half_width_m: float = 4.0
    wall_height_m: float = 3.0
    length_m: float = 120.0
    tile_m: float = 4.0
    texel_m: float = 0.01
    seed: int = 0


def make_texture(size_px: int, rng: np.random.Generator) -> Image:
    """A corner-rich grayscale texture: multi-scale noise plus random blobs and boxes."""
    texture = np.zeros((size_px, size_px), np.float32)
    for cells, weight in ((4, 0.5), (16, 0.35), (64, 0.25), (size_px // 4, 0.15)):
        noise = rng.random((cells, cells)).astype(np.float32)
        texture += weight * cv2.resize(noise, (size_px, size_px), interpolation=cv2.INTER_CUBIC)
    image = cv2.normalize(texture, None, 30, 200, cv2.NORM_MINMAX).astype(np.uint8)
    for _ in range(size_px // 6):
        centre = tuple(int(c) for c in rng.integers(0, size_px, 2))
        value = int(rng.integers(0, 256))
        if rng.random() < 0.5:
            cv2.circle(image, centre, int(rng.integers(3, size_px // 24)), value, -1)
        else:
            corner = (centre[0] + int(rng.integers(4, size_px // 16)), centre[1] + int(rng.integers(4, size_px // 16)))
            cv2.rectangle(image, centre, corner, value, -1)
    return image


@dataclass(frozen=True)
class _Tile:
    origin: Array  # world position of texture pixel (0, 0)
    axis_u: Array  # world step per texel along texture x
    axis_v: Array  # world step per texel along texture y
    size_px: tuple[int, int]
    texture: Image


class SyntheticStereoSource(StereoSource):
    """Rectified stereo frames of the synthetic road, with exact left-camera ground truth."""

    def __init__(self, config: SyntheticStereoConfig | None = None) -> None:
        self.config = config or SyntheticStereoConfig()
        cfg = self.config
        self.name = f"synthetic-{cfg.seed}"
        camera = PinholeCamera(cfg.focal_px, cfg.focal_px, cfg.width_px / 2 - 0.5, cfg.height_px / 2 - 0.5,
                               cfg.width_px, cfg.height_px)
        self._rig = StereoRig(camera, cfg.baseline_m)
        rng = np.random.default_rng(cfg.seed)
        self._tiles = self._build_tiles(rng)
        self._poses = self._build_poses()

    @property
    def rig(self) -> StereoRig:
        return self._rig

    def __len__(self) -> int:
        return self.config.frames

    def ground_truth(self) -> Trajectory:
        stamps = np.arange(self.config.frames) / self.config.rate_hz
        return Trajectory(stamps, self._poses.copy())

    def frame(self, index: int) -> StereoFrame:
        pose_left = self._poses[index]
        pose_right = pose_left @ pose_from_rt(np.eye(3), np.array([self.config.baseline_m, 0.0, 0.0]))
        stamp_ns = round(index * 1e9 / self.config.rate_hz)
        return StereoFrame(index, stamp_ns, self.render(pose_left), self.render(pose_right))

    def _build_poses(self) -> Array:
        cfg = self.config
        dt = 1.0 / cfg.rate_hz
        yaw_rate = np.radians(cfg.yaw_rate_dps)
        poses = np.zeros((cfg.frames, 4, 4))
        for i in range(cfg.frames):
            yaw = yaw_rate * i * dt
            if abs(yaw_rate) < 1e-9:
                x, z = 0.0, cfg.speed_mps * i * dt
            else:
                radius = cfg.speed_mps / yaw_rate
                x, z = radius * (1 - np.cos(yaw)), radius * np.sin(yaw)
            rotation = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
            poses[i] = pose_from_rt(rotation, np.array([x, 0.0, z]))
        return poses

    def _build_tiles(self, rng: np.random.Generator) -> list[_Tile]:
        cfg = self.config
        texels = round(cfg.tile_m / cfg.texel_m)
        tiles = []
        start = -2 * cfg.tile_m
        forward = np.array([0.0, 0.0, cfg.texel_m])
        wall_texels = round(cfg.wall_height_m / cfg.texel_m)
        top = cfg.camera_height_m - cfg.wall_height_m
        for k in range(int(cfg.length_m / cfg.tile_m)):
            z0 = start + k * cfg.tile_m
            # ground: texture x runs right across the road, texture y runs forward
            for x0 in np.arange(-cfg.road_half_width_m, cfg.road_half_width_m, cfg.tile_m):
                tiles.append(_Tile(np.array([x0, cfg.camera_height_m, z0]), np.array([cfg.texel_m, 0.0, 0.0]),
                                   forward, (texels, texels), make_texture(texels // 2, rng)))
            # walls: texture x runs forward, texture y runs down from the top
            for side in (-1.0, 1.0):
                tiles.append(_Tile(np.array([side * cfg.road_half_width_m, top, z0]), forward,
                                   np.array([0.0, cfg.texel_m, 0.0]), (texels, wall_texels),
                                   make_texture(texels // 2, rng)))
        return tiles

    def render(self, pose_world_cam: Array) -> Image:
        """Render the grayscale view of a camera at ``pose_world_cam``."""
        cfg = self.config
        width, height = cfg.width_px, cfg.height_px
        image = np.tile(np.linspace(225, 175, height, dtype=np.float32)[:, None], (1, width)).astype(np.uint8)
        pose_cam_world = invert_pose(pose_world_cam)
        K = self._rig.camera.matrix
        near = 0.05
        draws = []
        for tile in self._tiles:
            w_px, h_px = tile.size_px
            corners_tex = np.array([[0, 0], [w_px, 0], [w_px, h_px], [0, h_px]], dtype=np.float64)
            corners_world = tile.origin + corners_tex[:, :1] * tile.axis_u + corners_tex[:, 1:] * tile.axis_v
            corners_cam = corners_world @ pose_cam_world[:3, :3].T + pose_cam_world[:3, 3]
            if np.all(corners_cam[:, 2] < near):
                continue
            polygon = _clip_near(corners_cam, near)
            projected = polygon @ K.T
            pixels = projected[:, :2] / projected[:, 2:3]
            if (pixels[:, 0].max() < 0 or pixels[:, 0].min() > width or pixels[:, 1].max() < 0
                    or pixels[:, 1].min() > height):
                continue
            draws.append((float(polygon[:, 2].mean()), tile, pixels))
        for _, tile, pixels in sorted(draws, key=lambda item: -item[0]):
            self._draw_tile(image, tile, pixels, pose_cam_world, K)
        return image

    def _draw_tile(self, image: Image, tile: _Tile, pixels: Array, pose_cam_world: Array, K: Array) -> None:
        height, width = image.shape
        x0 = int(max(np.floor(pixels[:, 0].min()), 0))
        y0 = int(max(np.floor(pixels[:, 1].min()), 0))
        x1 = int(min(np.ceil(pixels[:, 0].max()) + 1, width))
        y1 = int(min(np.ceil(pixels[:, 1].max()) + 1, height))
        if x1 <= x0 or y1 <= y0:
            return
        rotation, translation = pose_cam_world[:3, :3], pose_cam_world[:3, 3]
        texture_scale = tile.size_px[0] / tile.texture.shape[1]
        columns = np.stack([rotation @ tile.axis_u * texture_scale, rotation @ tile.axis_v * texture_scale,
                            rotation @ tile.origin + translation], axis=1)
        homography = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1]], dtype=np.float64) @ K @ columns
        warped = cv2.warpPerspective(tile.texture, homography, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE)
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        polygon = np.round((pixels - [x0, y0]) * 16).astype(np.int32)
        cv2.fillPoly(mask, [polygon], 255, lineType=cv2.LINE_8, shift=4)
        region = image[y0:y1, x0:x1]
        np.copyto(region, warped, where=mask > 0)


def _clip_near(polygon: Array, near: float) -> Array:
    """Clip a convex polygon (M, 3) in camera coordinates to z >= near (Sutherland-Hodgman)."""
    result = []
    count = len(polygon)
    for i in range(count):
        current, following = polygon[i], polygon[(i + 1) % count]
        current_in, following_in = current[2] >= near, following[2] >= near
        if current_in:
            result.append(current)
        if current_in != following_in:
            fraction = (near - current[2]) / (following[2] - current[2])
            result.append(current + fraction * (following - current))
    return np.asarray(result)

"""How a camera's images behave, measured the same way on real and simulated frames, so that a simulated camera can
be held to a real one: a rectified stereo pair's vertical offset, and how much the brightness moves between frames.

Used by ``benchmarks/honest_camera.py`` (the table in ``docs/simulator.md``) and by the simulator's tests.
"""

from __future__ import annotations

from collections.abc import Iterable

import cv2
import numpy as np

from kartpilot.core.types import Image

__all__ = ["brightness_steps_percent", "vertical_offset_px"]


def _grey(image: Image) -> Image:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def vertical_offset_px(left: Image, right: Image, max_points: int = 800) -> tuple[float, int]:
    """The median vertical offset (pixels, right minus left) of corners tracked from a rectified pair's left image
    into its right one, and how many agreed: 0 for a perfectly rectified pair, a few tenths of a pixel for a real
    one. A track counts when tracking back lands within 0.1 px of where it started and it moved no further right
    than half a pixel (a disparity is leftward)."""
    first, second = _grey(left), _grey(right)
    corners = cv2.goodFeaturesToTrack(first, max_points, 0.01, 8)
    if corners is None:
        return float("nan"), 0
    ahead, status, _ = cv2.calcOpticalFlowPyrLK(first, second, corners, None, winSize=(21, 21), maxLevel=4)
    back, status_back, _ = cv2.calcOpticalFlowPyrLK(second, first, ahead, None, winSize=(21, 21), maxLevel=4)
    moved = (ahead - corners)[:, 0]
    good = ((status[:, 0] == 1) & (status_back[:, 0] == 1)
            & (np.linalg.norm((back - corners)[:, 0], axis=1) < 0.1) & (moved[:, 0] < 0.5))
    if not good.any():
        return float("nan"), 0
    return float(np.median(moved[good, 1])), int(np.count_nonzero(good))


def brightness_steps_percent(images: Iterable[Image]) -> float:
    """The median change of the mean grey level from one frame to the next, in percent of the level: 0 for a
    camera with a fixed exposure in a fixed light, more when an auto-exposure follows the view."""
    levels = np.array([float(np.mean(_grey(image)[::2, ::2])) for image in images])
    if len(levels) < 2:
        return float("nan")
    return float(np.median(np.abs(np.diff(levels)) / np.maximum(levels[:-1], 1.0)) * 100.0)

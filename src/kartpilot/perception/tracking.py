"""Pyramidal Lucas-Kanade (KLT) tracking with a forward-backward check.

Bouguet, "Pyramidal implementation of the Lucas Kanade feature tracker", 2000.
A point is kept when tracking it forward and back returns within
``max_fb_error_px`` of where it started (Kalal et al., "Forward-backward error",
ICPR 2010).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import Image

__all__ = ["KltConfig", "track_klt"]


@dataclass(frozen=True)
class KltConfig:
    window_px: int = 21
    pyramid_levels: int = 3
    max_fb_error_px: float = 0.5
    iterations: int = 30

    def __post_init__(self) -> None:
        if self.window_px < 5 or self.window_px % 2 == 0:
            raise ConfigError(f"klt.window_px must be odd and at least 5, got {self.window_px}")


def track_klt(
    image_from: Image, image_to: Image, points_px: NDArray[np.float32], config: KltConfig,
    initial_px: NDArray[np.float32] | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Track points from one image into another.

    Args:
        points_px: (N, 2) positions in ``image_from``.
        initial_px: optional (N, 2) guesses in ``image_to`` (for example from a descriptor
            match), which makes the search local and sub-pixel.

    Returns:
        (N, 2) positions in ``image_to`` and an (N,) mask of points tracked reliably.
    """
    count = points_px.shape[0]
    if count == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, config.iterations, 0.01)
    window = (config.window_px, config.window_px)
    start = np.ascontiguousarray(points_px, dtype=np.float32).reshape(-1, 1, 2)
    flags = 0
    guess = None
    if initial_px is not None:
        guess = np.ascontiguousarray(initial_px, dtype=np.float32).reshape(-1, 1, 2).copy()
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    forward, status, _ = cv2.calcOpticalFlowPyrLK(
        image_from, image_to, start, guess, winSize=window, maxLevel=config.pyramid_levels,
        criteria=criteria, flags=flags)
    backward, status_back, _ = cv2.calcOpticalFlowPyrLK(
        image_to, image_from, forward, start.copy(), winSize=window, maxLevel=config.pyramid_levels,
        criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    fb_error = np.linalg.norm((backward - start).reshape(-1, 2), axis=1)
    tracked = forward.reshape(-1, 2)
    height, width = image_to.shape[:2]
    inside = (tracked[:, 0] >= 0) & (tracked[:, 0] <= width - 1) & (tracked[:, 1] >= 0) & (
        tracked[:, 1] <= height - 1)
    ok = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb_error < config.max_fb_error_px) & inside
    return tracked.astype(np.float32), ok

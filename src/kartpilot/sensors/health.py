"""Camera health: a camera that stops delivering, or delivers black or frozen frames, is noticed.

:func:`frame_problem` judges one frame against the camera's previous one (pure).
:class:`CameraWatchdog` keeps, per camera, when it last delivered a good frame and
reports each camera that has not for longer than ``timeout_s``, so a stalled camera is
reported within a bounded time and its last image is never silently reused.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import FrameSet, Image

__all__ = ["CameraWatchdog", "HealthConfig", "frame_problem"]


@dataclass(frozen=True)
class HealthConfig:
    """Attributes:
        black_mean: a frame whose mean gray level is below this is black (lens cap, dead sensor).
        min_std: a frame whose gray level varies less than this is blank (uniform: saturated, covered).
        timeout_s: a camera without a good frame for this long is reported.
    """

    black_mean: float = 8.0
    min_std: float = 2.0
    timeout_s: float = 0.3

    def __post_init__(self) -> None:
        if self.timeout_s <= 0:
            raise ConfigError("health.timeout_s must be positive")


def _small_gray(image: Image) -> np.ndarray:
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    return cv2.resize(gray, (64, 48), interpolation=cv2.INTER_AREA).astype(np.float32)


def frame_problem(image: Image | None, previous: Image | None, config: HealthConfig) -> str:
    """Empty for a good frame, else what is wrong with it: ``missing``, ``empty``, ``black``, ``blank``
    or ``frozen`` (identical to the previous frame)."""
    if image is None:
        return "missing"
    if image.size == 0:
        return "empty"
    small = _small_gray(image)
    if float(small.mean()) < config.black_mean:
        return "black"
    if float(small.std()) < config.min_std:
        return "blank"
    if previous is not None and np.array_equal(image, previous):
        return "frozen"  # byte for byte: a driver repeating its last buffer (sensor noise never does)
    return ""


class CameraWatchdog:
    """Per camera: the last good frame's stamp and the last image (for the frozen check)."""

    def __init__(self, cameras: list[str], config: HealthConfig | None = None) -> None:
        self.config = config or HealthConfig()
        self._last_good_ns: dict[str, int | None] = dict.fromkeys(cameras)
        self._previous: dict[str, Image | None] = dict.fromkeys(cameras)
        self._start_ns: int | None = None
        self.problems: dict[str, str] = {}
        self.frame_problems: dict[str, str] = {}

    def check(self, frames: FrameSet) -> dict[str, str]:
        """The cameras in trouble at ``frames.stamp_ns``, with the reason; updates the state.

        A camera is reported once it has had no good frame for ``timeout_s`` (since the start, if it
        never had one). ``frame_problems`` keeps what was wrong with each camera's frame in this set."""
        if self._start_ns is None:
            self._start_ns = frames.stamp_ns
        start = self._start_ns
        reported: dict[str, str] = {}
        for name in self._last_good_ns:
            image = frames.images.get(name)
            problem = frame_problem(image, self._previous[name], self.config)
            self.frame_problems[name] = problem
            if image is not None and image.size:
                self._previous[name] = image
            if not problem:
                self._last_good_ns[name] = frames.stamp_ns
                continue
            last_good = self._last_good_ns[name]
            since = last_good if last_good is not None else start
            if frames.stamp_ns - since > round(self.config.timeout_s * 1e9):
                reported[name] = f"no good frame for {(frames.stamp_ns - since) * 1e-9:.2f} s (last: {problem})"
        self.problems = reported
        return reported

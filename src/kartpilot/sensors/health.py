"""Sensor health: a camera that stops delivering, or delivers black or frozen frames, is noticed; so is a LiDAR
that stops, repeats its sweep or sees nothing.

:func:`frame_problem` judges one frame against the camera's previous one (pure).
:class:`CameraWatchdog` keeps, per camera, when it last delivered a good frame and
reports each camera that has not for longer than ``timeout_s``, so a stalled camera is
reported within a bounded time and its last image is never silently reused.
:func:`scan_problem` and :class:`LidarWatchdog` do the same for a LiDAR's sweeps; a LiDAR in trouble is not a
reason to stop (the cameras still see): the drive falls back to the camera-only rules and says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from kartpilot.core.config import check_values
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import FrameSet, Image, LaserScan

__all__ = ["CameraWatchdog", "HealthConfig", "LidarHealthConfig", "LidarWatchdog", "SweepSummary", "frame_problem",
           "scan_problem", "summarise_sweeps"]


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


@dataclass(frozen=True)
class LidarHealthConfig:
    """Attributes:
        timeout_s: a LiDAR without a good sweep for this long is reported (an RPLIDAR at 10 Hz: five sweeps).
        min_returns: a sweep with fewer returns than this is empty (a covered sensor). 0 by default: in open
            space a sweep may rightly see nothing within its range (the simulated venue's straights do).
    """

    timeout_s: float = 0.5
    min_returns: int = 0

    def __post_init__(self) -> None:
        check_values("lidar_health", self, (("timeout_s", self.timeout_s > 0, "positive"),
                                            ("min_returns", self.min_returns >= 0, "0 or more")))


def scan_problem(scan: LaserScan, previous: LaserScan | None, config: LidarHealthConfig) -> str:
    """Empty for a good sweep, else what is wrong with it: ``empty`` (fewer returns than ``min_returns``),
    ``frozen`` (the same ranges as the sweep before, to the bit: a sensor's noise never repeats) or ``stale``
    (not later than the sweep before)."""
    ranges = np.asarray(scan.ranges_m)
    if int(np.count_nonzero(np.isfinite(ranges))) < config.min_returns:
        return "empty"
    if previous is not None:
        if scan.stamp_ns <= previous.stamp_ns:
            return "stale"
        if np.isfinite(ranges).any() and np.array_equal(ranges, np.asarray(previous.ranges_m), equal_nan=True):
            return "frozen"  # (nothing in range twice is open space, not a hung driver)
    return ""


class LidarWatchdog:
    """Per LiDAR: when it last gave a good sweep, and the sweep before (for the frozen check). ``check`` returns
    the LiDARs in trouble; ``problems`` keeps them between sets (a set without a sweep changes nothing but the
    time since the last good one)."""

    def __init__(self, lidars: list[str], config: LidarHealthConfig | None = None) -> None:
        self.config = config or LidarHealthConfig()
        self._last_good_ns: dict[str, int | None] = dict.fromkeys(lidars)
        self._previous: dict[str, LaserScan | None] = dict.fromkeys(lidars)
        self.sweep_problems: dict[str, str] = dict.fromkeys(lidars, "no sweep yet")  # its last sweep's ("": good)
        self._start_ns: int | None = None
        self.problems: dict[str, str] = {}

    def check(self, frames: FrameSet) -> dict[str, str]:
        if self._start_ns is None:
            self._start_ns = frames.stamp_ns
        reported: dict[str, str] = {}
        for name in self._last_good_ns:
            scan = frames.scans.get(name)
            if scan is not None:
                problem = scan_problem(scan, self._previous[name], self.config)
                self._previous[name] = scan
                if not problem:
                    self._last_good_ns[name] = frames.stamp_ns
                self.sweep_problems[name] = problem or ""
            last_good = self._last_good_ns[name]
            since = last_good if last_good is not None else self._start_ns
            if frames.stamp_ns - since > round(self.config.timeout_s * 1e9):
                last = self.sweep_problems[name] or "no sweep"
                reported[name] = f"no good sweep for {(frames.stamp_ns - since) * 1e-9:.2f} s (last: {last})"
        self.problems = reported
        return reported


@dataclass(frozen=True)
class SweepSummary:
    """A LiDAR's sweeps over a stretch of time, as ``kartpilot lidar monitor`` and ``recordings info`` show them:
    how many, their rate and longest gap, the returns per sweep (median), the nearest return, and how many were
    frozen (a repeat of the one before), stale (not later than it) or empty."""

    sweeps: int
    rate_hz: float
    longest_gap_s: float
    returns_median: float
    nearest_m: float
    frozen: int
    stale: int
    empty: int

    def line(self) -> str:
        return (f"{self.sweeps} sweeps, {self.rate_hz:.2f} Hz, longest gap {self.longest_gap_s:.3f} s, "
                f"{self.returns_median:.0f} returns a sweep, nearest {self.nearest_m:.2f} m; frozen {self.frozen}, "
                f"stale {self.stale}, empty {self.empty}")


def summarise_sweeps(scans: list[LaserScan], config: LidarHealthConfig | None = None) -> SweepSummary:
    """The summary of a LiDAR's sweeps (pure)."""
    config = config or LidarHealthConfig(min_returns=1)
    stamps = np.array([s.stamp_ns for s in scans], np.int64)
    gaps = np.diff(stamps) * 1e-9 if len(stamps) > 1 else np.zeros(0)
    span = (stamps[-1] - stamps[0]) * 1e-9 if len(stamps) > 1 else 0.0
    returns = [int(np.count_nonzero(np.isfinite(s.ranges_m))) for s in scans]
    nearest = [float(np.nanmin(s.ranges_m)) for s, n in zip(scans, returns, strict=True) if n]
    problems = [scan_problem(scan, scans[k - 1] if k else None, config) for k, scan in enumerate(scans)]
    return SweepSummary(len(scans), (len(scans) - 1) / span if span > 0 else math.nan,
                        float(gaps.max()) if len(gaps) else math.nan,
                        float(np.median(returns)) if returns else math.nan, min(nearest) if nearest else math.nan,
                        problems.count("frozen"), problems.count("stale"), problems.count("empty"))

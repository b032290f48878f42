"""Fault injection for simulated drives: ``--inject KIND@SECONDS``.

Each kind breaks one thing the way it breaks on a kart, from its time on:

* ``camera-freeze``: every camera repeats its last image, byte for byte (a hung driver);
* ``black-frame``: one set of black images (a covered lens, a sensor glitch);
* ``vo-failure``: visual odometry fails on every frame (the localizer bridges, then reports lost);
* ``can-bus-off``: the CAN controller goes bus-off: every send fails for ``BUS_OFF_S``, then it recovers;
* ``heartbeat-loss``: the kart's ECUs and sensors stop reporting;
* ``ecu-error``: an ECU reports an error (the RDW steering ECU's error byte; our DBC's fault code);
* ``steering-sensor-loss``, ``steering-sensor-range``: the RDW kart's steering sensor goes silent, or
  reports counts out of its valid range (its ECU goes to its failsafe);
* ``loop-stall``: the loop hangs: its commands stop reaching the actuator, whose sender goes on;
* ``gamepad-unplug``: the operator's gamepad is unplugged;
* ``stage-exception``: a pipeline stage raises;
* ``lidar-loss``: the LiDAR's sweeps stop coming (a cable, its motor);
* ``lidar-freeze``: the LiDAR repeats its last sweep, range for range (a hung driver).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, TypeVar, cast

import can
import numpy as np

from kartpilot.core.errors import ConfigError, OdometryError
from kartpilot.core.types import ActuatorCommand, FrameSet, FrameSource, LaserScan
from kartpilot.odometry.vo import VisualOdometry, VOStep

__all__ = ["BUS_OFF_S", "KINDS", "SOURCE_FAULTS", "FailingVO", "FaultyBus", "InjectedSource", "Injection",
           "RaisingPipeline", "failing_vo", "parse_injection"]

V = TypeVar("V", bound=VisualOdometry)

KINDS = ("camera-freeze", "black-frame", "vo-failure", "can-bus-off", "heartbeat-loss", "ecu-error",
         "steering-sensor-loss", "steering-sensor-range", "loop-stall", "gamepad-unplug", "stage-exception",
         "lidar-loss", "lidar-freeze")
BUS_OFF_S = 0.5
SOURCE_FAULTS = ("camera-freeze", "black-frame", "lidar-loss", "lidar-freeze")
"""The faults of what the kart sees (:class:`InjectedSource`): any frame source takes them."""


@dataclass(frozen=True)
class Injection:
    kind: str
    at_s: float

    def active(self, stamp_ns: int) -> bool:
        return stamp_ns * 1e-9 >= self.at_s


def parse_injection(text: str) -> Injection:
    """``KIND@SECONDS`` -> Injection."""
    kind, _, at = text.partition("@")
    if kind not in KINDS:
        raise ConfigError(f"--inject {text!r}: the kind is one of {', '.join(KINDS)}")
    try:
        at_s = float(at)
    except ValueError as exc:
        raise ConfigError(f"--inject {text!r}: write KIND@SECONDS, e.g. camera-freeze@3.5") from exc
    if at_s < 0:
        raise ConfigError(f"--inject {text!r}: the time must not be negative")
    return Injection(kind, at_s)


class InjectedSource:
    """A frame source whose cameras freeze, or deliver one black set, and whose LiDAR stops or freezes, from the
    injection's time (what the cameras suffer leaves the scans alone, and the other way round)."""

    def __init__(self, source: FrameSource, injections: list[Injection]) -> None:
        self.source = source
        self.freeze = next((i for i in injections if i.kind == "camera-freeze"), None)
        self.black = next((i for i in injections if i.kind == "black-frame"), None)
        self.lidar_loss = next((i for i in injections if i.kind == "lidar-loss"), None)
        self.lidar_freeze = next((i for i in injections if i.kind == "lidar-freeze"), None)
        self._frozen: FrameSet | None = None
        self._last: FrameSet | None = None
        self._black_done = False
        self._frozen_scans: dict[str, LaserScan] = {}

    def read(self) -> FrameSet | None:
        frames = self.source.read()
        if frames is None:
            return None
        scans = self._scans(frames)
        if self.freeze is not None and self.freeze.active(frames.stamp_ns):
            if self._frozen is None:
                self._frozen = self._last if self._last is not None else frames
            return FrameSet(frames.index, frames.stamp_ns, {k: v.copy() for k, v in self._frozen.images.items()},
                            scans=scans)
        if self.black is not None and not self._black_done and self.black.active(frames.stamp_ns):
            self._black_done = True
            return FrameSet(frames.index, frames.stamp_ns, {k: np.zeros_like(v) for k, v in frames.images.items()},
                            scans=scans)
        self._last = frames
        return frames if scans is frames.scans else replace(frames, scans=scans)

    def _scans(self, frames: FrameSet) -> Mapping[str, LaserScan]:
        if self.lidar_loss is not None and self.lidar_loss.active(frames.stamp_ns):
            return {}
        if self.lidar_freeze is not None and self.lidar_freeze.active(frames.stamp_ns):
            if not self._frozen_scans:
                self._frozen_scans = dict(frames.scans)
            # the same ranges again, under the sweep's own new time (a driver that hangs keeps stamping)
            return {name: replace(self._frozen_scans[name], stamp_ns=scan.stamp_ns)
                    for name, scan in frames.scans.items() if name in self._frozen_scans}
        return frames.scans


class FaultyBus(can.BusABC):
    """A bus whose sends fail (bus-off) from ``off_from_ns`` for ``BUS_OFF_S``; reads pass through."""

    def __init__(self, bus: can.BusABC, clock: Callable[[], int], off_from_s: float | None) -> None:
        super().__init__(channel=getattr(bus, "channel_info", "faulty"))
        self.bus = bus
        self.clock = clock
        self.off_from_s = off_from_s

    def _off(self) -> bool:
        if self.off_from_s is None:
            return False
        now_s = self.clock() * 1e-9
        return self.off_from_s <= now_s < self.off_from_s + BUS_OFF_S

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._off():
            raise can.CanOperationError("bus-off (injected)")
        self.bus.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.bus.recv(timeout), False

    def shutdown(self) -> None:
        self.bus.shutdown()
        super().shutdown()


class FailingVO:
    """A VO that fails on every frame set from the injection's time (``vo-failure``); otherwise the VO itself."""

    def __init__(self, vo: VisualOdometry, injection: Injection) -> None:
        self.vo, self.injection = vo, injection

    def process(self, frames: FrameSet) -> VOStep:
        if self.injection.active(frames.stamp_ns):
            raise OdometryError("visual odometry failed (injected)")
        return self.vo.process(frames)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.vo, name)


def failing_vo(injection: Injection) -> Callable[[V], V]:
    """The ``wrap_vo`` seam of a localiser for the ``vo-failure`` injection."""
    def wrap(vo: V) -> V:
        return cast(V, FailingVO(vo, injection))

    return wrap


class RaisingPipeline:
    """A pipeline that raises from ``at_s`` (the ``stage-exception`` injection); otherwise the pipeline."""

    def __init__(self, pipeline: Callable[[FrameSet], ActuatorCommand], at_s: float) -> None:
        self.pipeline, self.at_s = pipeline, at_s

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        if frames.stamp_ns * 1e-9 >= self.at_s:
            raise RuntimeError("a stage raised (injected)")
        return self.pipeline(frames)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.pipeline, name)

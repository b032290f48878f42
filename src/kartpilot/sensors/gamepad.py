"""A gamepad through the Linux joystick interface (``/dev/input/js0``), mapped as an Xbox controller.

The kernel's joystick device delivers 8-byte events (time, value, type, number); a reader thread
keeps the axes and buttons. Unplugging the pad ends the reads (an error or end of file): the pad is
then ``connected = False``, which the supervisor treats as a lost operator link, and the reader
tries to open the device again every ``reopen_s``. No library is needed for this.

:func:`operator_input` (pure) turns the axes and buttons into an :class:`OperatorInput`: the right
trigger is the throttle, the left trigger the brake, the left stick steers; holding RB lets autonomy
run (the dead-man), B is the emergency stop; X asks for manual driving, Y for autonomy, Back to
disarm, Start to re-arm after a fault.
"""

from __future__ import annotations

import logging
import os
import struct
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, OperatorInput

__all__ = ["Gamepad", "GamepadMapping", "operator_input"]

log = logging.getLogger(__name__)

EVENT = struct.Struct("<IhBB")  # time_ms, value, type, number
JS_BUTTON, JS_AXIS, JS_INIT = 0x01, 0x02, 0x80
AXIS_MAX = 32767.0


@dataclass(frozen=True)
class GamepadMapping:
    """Axis and button numbers (the xpad driver's Xbox layout by default) and the scaling.

    Attributes:
        max_steer_rad: the steer at full stick.
        deadzone: stick and trigger travel (0 to 1) that counts as none.
        triggers_rest_negative: triggers read -32767 released and +32767 pressed (xpad); False for 0..32767.
    """

    steer_axis: int = 0
    throttle_axis: int = 5
    brake_axis: int = 2
    hold_button: int = 5
    estop_button: int = 1
    manual_button: int = 2
    autonomous_button: int = 3
    disarm_button: int = 6
    rearm_button: int = 7
    max_steer_rad: float = 0.4
    deadzone: float = 0.08
    triggers_rest_negative: bool = True

    def __post_init__(self) -> None:
        if not 0 <= self.deadzone < 1:
            raise ConfigError("gamepad.deadzone must be in [0, 1)")


def _dead(value: float, deadzone: float) -> float:
    if abs(value) <= deadzone:
        return 0.0
    return (abs(value) - deadzone) / (1.0 - deadzone) * (1.0 if value > 0 else -1.0)


def _trigger(raw: int, mapping: GamepadMapping) -> float:
    fraction = (raw + AXIS_MAX) / (2 * AXIS_MAX) if mapping.triggers_rest_negative else raw / AXIS_MAX
    return _dead(min(max(fraction, 0.0), 1.0), mapping.deadzone)


def operator_input(axes: Mapping[int, int], buttons: Mapping[int, int], pressed: set[int], mapping: GamepadMapping,
                   connected: bool, stamp_ns: int) -> OperatorInput:
    """The person's input from the pad's state. ``pressed``: buttons that went down since the last call
    (requests are edges, not levels)."""
    rest = -int(AXIS_MAX) if mapping.triggers_rest_negative else 0
    steer = -_dead(axes.get(mapping.steer_axis, 0) / AXIS_MAX, mapping.deadzone) * mapping.max_steer_rad
    throttle = _trigger(axes.get(mapping.throttle_axis, rest), mapping)
    brake = _trigger(axes.get(mapping.brake_axis, rest), mapping)
    if brake > 0:
        throttle = 0.0
    request = next((name for name, button in (("disarm", mapping.disarm_button), ("rearm", mapping.rearm_button),
                                              ("manual", mapping.manual_button),
                                              ("autonomous", mapping.autonomous_button)) if button in pressed), "")
    return OperatorInput(connected=connected, estop=bool(buttons.get(mapping.estop_button, 0)),
                         hold=bool(buttons.get(mapping.hold_button, 0)), request=request,
                         manual=ActuatorCommand(stamp_ns, steer, throttle, brake), source="gamepad")


class Gamepad:
    """Reads a joystick device in a thread; calling it gives the current :class:`OperatorInput`."""

    def __init__(self, device: str | Path = "/dev/input/js0", mapping: GamepadMapping | None = None,
                 reopen_s: float = 0.5) -> None:
        self.device = Path(device)
        self.mapping = mapping or GamepadMapping()
        self.reopen_s = reopen_s
        self.connected = False
        self.disconnects = 0
        self._axes: dict[int, int] = {}
        self._buttons: dict[int, int] = {}
        self._pressed: set[int] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> Gamepad:
        self._thread = threading.Thread(target=self._run, name="gamepad", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                fd = os.open(self.device, os.O_RDONLY)
            except OSError:
                time.sleep(self.reopen_s)
                continue
            with self._lock:
                self.connected = True
            log.info("gamepad %s connected", self.device)
            try:
                while not self._stop.is_set():
                    data = os.read(fd, EVENT.size)
                    if len(data) < EVENT.size:
                        break  # end of file: the device went away
                    self._event(*EVENT.unpack(data))
            except OSError:
                pass  # ENODEV: unplugged
            finally:
                os.close(fd)
            with self._lock:
                self.connected = False
                self.disconnects += 1
                self._axes.clear()
                self._buttons.clear()  # a vanished pad holds nothing (no hold, no throttle)
            log.error("gamepad %s disconnected", self.device)
            time.sleep(self.reopen_s)

    def _event(self, _time_ms: int, value: int, kind: int, number: int) -> None:
        with self._lock:
            if kind & JS_AXIS:
                self._axes[number] = value
            elif kind & JS_BUTTON:
                if value and not self._buttons.get(number, 0) and not kind & JS_INIT:
                    self._pressed.add(number)
                self._buttons[number] = value

    def __call__(self, stamp_ns: int) -> OperatorInput:
        with self._lock:
            pressed, self._pressed = self._pressed, set()
            return operator_input(dict(self._axes), dict(self._buttons), pressed, self.mapping, self.connected,
                                  stamp_ns)

"""A fake RPLIDAR on a pseudo-terminal, speaking the maker's serial protocol (Slamtec, "RPLIDAR Interface
Protocol and Application Notes": a request is 0xA5 and a command byte, with a size, a payload and an XOR checksum
when it carries one; an answer starts with the descriptor 0xA5 0x5A, a 30-bit length and a 2-bit mode, and a type
byte). It answers GET_INFO (0x50), GET_HEALTH (0x52), SCAN (0x20: 5-byte measurements until STOP), STOP (0x25),
RESET (0x40) and the motor's SET_PWM (0xF0), and can report bad health, put garbage on the line, or vanish."""

from __future__ import annotations

import contextlib
import os
import random
import select
import struct
import threading
import time
import tty
from collections.abc import Callable

INFO = bytes([0x18, 0x1D, 0x01, 0x05]) + bytes(range(16))  # model 0x18 (an A2M8), firmware 1.29, hardware 5
HEALTH_STATUS = {"Good": 0, "Warning": 1, "Error": 2}


def descriptor(length: int, multiple: bool, data_type: int) -> bytes:
    return b"\xa5\x5a" + struct.pack("<I", length | (int(multiple) << 30)) + bytes([data_type])


def measurement(start: bool, quality: int, angle_cw_deg: float, distance_mm: float) -> bytes:
    """One 5-byte measurement: the start flag and its inverse, the quality, the angle in 1/64 deg with the check
    bit, the distance in 1/4 mm."""
    angle_q6 = round(angle_cw_deg * 64) % (360 * 64)
    distance_q2 = round(distance_mm * 4)
    return bytes([(quality << 2) | ((not start) << 1) | int(start), ((angle_q6 & 0x7F) << 1) | 1, angle_q6 >> 7,
                  distance_q2 & 0xFF, distance_q2 >> 8])


class FakeRplidar:
    """The device behind a pty: :attr:`port` is its name. ``scene(angle_cw_deg)`` gives the distance in mm (0: no
    return) of each of ``samples`` measurements a sweep, at ``rate_hz`` sweeps a second."""

    def __init__(self, scene: Callable[[float], float], health: str = "Good", error_code: int = 0,
                 rate_hz: float = 10.0, samples: int = 360, garbage_at_sweeps: tuple[int, ...] = (),
                 garbage_always_from: int | None = None, vanish_after: int | None = None) -> None:
        self.scene = scene
        self.health = health
        self.error_code = error_code
        self.rate_hz = rate_hz
        self.samples = samples
        self.garbage_at_sweeps = set(garbage_at_sweeps)
        self.garbage_always_from = garbage_always_from
        self.vanish_after = vanish_after
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave  # kept open, so the pty lives until the fake closes
        self.requests: list[int] = []
        self.pwm: list[int] = []
        self.sweeps_sent = 0
        self._scanning = False
        self._stop = threading.Event()
        self._rng = random.Random(5)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            written = os.write(self.master, view)
            view = view[written:]

    def _answer(self, buffer: bytearray) -> None:
        while len(buffer) >= 2:
            if buffer[0] != 0xA5:
                del buffer[0]
                continue
            command = buffer[1]
            if command & 0x80 or command == 0xF0:  # a command with a payload: size, payload, checksum
                if len(buffer) < 3 or len(buffer) < 4 + buffer[2]:
                    return
                size = buffer[2]
                payload, checksum = bytes(buffer[3:3 + size]), buffer[3 + size]
                check = 0
                for value in buffer[:3 + size]:
                    check ^= value
                del buffer[:4 + size]
                if check != checksum:
                    continue  # the device ignores a request whose checksum is wrong
                if command == 0xF0:
                    self.pwm.append(struct.unpack("<H", payload)[0])
                self.requests.append(command)
                continue
            del buffer[:2]
            self.requests.append(command)
            if command == 0x50:
                self._send(descriptor(20, False, 0x04) + INFO)
            elif command == 0x52:
                self._send(descriptor(3, False, 0x06) + bytes([HEALTH_STATUS[self.health]])
                           + struct.pack("<H", self.error_code))
            elif command in (0x20, 0x21):
                self._send(descriptor(5, True, 0x81))
                self._scanning = True
            elif command in (0x25, 0x40):
                self._scanning = False

    def _sweep(self) -> bytes:
        out = bytearray()
        for k in range(self.samples):
            angle = 360.0 * k / self.samples
            distance = self.scene(angle)
            if distance > 0:  # a real sensor's noise: no two sweeps alike
                distance += self._rng.uniform(-2.0, 2.0)
            out += measurement(k == 0, 47 if distance > 0 else 0, angle, distance)
        garbage = self.sweeps_sent in self.garbage_at_sweeps or (
            self.garbage_always_from is not None and self.sweeps_sent >= self.garbage_always_from)
        if garbage:  # a loose connector: bytes that are no measurement, in the middle of the sweep
            middle = len(out) // 2
            out[middle:middle] = bytes([0x00, 0x00, 0x00]) + bytes(self._rng.randrange(256) & 0xFC for _ in range(7))
        return bytes(out)

    def _run(self) -> None:
        buffer = bytearray()
        next_sweep = time.monotonic()
        while not self._stop.is_set():
            readable, _, _ = select.select([self.master], [], [], 0.005)
            if readable:
                try:
                    buffer += os.read(self.master, 4096)
                except OSError:
                    return
                self._answer(buffer)
            if self._scanning and time.monotonic() >= next_sweep:
                if self.vanish_after is not None and self.sweeps_sent >= self.vanish_after:
                    self.vanish()
                    return
                self._send(self._sweep())
                self.sweeps_sent += 1
                next_sweep = time.monotonic() + 1.0 / self.rate_hz

    def vanish(self) -> None:
        """Unplugged: the device's side of the line closes."""
        self._stop.set()
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def close(self) -> None:
        self.vanish()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)

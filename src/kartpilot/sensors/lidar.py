"""A planar LiDAR on the kart: the RPLIDAR family (A1, A2, A3, S1) through ``rplidar-roboticia``.

Chosen against the alternatives (docs/lidar.md): Slamtec's own SDK is C++ (a compiler and a binding on the kart);
ROS 2's ``sl_lidar_ros2`` node needs a ROS installation, which a team that runs ROS reads through kartpilot's bag
and MCAP readers instead. ``rplidar-roboticia`` is one pure-Python module over pyserial that speaks the maker's
serial protocol (its command and answer frames, the scan modes, the motor's PWM, the device's health), the library
a 2025 team drove its RPLIDAR with.

:class:`RplidarScanner` runs the sensor in a thread: it reads the device's information and health first (a device
that reports ``Error`` is refused with its code, before a drive starts), starts the motor and the scan, and turns
the stream of measurements into sweeps (:func:`sweep_from_measures`, pure). Garbage on the line (a loose
connector) makes the library raise; the scanner stops the scan, empties the input and starts again, and gives up
after ``max_resyncs`` in a row with an error that says so. A device that goes away (unplugged) ends the thread
with an error naming the port. Neither stops the drive by itself: :class:`~kartpilot.sensors.health.LidarWatchdog`
notices the sweeps stopping, and the drive falls back to the camera-only rules. :class:`WithScans` puts the sweeps
on the frame sets of any frame source.

The RPLIDAR measures clockwise from its front in degrees; a :class:`~kartpilot.core.types.LaserScan` counts
counter-clockwise in radians (ROS's convention), so every angle changes sign on the way in.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from kartpilot.core.config import check_values
from kartpilot.core.errors import ConfigError, SensorError
from kartpilot.core.types import FrameSet, FrameSource, LaserScan

__all__ = ["RplidarConfig", "RplidarScanner", "WithScans", "sweep_from_measures"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RplidarConfig:
    """Attributes:
        port: the serial device (``/dev/ttyUSB0``; a udev name such as ``/dev/rplidar`` survives re-plugging), or
            any URL pyserial opens (``socket://HOST:PORT`` for a serial-over-network bridge).
        baudrate: 115200 for the A1 and A2, 256000 for the A3 and S1.
        scan_mode: ``normal`` (about 4,000 measurements a second) or ``express`` (twice as many, A2 and later).
        motor_pwm: the motor's PWM duty (0 to 1023; 660 spins an A2 at about 10 Hz).
        step_deg: the sweep's angle between beams; each beam keeps its nearest return.
        range_min_m, range_max_m: what a return must lie within to count.
        max_resyncs: garbage on the line this many times in a row gives up.
        timeout_s: the serial port's read timeout.
    """

    port: str = "/dev/ttyUSB0"
    baudrate: int = 115200
    scan_mode: str = "normal"
    motor_pwm: int = 660
    step_deg: float = 1.0
    range_min_m: float = 0.15
    range_max_m: float = 12.0
    max_resyncs: int = 5
    timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if not self.port:
            raise ConfigError("lidar.port must name the serial device")
        if self.baudrate not in (115200, 256000, 1000000):
            raise ConfigError(f"lidar.baudrate {self.baudrate}: 115200 (A1, A2), 256000 (A3, S1) or 1000000 (S2)")
        if self.scan_mode not in ("normal", "express"):
            raise ConfigError(f"lidar.scan_mode {self.scan_mode!r}: normal or express")
        if not 0 <= self.motor_pwm <= 1023:
            raise ConfigError(f"lidar.motor_pwm {self.motor_pwm}: 0 to 1023")
        check_values("lidar", self, (("step_deg", 0.1 <= self.step_deg <= 10, "0.1 to 10"),
                                     ("range_min_m", 0 <= self.range_min_m < self.range_max_m, "0 up to range_max_m"),
                                     ("range_max_m", self.range_max_m <= 100, "at most 100"),
                                     ("max_resyncs", self.max_resyncs >= 0, "not negative"),
                                     ("timeout_s", 0 < self.timeout_s <= 10, "above 0, at most 10")))


def sweep_from_measures(measures: Sequence[tuple[float, float, float]], stamp_ns: int, scan_time_s: float,
                        config: RplidarConfig) -> LaserScan:
    """One sweep from an RPLIDAR's measurements ``(quality, angle clockwise in degrees, distance in mm)``: beams
    ``step_deg`` apart counter-clockwise from -180 deg, each with its nearest return within the range (NaN where
    none), its intensity the return's quality (0 to 63)."""
    beams = round(360.0 / config.step_deg)
    step = math.tau / beams
    ranges = np.full(beams, np.inf)
    strengths = np.zeros(beams, np.float32)
    if len(measures):
        data = np.asarray(measures, np.float64).reshape(-1, 3)
        distance = data[:, 2] / 1000.0
        valid = (distance >= config.range_min_m) & (distance <= config.range_max_m)
        angle = np.remainder(-np.radians(data[valid, 1]) + math.pi, math.tau)  # counter-clockwise, from -180 deg
        index = np.minimum((angle / step + 0.5).astype(int), beams) % beams
        order = np.argsort(-distance[valid])  # the nearest written last: it stays
        ranges[index[order]] = distance[valid][order]
        strengths[index[order]] = data[valid, 0][order]
    ranges[np.isinf(ranges)] = np.nan
    return LaserScan(stamp_ns, -math.pi, step, scan_time_s / beams if scan_time_s > 0 else 0.0, max(scan_time_s, 0.0),
                     config.range_min_m, config.range_max_m, ranges.astype(np.float32),
                     np.where(np.isnan(ranges), 0.0, strengths).astype(np.float32))


class _Port:
    """The serial port as the library uses it, with the modem lines optional: an A2 or A3 runs its motor on the
    PWM command, and a port without modem lines (a USB bridge that does not wire DTR, a pseudo-terminal, a network
    bridge) refuses the A1's DTR switch, which is then left alone."""

    def __init__(self, port: Any) -> None:
        self._port = port

    def setDTR(self, value: bool) -> None:
        try:
            self._port.setDTR(value)
        except OSError as exc:
            if exc.errno not in (errno.ENOTTY, errno.EINVAL):
                raise
            log.debug("LiDAR port has no DTR line (%s): the motor runs on its PWM command", exc)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._port, name)


def _driver_class() -> type:
    try:
        import serial
        from rplidar import RPLidar
    except ImportError as exc:  # pragma: no cover - both are kartpilot's dependencies
        raise SensorError(f"the RPLIDAR driver needs rplidar-roboticia and pyserial: {exc}") from None

    class Driver(RPLidar):
        """rplidar-roboticia's RPLidar (0.9.5, pinned), its port opened by URL, its modem lines optional, and its
        answers read with the port's timeout: the library waits for an answer's bytes in a loop without one, so a
        device that stops sending (or whose port is gone without an error) would hold the thread for good."""

        _serial: Any

        def _read_response(self, dsize: int) -> bytes:
            data = self._serial.read(dsize)
            if len(data) < dsize:
                raise SensorError(f"no data for {self.timeout} s ({len(data)} of {dsize} bytes)")
            return bytes(data)

        def connect(self) -> None:
            if self._serial is not None:
                self.disconnect()
            try:
                self._serial = _Port(serial.serial_for_url(self.port, self.baudrate, parity=serial.PARITY_NONE,
                                                           stopbits=serial.STOPBITS_ONE, timeout=self.timeout))
            except (serial.SerialException, OSError, ValueError) as err:
                from rplidar import RPLidarException

                raise RPLidarException(f"cannot open {self.port}: {err}") from None

    return Driver


class RplidarScanner:
    """An RPLIDAR in a thread: :meth:`start` checks the device and starts it; :meth:`take` returns the sweeps
    completed since the last call; :attr:`error` says why the thread ended, if it did."""

    def __init__(self, config: RplidarConfig, clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.config = config
        self.clock = clock
        self.info: dict[str, Any] = {}
        self.health: tuple[str, int] = ("unknown", 0)
        self.error: str | None = None
        self.resyncs = 0
        self.sweeps = 0
        self._device: Any = None
        self._sweeps: list[LaserScan] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> RplidarScanner:
        """Open the port, read the device's information and health (``Error`` is refused with its code; a
        ``Warning`` is logged), and start scanning in the background."""
        from rplidar import RPLidarException

        where = f"LiDAR on {self.config.port}"
        try:
            self._device = _driver_class()(self.config.port, self.config.baudrate, self.config.timeout_s,
                                           logger=logging.getLogger("rplidar"))
            self._device.clean_input()
            self.info = self._device.get_info()
            self.health = self._device.get_health()
        except (RPLidarException, SensorError) as exc:  # the library's, or no answer within the timeout
            self.close()
            raise SensorError(f"{where}: {exc}") from None
        except (OSError, ValueError, KeyError, IndexError) as exc:
            self.close()
            raise SensorError(f"{where}: no RPLIDAR answers there ({type(exc).__name__}: {exc})") from None
        if not isinstance(self.info, dict) or not isinstance(self.health, tuple):
            self.close()
            raise SensorError(f"{where}: the device was busy sending and did not answer (unplug it, or wait)")
        status, code = self.health
        if status == "Error":
            self.close()
            raise SensorError(f"{where} reports its health as Error (code {code:#06x}): it has stopped to protect "
                              "itself; power it off and on, and look at its window and motor")
        if status == "Warning":
            log.warning("%s reports a Warning (code %#06x): it measures, but look at it", where, code)
        log.info("%s: model %s, firmware %s, hardware %s, serial %s", where, self.info.get("model"),
                 self.info.get("firmware"), self.info.get("hardware"), self.info.get("serialnumber"))
        self._thread = threading.Thread(target=self._run, name="lidar", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        from rplidar import RPLidarException

        measures: list[tuple[float, float, float]] = []
        started_ns: int | None = None
        while not self._stop.is_set():
            try:
                self._device.motor_speed = self.config.motor_pwm
                for new_scan, quality, angle, distance in self._device.iter_measures(self.config.scan_mode):
                    if self._stop.is_set():
                        return
                    if new_scan:
                        now = self.clock()
                        if started_ns is not None and len(measures) > 5:
                            scan_time = (now - started_ns) * 1e-9
                            sweep = sweep_from_measures(measures, started_ns, scan_time, self.config)
                            with self._lock:
                                self._sweeps.append(sweep)
                                del self._sweeps[:-20]  # a consumer that stopped taking keeps the latest
                            self.sweeps += 1
                            self.resyncs = 0
                        started_ns, measures = now, []
                    if quality is not None and distance > 0:
                        measures.append((float(quality), float(angle), float(distance)))
            except RPLidarException as exc:
                if self._stop.is_set():
                    return
                self.resyncs += 1
                log.warning("LiDAR on %s: garbage on the line (%s): starting its scan again (%d in a row)",
                            self.config.port, exc, self.resyncs)
                if self.resyncs > self.config.max_resyncs:
                    self.error = (f"LiDAR on {self.config.port}: garbage on the line {self.resyncs} times in a row "
                                  f"({exc}); is its cable loose or its baud rate ({self.config.baudrate}) wrong?")
                    log.error("%s", self.error)
                    return
                with contextlib.suppress(Exception):  # the next start says what is wrong, if anything
                    self._device.stop()
                    self._device.clean_input()
                measures, started_ns = [], None
            except Exception as exc:  # the port went away (unplugged, silent): said once, and the thread ends
                if self._stop.is_set():
                    return
                self.error = f"LiDAR on {self.config.port} went away: {type(exc).__name__}: {exc}"
                log.error("%s", self.error)
                return

    def take(self) -> list[LaserScan]:
        """The sweeps completed since the last call (the latest 20 at most), oldest first."""
        with self._lock:
            sweeps, self._sweeps = self._sweeps, []
        return sweeps

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def close(self) -> None:
        """Stop the scan and the motor and let go of the port (whatever state the device is in)."""
        self._stop.set()
        device, self._device = self._device, None
        if device is not None:
            for step in (device.stop, device.stop_motor, device.disconnect):
                with contextlib.suppress(Exception):  # a device that went away cannot be stopped
                    step()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def __enter__(self) -> RplidarScanner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class WithScans:
    """A frame source whose sets carry a LiDAR's newest sweep (the one that began last, since the set before) under
    ``name``; the others are not lost to a recorder (``taken`` counts them) but a set holds one sweep a LiDAR."""

    def __init__(self, source: FrameSource, scanner: RplidarScanner, name: str = "lidar") -> None:
        self.source = source
        self.scanner = scanner
        self.name = name
        self.taken = 0
        self._told: str | None = None

    def read(self) -> FrameSet | None:
        frames = self.source.read()
        if frames is None:
            return None
        sweeps = self.scanner.take()
        self.taken += len(sweeps)
        if self.scanner.error and self._told != self.scanner.error:
            self._told = self.scanner.error
            log.error("%s: the drive goes on without it (its watchdog reports it)", self.scanner.error)
        if not sweeps:
            return frames
        return replace(frames, scans={**frames.scans, self.name: sweeps[-1]})

    def close(self) -> None:
        close = getattr(self.source, "close", None)
        if close is not None:
            close()
        self.scanner.close()

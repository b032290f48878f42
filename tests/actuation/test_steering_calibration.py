"""Steering calibration against the simulated RDW ECUs: the sweep recovers a known mapping, with a simulated
clock; the CLI writes it into the rig file, against ECUs answering in real time."""

import math
import threading
import time

import pytest

from kartpilot.actuation.can_bus import CanConfig, open_bus
from kartpilot.actuation.steering_calibration import (
    fit_steering,
    steer_of_turning_circle,
    steering_actuator,
    sweep_steering,
    sweep_values,
)
from kartpilot.calibration.rig import Rig, load_rig, save_rig
from kartpilot.cli.main import main
from kartpilot.core.errors import CalibrationError
from kartpilot.core.vehicle import SteeringCalibration, get_vehicle
from kartpilot.sim.can_ecu import RdwEcus

SDC = get_vehicle("sdc-kart")
# a kart whose steering differs from the built-in default: another slope, sign and a sensor offset
TRUE = SteeringCalibration(value_sign=-1, rad_per_value=0.29, counts_per_value=-555.0, count_offset=17.0)


class _Servo:
    """The simulated wheels: they follow the ECU's target at a finite rate."""

    def __init__(self) -> None:
        self.steer_rad = 0.0

    def follow(self, target_rad: float, dt_s: float, rate_radps: float = 1.2) -> None:
        step = rate_radps * dt_s
        self.steer_rad += min(max(target_rad - self.steer_rad, -step), step)


def test_the_sweep_recovers_a_known_steering_mapping():
    config = CanConfig(channel=f"steer-cal-{time.monotonic_ns()}", protocol="rdw")
    clock_ns = [0]
    servo = _Servo()
    ecus = RdwEcus(open_bus(config), lambda: clock_ns[0], TRUE, lambda: (servo.steer_rad, 0.0))
    values = sweep_values(1.0, 9)
    actuator, protocol = steering_actuator(open_bus(config), config, values, lambda: clock_ns[0])

    def wait(seconds: float) -> None:  # the simulated world goes on while the sweep waits
        for _ in range(round(seconds / 0.005)):
            clock_ns[0] += 5_000_000
            actuator.tick()
            servo.follow(ecus.step().steer_rad, 0.005)

    # the turning circle a person measures at full lock (value 1.25) on this kart
    full_lock_rad = TRUE.steer_of_value(1.25)
    diameter = 2 * SDC.wheelbase_m / math.tan(abs(full_lock_rad))
    rad_per_value = steer_of_turning_circle(diameter, SDC.wheelbase_m) / 1.25
    try:
        points = sweep_steering(actuator.send, lambda: protocol.sensor_counts(clock_ns[0]), wait, values, 1.0)
    finally:
        actuator.close()
        ecus.bus.shutdown()
    calibration, r_squared = fit_steering(points, rad_per_value)
    print(points, calibration, r_squared)
    assert [v for v, _ in points] == [0.0, 0.25, 0.5, 0.75, 1.0, -0.25, -0.5, -0.75, -1.0]
    assert calibration.counts_per_value == pytest.approx(TRUE.counts_per_value, abs=1.0)
    assert calibration.count_offset == pytest.approx(TRUE.count_offset, abs=1.0)
    assert calibration.rad_per_value == pytest.approx(TRUE.rad_per_value, rel=1e-6)
    assert r_squared > 0.999
    assert actuator.quiet_stops == 0  # the sweep kept its command coming
    for steer in (-0.3, 0.0, 0.2):  # the fitted mapping reads the sensor as the true one does
        assert calibration.steer_of_counts(TRUE.counts_of(steer)) == pytest.approx(steer, abs=0.002)


def test_a_sensor_that_does_not_follow_is_refused():
    with pytest.raises(CalibrationError, match="does not follow the command"):
        fit_steering([(0.0, 0.0), (0.5, 300.0), (1.0, 0.0), (-0.5, 290.0), (-1.0, 5.0)], 0.3)


def test_the_cli_writes_the_steering_into_the_rig_file(tmp_path, capsys):
    rig_path = save_rig(Rig({"center": SDC.camera("center")}), tmp_path / "kart.yaml")
    channel = f"steer-cli-{time.monotonic_ns()}"
    servo = _Servo()
    ecus = RdwEcus(open_bus(CanConfig(channel=channel)), time.monotonic_ns, TRUE, lambda: (servo.steer_rad, 0.0))
    stop = threading.Event()

    def kart() -> None:
        last = time.monotonic()
        while not stop.is_set():
            now = time.monotonic()
            servo.follow(ecus.step().steer_rad, now - last, rate_radps=20.0)
            last = now
            time.sleep(0.003)

    threading.Thread(target=kart, daemon=True).start()
    try:
        code = main(["calibrate", "steering", "--rig", str(rig_path), "--bus", "virtual", "--channel", channel,
                     "--rad-per-value", "0.29", "--steps", "5", "--settle", "0.15"])
    finally:
        stop.set()
        time.sleep(0.02)
        ecus.bus.shutdown()
    out = capsys.readouterr().out
    print(out)
    assert code == 0
    steering = load_rig(rig_path).steering
    assert steering is not None and steering.counts_per_value == pytest.approx(-555.0, abs=8.0)
    assert steering.rad_per_value == 0.29 and "written to" in out
    assert main(["calibrate", "steering", "--rig", str(rig_path), "--bus", "virtual", "--channel", channel,
                 "--steps", "5"]) == 1  # no scale given: one line, nothing moved
    assert "--turning-circle" in capsys.readouterr().err

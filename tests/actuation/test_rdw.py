"""The RDW Self Driving Challenge kart's protocol, byte for byte against the organiser's documented examples,
its feedback and watchdogs, and the simulated ECUs' documented rules."""

import itertools

import can
import pytest
from tests.conftest import SteppedClock

from kartpilot.actuation.can_bus import ActuatorLimits, CanActuator, CanConfig, make_protocol, open_bus
from kartpilot.actuation.rdw_protocol import RdwConfig, RdwProtocol, decode_rdw, load_rdw_dbc, rdw_command_frames
from kartpilot.core.errors import ActuationError, ConfigError
from kartpilot.core.types import ActuatorCommand
from kartpilot.core.vehicle import SteeringCalibration, get_vehicle
from kartpilot.sim.can_ecu import RdwEcus

DB = load_rdw_dbc()
SDC = get_vehicle("sdc-kart")
_channels = itertools.count()


def _frame(frame_id: int, hex_bytes: str) -> can.Message:
    return can.Message(arbitration_id=frame_id, data=bytes.fromhex(hex_bytes), is_extended_id=False)


@pytest.mark.parametrize(("value", "expected"), [(0.5, "0000003f"), (1.0, "0000803f"), (-1.25, "0000a0bf")])
def test_the_steering_target_is_a_little_endian_float_with_the_sample_s_speed_or_the_ecu_s_default(value, expected):
    with_speed = rdw_command_frames(DB, value, 0.0, 0.0, "forward", 0xC300)
    assert [f.arbitration_id for f in with_speed] == [0x110, 0x220, 0x330]
    assert with_speed[1].data.hex() == expected + "0000c300" and with_speed[1].dlc == 8
    default_speed = rdw_command_frames(DB, value, 0.0, 0.0, "forward", 0)[1]
    assert default_speed.data.hex() == expected and default_speed.dlc == 4
    assert decode_rdw(DB, default_speed) == ("SteeringCommand", {"SteeringTarget": value, "SteeringSpeed": 0})


def test_brake_and_motor_frames_carry_whole_percent_and_the_gear():
    brake, _, motor = rdw_command_frames(DB, 0.0, 0.374, 0.5, "forward", 0)
    assert brake.data.hex() == "3200000000000000"  # 50 %, bytes 1 to 7 zero
    assert motor.data.hex() == "2500010000000000"  # 37 %, 0, gear 1 (forward)
    assert rdw_command_frames(DB, 0.0, 1.0, 0.0, "neutral", 0)[2].data.hex()[:6] == "640000"
    assert rdw_command_frames(DB, 0.0, 0.0, 0.0, "reverse", 0)[2].data[2] == 2
    with pytest.raises(ActuationError, match="gear"):  # nothing can encode gear 3 or more
        rdw_command_frames(DB, 0.0, 0.0, 0.0, "3", 0)
    assert rdw_command_frames(DB, 7.0, 0.0, 0.0, "forward", 0)[1].data.hex() == "0000a03f"  # clamped to 1.25


def test_the_kart_s_frames_decode_as_documented():
    assert decode_rdw(DB, _frame(0x440, "014a000000000000")) == ("Speed", {"Speed": pytest.approx(33.0)})
    assert decode_rdw(DB, _frame(0x1E5, "00fffc0000000000")) == ("SteeringSensor", {"SteeringCounts": -4})
    name, steering = decode_rdw(DB, _frame(0x720, "fed400c801030000"))
    assert name == "SteeringFeedback"
    assert steering == {"SteeringAngle": -300, "SteeringTargetCounts": 200, "SteeringDirection": 1,
                        "SteeringError": 3}
    name, motor = decode_rdw(DB, _frame(0x730, "8001010100000000"))
    assert (name, motor) == ("MotorFeedback", {"ThrottleDac": 128, "Braking": 1, "Gear": 1, "Idle": 1})
    name, brake = decode_rdw(DB, _frame(0x710, "01f4032001320100"))
    assert name == "BrakeFeedback"
    assert brake == {"BrakePosition": 500, "BrakeTarget": 800, "BrakeDirection": 1, "BrakeSpeed": 50, "BrakeError": 1}
    assert decode_rdw(DB, _frame(0x123, "00")) is None
    with pytest.raises(ActuationError, match=r"Speed \(0x440\): 1 bytes hold none"):
        decode_rdw(DB, _frame(0x440, "01"))


def test_a_short_feedback_frame_gives_the_signals_whose_bytes_it_holds():
    """The teams' decoders read 0x440's speed from its first two bytes whatever its length; a team's kart
    simulator sends 2-byte frames. Such a frame is the speed; a frame too short for any signal is an error."""
    assert decode_rdw(DB, _frame(0x440, "014a")) == ("Speed", {"Speed": pytest.approx(33.0)})
    _, brake = decode_rdw(DB, _frame(0x710, "01f40320"))  # position and target, not the rest
    assert brake == {"BrakePosition": 500, "BrakeTarget": 800}
    protocol = RdwProtocol(SteeringCalibration())
    protocol.receive(1, _frame(0x440, "014a"))
    assert protocol.feedback(2).speed_mps == pytest.approx(33.0 / 3.6)
    with pytest.raises(ActuationError):  # holds no whole signal: the bus counts it as a receive error
        protocol.receive(3, _frame(0x710, "01"))


def test_steer_rad_positive_left_becomes_the_ecu_s_value_positive_right_through_the_calibration():
    protocol = RdwProtocol(SDC.steering)
    steering = protocol.command_frames(ActuatorCommand(0, 0.16, 0.0, 1.0), "autonomous")[1]
    assert steering.data.hex() == "000000bf0000c300"  # 0.16 rad left: -0.5
    calibration = SteeringCalibration(value_sign=-1, rad_per_value=0.3, value_offset=0.05)
    assert calibration.value_of(0.0) == pytest.approx(0.05)
    assert calibration.steer_of_value(calibration.value_of(0.2)) == pytest.approx(0.2)
    assert calibration.steer_of_counts(calibration.counts_of(-0.1)) == pytest.approx(-0.1)
    with pytest.raises(ConfigError, match=r"steering\.rad_per_value"):
        SteeringCalibration(rad_per_value=float("nan"))


def test_reverse_goes_out_only_once_the_kart_is_known_to_stand_still():
    protocol = RdwProtocol(SDC.steering, RdwConfig(gear="reverse"))
    assert protocol.gear() == "neutral"  # no speed heard yet
    protocol.receive(0, _frame(0x440, "0050000000000000"))  # 8 km/h
    assert protocol.gear() == "neutral"
    protocol.receive(1, _frame(0x440, "0000000000000000"))
    assert protocol.gear() == "reverse"


def test_each_fault_the_kart_can_show_is_named():
    protocol = RdwProtocol(SDC.steering, RdwConfig(expect=("speed", "steering_sensor")))
    protocol.receive(0, _frame(0x440, "0064000000000000"))
    protocol.receive(0, _frame(0x1E5, "0001000000000000"))
    assert protocol.faults(100_000_000, "autonomous") == []
    assert protocol.feedback(100_000_000).speed_mps == pytest.approx(10.0 / 3.6)
    assert protocol.faults(250_000_000, "autonomous") == ["no steering sensor (0x1e5) for 0.25 s"]
    assert protocol.feedback(250_000_000).steer_rad is None  # stale: not used
    protocol.receive(300_000_000, _frame(0x1E5, "0003840000000000"))  # 900 counts
    assert protocol.faults(300_000_000, "autonomous") == ["steering sensor out of range (900 counts, valid -800 to "
                                                          "800)"]
    protocol.receive(300_000_000, _frame(0x1E5, "0000000000000000"))
    protocol.receive(300_000_000, _frame(0x720, "0000000000020000"))
    protocol.receive(300_000_000, _frame(0x730, "0000000100000000"))
    assert protocol.faults(300_000_000, "disarmed") == ["the steering ECU reports error 2"]
    assert protocol.faults(300_000_000, "autonomous") == ["the steering ECU reports error 2",
                                                          "the motor ECU is idle (it saw no motor command for 200 ms)"]


def test_the_vehicle_says_which_protocol_its_actuators_speak():
    assert make_protocol(CanConfig(), SDC).name == "rdw"
    assert make_protocol(CanConfig(), get_vehicle("rc-kart")).name == "kartpilot"
    assert make_protocol(CanConfig(protocol="kartpilot"), SDC).name == "kartpilot"


class _Kart:
    """The simulated kart's ECUs on one side of a virtual bus, the actuator on the other, a shared clock."""

    def __init__(self, steering: SteeringCalibration | None = None) -> None:
        self.config = CanConfig(channel=f"rdw-{next(_channels)}")
        self.clock = SteppedClock()
        self.steer_rad, self.speed_mps = 0.0, 0.0
        self.ecus = RdwEcus(open_bus(self.config), self.clock, steering or SDC.steering,
                            lambda: (self.steer_rad, self.speed_mps))
        self.actuator = CanActuator(open_bus(self.config), make_protocol(self.config, SDC), self.config,
                                    ActuatorLimits().for_vehicle(SDC), self.clock)
        self.executed: list[ActuatorCommand] = []
        self.command: ActuatorCommand | None = None  # what the loop sends, at 30 Hz
        self._loop_ns = 0

    def drive(self, command: ActuatorCommand) -> None:
        self.command = command
        self._loop_ns = self.clock.ns
        self.actuator.send(command)

    def run(self, seconds: float, loop: bool = True, tick: bool = True, step_s: float = 0.005) -> None:
        """Advance the clock; the loop sends its command every 1/30 s (``loop``), the sender ticks (``tick``)."""
        for _ in range(round(seconds / step_s)):
            self.clock.advance(step_s)
            if loop and self.command is not None and self.clock.ns - self._loop_ns >= 1e9 / 30:
                self._loop_ns = self.clock.ns
                self.actuator.send(self.command)
            if tick:
                self.actuator.tick()
            self.executed.append(self.ecus.step())

    def close(self) -> None:
        self.actuator.bus.shutdown()
        self.ecus.bus.shutdown()


def test_the_simulated_ecus_follow_the_commands_and_report_at_their_rates():
    kart = _Kart()
    kart.actuator.state = "autonomous"
    kart.speed_mps = 3.0
    kart.drive(ActuatorCommand(0, 0.1, 0.4, 0.0))
    kart.run(1.0)
    assert kart.executed[-1].steer_rad == pytest.approx(0.1, abs=1e-6)
    assert kart.executed[-1].throttle == pytest.approx(0.4)
    assert kart.ecus.applied[-1].source == "command"
    assert kart.actuator.faults() == []
    assert kart.actuator.feedback().speed_mps == pytest.approx(3.0, abs=0.05 / 3.6)
    assert kart.actuator.frames_sent == 3 * (1 + 25)  # the first at once, then every 40 ms
    assert len(kart.ecus.speed_reports) == 50
    assert all(abs(kmh - true * 3.6) <= 0.05 + 1e-9 for _, true, kmh in kart.ecus.speed_reports)
    kart.close()


def test_the_brake_travels_and_a_motor_frame_with_gear_3_is_ignored():
    kart = _Kart()
    kart.drive(ActuatorCommand(0, 0.0, 0.0, 1.0))
    kart.run(0.2)
    assert kart.ecus.applied[-1].command.brake == 1.0  # the target at once
    assert 0.3 < kart.executed[-1].brake < 0.7  # the position on its way (0.4 s for the full travel)
    kart.run(0.3)
    assert kart.executed[-1].brake == 1.0
    rejected = kart.ecus.rejected_frames
    kart.ecus.bus.recv(timeout=0.0)
    kart.actuator.bus.send(_frame(0x330, "3200030000000000"))  # throttle 50 %, gear 3
    kart.run(0.01, loop=False, tick=False)
    assert kart.ecus.rejected_frames == rejected + 1 and kart.executed[-1].throttle == 0.0
    kart.close()


def test_a_silent_loop_is_stopped_by_us_first_and_by_the_motor_ecu_s_idle_last():
    kart = _Kart()
    kart.actuator.state = "autonomous"
    kart.drive(ActuatorCommand(0, 0.0, 0.5, 0.0))
    kart.run(0.5)
    assert kart.executed[-1].throttle == 0.5
    quiet_from = kart._loop_ns  # the loop hangs after its last command; the sender thread goes on
    kart.run(0.3, loop=False)
    first_stop = next(a for a in kart.ecus.applied if a.stamp_ns > quiet_from and a.command.brake == 1.0)
    assert first_stop.source == "command"  # our own stop, before the ECU's idle
    assert (first_stop.stamp_ns - quiet_from) * 1e-9 <= kart.config.command_timeout_s + 0.04 + 0.005
    assert kart.actuator.quiet_stops == 1
    dead_from = kart.clock.ns  # now the whole process dies: nothing is sent any more
    kart.run(0.4, loop=False, tick=False)
    idle = next(a for a in kart.ecus.applied if a.stamp_ns > dead_from and a.source == "motor-idle")
    assert 0.16 <= (idle.stamp_ns - dead_from) * 1e-9 <= 0.2 + 0.005 and kart.executed[-1].throttle == 0.0
    kart.close()


def test_the_steering_ecu_goes_to_its_failsafe_and_each_sensor_fault_reaches_the_watchdogs():
    for kind, expected in (("steering-sensor-loss", "no steering sensor (0x1e5)"),
                           ("steering-sensor-range", "steering sensor out of range")):
        kart = _Kart()
        kart.actuator.state = "autonomous"
        kart.drive(ActuatorCommand(0, 0.0, 0.2, 0.0))
        kart.run(0.5)
        kart.ecus.inject(kind)
        start = kart.clock.ns
        seen = None
        while seen is None and kart.clock.ns - start < 1e9:
            kart.run(0.005)
            if any(f.startswith(expected) for f in kart.actuator.faults()):
                seen = kart.clock.ns
        assert seen is not None and (seen - start) * 1e-9 <= 0.2 + 0.005 + 1e-9, kind
        kart.drive(ActuatorCommand(kart.clock.ns, 0.3, 0.2, 0.0))  # the ECU no longer follows
        kart.run(0.3)
        assert kart.ecus.applied[-1].source == "steering-failsafe" and kart.executed[-1].steer_rad == 0.0
        assert any(f.startswith("the steering ECU reports error") for f in kart.actuator.faults()), kind
        kart.close()

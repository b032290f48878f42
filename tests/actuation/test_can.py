"""The CAN layer on python-can's virtual bus: the DBC, limits, spacing, status and faults."""

import itertools
import time

import can
import pytest

from kartpilot.actuation.can_bus import (
    ActuatorLimits,
    CanActuator,
    CanConfig,
    command_frames,
    decode,
    limit_command,
    load_dbc,
    open_bus,
)
from kartpilot.core.errors import ActuationError, ConfigError
from kartpilot.core.types import ActuatorCommand
from kartpilot.sim.can_ecu import SimEcus

_channels = itertools.count()


def _pair():
    channel = f"test-{next(_channels)}"
    config = CanConfig(channel=channel)
    return open_bus(config), open_bus(config), config


class Clock:
    def __init__(self) -> None:
        self.ns = 0

    def __call__(self) -> int:
        return self.ns

    def advance(self, seconds: float) -> None:
        self.ns += round(seconds * 1e9)


class Vehicle:
    def __init__(self) -> None:
        self.commands: list[ActuatorCommand] = []

    def send(self, command: ActuatorCommand) -> None:
        self.commands.append(command)


def test_frames_round_trip_through_the_dbc_and_a_corrupted_byte_is_refused():
    db = load_dbc()
    frames = command_frames(db, ActuatorCommand(0, -0.2345, 0.5, 0.0), "autonomous", 7)
    assert [f.arbitration_id for f in frames] == [0x100, 0x101, 0x102, 0x110]
    name, values = decode(db, frames[0])
    assert name == "SteerCommand" and values["SteerAngle"] == pytest.approx(-0.2345, abs=1e-4)
    assert values["Counter"] == 7 and values["Enable"] == 1
    assert decode(db, frames[3])[1]["State"] == 2
    corrupted = bytearray(frames[1].data)
    corrupted[0] ^= 0x10
    with pytest.raises(ActuationError, match="ThrottleCommand: wrong checksum"):
        decode(db, can.Message(arbitration_id=0x101, data=bytes(corrupted), is_extended_id=False))
    with pytest.raises(ActuationError, match="unknown CAN frame 0x7ff"):
        decode(db, can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False))


def test_a_dbc_without_the_kart_s_messages_is_named(tmp_path):
    dbc = tmp_path / "other.dbc"
    dbc.write_text('VERSION ""\n\nBU_: A\n\nBO_ 256 SteerCommand: 8 A\n SG_ SteerAngle : 0|16@1- (0.0001,0) '
                   '[-1|1] "rad" A\n')
    with pytest.raises(ConfigError, match="message SteerCommand needs Counter and Checksum"):
        load_dbc(dbc)
    with pytest.raises(ConfigError, match="DBC file not found"):
        load_dbc(tmp_path / "missing.dbc")


def test_commands_are_clamped_rate_limited_and_braking_drops_the_throttle():
    limits = ActuatorLimits(max_steer_rad=0.4, max_steer_rate_radps=2.0, max_throttle=0.8,
                            max_throttle_rise_per_s=1.0)
    first = limit_command(None, ActuatorCommand(0, 1.0, 1.0, 0.0), limits, 0.0)
    assert (first.steer_rad, first.throttle) == (0.4, 0.8)
    previous = ActuatorCommand(0, 0.0, 0.1, 0.0)
    step = limit_command(previous, ActuatorCommand(1, -0.4, 0.8, 0.0), limits, 0.05)
    assert step.steer_rad == pytest.approx(-0.1) and step.throttle == pytest.approx(0.15)
    stop = limit_command(ActuatorCommand(0, 0.3, 0.8, 0.0), ActuatorCommand(1, 0.3, 0.8, 1.0), limits, 0.05)
    assert (stop.throttle, stop.brake) == (0.0, 1.0)  # a stop is never rate limited
    assert limit_command(previous, ActuatorCommand(1, float("nan"), 0.5, 0.0), limits, 0.05).brake == 1.0


def test_the_simulated_ecus_apply_what_the_actuator_sends_and_report_back():
    kart_bus, ecu_bus, config = _pair()
    clock = Clock()
    actuator = CanActuator(kart_bus, config, clock=clock)
    vehicle = Vehicle()
    ecus = SimEcus(ecu_bus, vehicle, clock, measured=lambda: (0.05, 1.5))
    actuator.state = "autonomous"
    for k in range(5):
        clock.advance(0.02)
        actuator.send(ActuatorCommand(clock.ns, 0.01 * k, 0.3, 0.0))
        ecus.step()
        actuator.poll()
    assert vehicle.commands[-1].steer_rad == pytest.approx(0.04, abs=1e-4)
    assert vehicle.commands[-1].throttle == pytest.approx(0.3, abs=1e-4)
    assert actuator.faults() == []
    assert actuator.ecu_values("drive")["Speed"] == pytest.approx(1.5)
    kart_bus.shutdown()
    ecu_bus.shutdown()


def test_sends_closer_than_the_minimum_spacing_are_held_back_but_a_stop_never_is():
    kart_bus, ecu_bus, config = _pair()
    clock = Clock()
    actuator = CanActuator(kart_bus, CanConfig(channel=config.channel, min_spacing_ms=5.0), clock=clock)
    actuator.send(ActuatorCommand(0, 0.0, 0.2, 0.0))
    clock.advance(0.001)
    actuator.send(ActuatorCommand(0, 0.0, 0.2, 0.0))
    assert actuator.skipped_sends == 1 and actuator.frames_sent == 4
    clock.advance(0.001)
    actuator.send(ActuatorCommand.stop(0))
    assert actuator.frames_sent == 8
    frames = []
    while (frame := ecu_bus.recv(timeout=0.0)) is not None:
        frames.append(frame)
    assert decode(load_dbc(), frames[-2])[1]["Brake"] == 1.0
    kart_bus.shutdown()
    ecu_bus.shutdown()


def test_missing_ecu_status_an_ecu_fault_and_a_bus_off_are_reported():
    kart_bus, ecu_bus, config = _pair()
    clock = Clock()
    actuator = CanActuator(kart_bus, config, clock=clock)
    ecus = SimEcus(ecu_bus, Vehicle(), clock)
    actuator.send(ActuatorCommand(0, 0.0, 0.2, 0.0))
    ecus.step()
    actuator.poll()
    assert actuator.faults() == []
    ecus.silent = True
    clock.advance(0.15)
    assert actuator.faults() == [f"no status from the {e} ECU for 0.15 s" for e in ("steer", "drive", "brake")]
    ecus.silent = False
    clock.advance(0.15)  # no heartbeat for 0.3 s: the ECUs brake on their own and say so
    assert ecus.step().brake == 1.0 and ecus.applied[-1].source == "ecu-timeout"
    actuator.poll()
    assert "the steer ECU reports command_timeout" in actuator.faults()

    class BusOff(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="off")

        def send(self, msg, timeout=None):
            raise can.CanOperationError("bus-off")

        def _recv_internal(self, timeout):
            return None, False

    broken = CanActuator(BusOff(), config, clock=clock)
    broken.send(ActuatorCommand(0, 0.0, 0.2, 0.0))
    assert broken.tx_errors == 1 and "CAN transmit failed (bus-off)" in broken.faults()
    kart_bus.shutdown()
    ecu_bus.shutdown()


def test_the_live_sender_repeats_the_command_and_stops_by_itself_when_the_loop_goes_quiet():
    kart_bus, ecu_bus, config = _pair()
    actuator = CanActuator(kart_bus, CanConfig(channel=config.channel, send_rate_hz=100.0, command_timeout_s=0.1))
    actuator.start()
    actuator.send(ActuatorCommand(0, 0.1, 0.4, 0.0))
    time.sleep(0.3)  # the loop has hung
    actuator.close()
    db = load_dbc()
    brakes = []
    while (frame := ecu_bus.recv(timeout=0.0)) is not None:
        name, values = decode(db, frame)
        if name == "BrakeCommand":
            brakes.append(values["Brake"])
    assert len(brakes) >= 10  # repeated at the fixed rate, not only when the loop sent
    assert brakes[0] == 0.0 and brakes[-1] == 1.0
    ecu_bus.shutdown()


def test_an_interface_that_does_not_exist_is_named():
    with pytest.raises(ActuationError, match="cannot open CAN interface socketcan channel nocan0"):
        open_bus(CanConfig(interface="socketcan", channel="nocan0"))

"""The CAN layer on python-can's virtual bus with our own protocol (the rc-kart's): the DBC, limits, the
periodic schedule, status and faults. The RDW kart's protocol is tested in test_rdw.py."""

import itertools
import time

import can
import pytest
from tests.conftest import SteppedClock

from kartpilot.actuation.can_bus import ActuatorLimits, CanActuator, CanConfig, limit_command, open_bus
from kartpilot.actuation.kartpilot_protocol import KartpilotProtocol, command_frames, decode, load_dbc
from kartpilot.core.errors import ActuationError, ConfigError
from kartpilot.core.types import ActuatorCommand
from kartpilot.core.vehicle import get_vehicle
from kartpilot.sim.can_ecu import KartpilotEcus

_channels = itertools.count()


def _pair():
    channel = f"test-{next(_channels)}"
    config = CanConfig(channel=channel)
    return open_bus(config), open_bus(config), config


def _actuator(bus, config, clock, **kwargs):
    return CanActuator(bus, KartpilotProtocol(config.dbc, config.ecus, config.status_timeout_s, clock()), config,
                       ActuatorLimits().for_vehicle(get_vehicle("rc-kart")), clock=clock, **kwargs)


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


def test_a_dbc_given_for_the_rdw_kart_is_refused_not_ignored(tmp_path):
    from kartpilot.actuation.can_bus import CanConfig, make_protocol, protocol_database

    sdc = get_vehicle("sdc-kart")
    config = CanConfig(dbc=str(tmp_path / "team.dbc"))
    with pytest.raises(ConfigError, match="speaks rdw"):
        make_protocol(config, sdc)
    with pytest.raises(ConfigError, match=r"can\.protocol: kartpilot"):
        protocol_database(config, sdc)
    assert make_protocol(CanConfig(), sdc).name == "rdw"


def test_the_limits_narrow_the_kart_s_own_range_and_are_checked():
    sdc = get_vehicle("sdc-kart")
    assert ActuatorLimits().for_vehicle(sdc).max_steer_rad == sdc.max_steer_rad
    assert ActuatorLimits(max_steer_rad=0.3).for_vehicle(sdc).max_steer_rad == 0.3
    assert ActuatorLimits(max_steer_rad=0.9).for_vehicle(sdc).max_steer_rad == sdc.max_steer_rad
    with pytest.raises(ConfigError, match=r"limits\.max_throttle"):
        ActuatorLimits(max_throttle=float("nan"))


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
    clock = SteppedClock()
    actuator = _actuator(kart_bus, config, clock)
    ecus = KartpilotEcus(ecu_bus, clock, measured=lambda: (0.05, 1.5))
    actuator.state = "autonomous"
    for k in range(5):
        clock.advance(0.04)
        actuator.send(ActuatorCommand(clock.ns, 0.01 * k, 0.3, 0.0))
        actuator.tick()
        applied = ecus.step()
        actuator.poll()
    assert applied.steer_rad == pytest.approx(0.04, abs=1e-4)
    assert applied.throttle == pytest.approx(0.3, abs=1e-4)
    assert actuator.faults() == []
    assert actuator.protocol.ecu_values("drive")["Speed"] == pytest.approx(1.5)
    assert actuator.feedback().speed_mps == pytest.approx(1.5)
    kart_bus.shutdown()
    ecu_bus.shutdown()


def test_commands_go_out_on_a_fixed_schedule_but_a_stop_goes_out_at_once():
    kart_bus, ecu_bus, config = _pair()
    clock = SteppedClock()
    actuator = _actuator(kart_bus, CanConfig(channel=config.channel, send_rate_hz=25.0), clock)
    actuator.send(ActuatorCommand(0, 0.0, 0.2, 0.0))  # the first command starts the schedule
    assert actuator.frames_sent == 4
    for _ in range(20):  # the loop sends every 10 ms, the bus hears every 40 ms
        clock.advance(0.01)
        actuator.send(ActuatorCommand(clock.ns, 0.0, 0.2, 0.0))
        actuator.tick()
    assert actuator.frames_sent == 4 * 6
    clock.advance(0.001)
    actuator.send(ActuatorCommand.stop(clock.ns))
    assert actuator.frames_sent == 4 * 7
    frames = []
    while (frame := ecu_bus.recv(timeout=0.0)) is not None:
        frames.append(frame)
    assert decode(load_dbc(), frames[-2])[1]["Brake"] == 1.0
    kart_bus.shutdown()
    ecu_bus.shutdown()


def test_missing_ecu_status_an_ecu_fault_and_a_bus_off_are_reported():
    kart_bus, ecu_bus, config = _pair()
    clock = SteppedClock()
    actuator = _actuator(kart_bus, config, clock)
    ecus = KartpilotEcus(ecu_bus, clock)
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
    ecus.inject("ecu-error")  # the heartbeat is back, but an ECU's actuator has failed
    clock.advance(0.05)
    actuator.tick()
    ecus.step()
    actuator.poll()
    assert "the steer ECU reports actuator" in actuator.faults()

    class BusOff(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="off")

        def send(self, msg, timeout=None):
            raise can.CanOperationError("bus-off")

        def _recv_internal(self, timeout):
            return None, False

    broken = _actuator(BusOff(), config, clock)
    broken.send(ActuatorCommand(0, 0.0, 0.2, 0.0))
    assert broken.tx_errors == 1 and "CAN transmit failed (bus-off)" in broken.faults()
    kart_bus.shutdown()
    ecu_bus.shutdown()


def test_the_live_sender_repeats_the_command_and_stops_by_itself_when_the_loop_goes_quiet():
    kart_bus, ecu_bus, config = _pair()
    actuator = _actuator(kart_bus, CanConfig(channel=config.channel, send_rate_hz=100.0, command_timeout_s=0.1),
                         time.monotonic_ns)
    actuator.start()
    actuator.send(ActuatorCommand(0, 0.1, 0.4, 0.0))  # then the loop hangs
    db = load_dbc()
    brakes: list[float] = []
    deadline = time.monotonic() + 10.0  # a bound for a broken sender, not a measure of speed
    while brakes.count(1.0) < 3 and time.monotonic() < deadline:  # on what the bus carries, not on the clock
        frame = ecu_bus.recv(timeout=0.1)
        if frame is not None and (decoded := decode(db, frame))[0] == "BrakeCommand":
            brakes.append(decoded[1]["Brake"])
    actuator.close()
    assert brakes[0] == 0.0  # the loop's command first
    assert brakes.count(1.0) >= 3 and brakes[brakes.index(1.0):] == [1.0] * brakes.count(1.0)  # then the stop,
    # repeated at the fixed rate without the loop sending anything, and nothing else after it
    ecu_bus.shutdown()


def test_an_interface_that_does_not_exist_is_named():
    with pytest.raises(ActuationError, match="cannot open CAN interface socketcan channel nocan0"):
        open_bus(CanConfig(interface="socketcan", channel="nocan0"))

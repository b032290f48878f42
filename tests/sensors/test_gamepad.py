"""The gamepad through the Linux joystick interface, fed by a FIFO standing in for /dev/input/js0."""

import os
import struct
import threading
import time

import pytest

from kartpilot.sensors.gamepad import Gamepad, GamepadMapping, operator_input

EVENT = struct.Struct("<IhBB")


def test_triggers_stick_and_buttons_map_to_the_operator_s_input():
    mapping = GamepadMapping(max_steer_rad=0.4, deadzone=0.0)
    pad = operator_input({0: -32767, 5: 32767, 2: -32767}, {5: 1}, {3}, mapping, True, 7)
    assert pad.manual.steer_rad == pytest.approx(0.4)  # stick left: steer left (positive)
    assert pad.manual.throttle == pytest.approx(1.0) and pad.manual.brake == 0.0
    assert pad.hold and pad.request == "autonomous" and not pad.estop
    braking = operator_input({5: 32767, 2: 0}, {1: 1}, set(), mapping, True, 7)
    assert braking.manual.brake == pytest.approx(0.5) and braking.manual.throttle == 0.0 and braking.estop
    resting = operator_input({}, {}, set(), GamepadMapping(), True, 7)
    assert resting.manual.throttle == 0.0 and resting.manual.brake == 0.0 and not resting.hold


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs POSIX FIFOs")
def test_events_are_read_and_unplugging_the_pad_drops_the_link_and_every_button(tmp_path):
    device = tmp_path / "js0"
    os.mkfifo(device)
    pad = Gamepad(device, reopen_s=0.05).start()
    writer_ready = threading.Event()
    holder = {}

    def open_writer():
        holder["fd"] = os.open(device, os.O_WRONLY)
        writer_ready.set()

    threading.Thread(target=open_writer, daemon=True).start()
    assert writer_ready.wait(2.0)
    fd = holder["fd"]
    os.write(fd, EVENT.pack(0, 1, 0x81, 5))  # initial state: RB held
    os.write(fd, EVENT.pack(10, 1, 0x01, 3))  # Y pressed: autonomy requested
    os.write(fd, EVENT.pack(20, 32767, 0x02, 5))  # right trigger fully pressed
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and pad(0).manual.throttle < 1.0:
        time.sleep(0.01)
    state = pad(1)
    assert state.connected and state.hold and state.manual.throttle == pytest.approx(1.0)
    assert pad(2).request == ""  # a request is an edge: once per press
    os.close(fd)  # unplugged
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and pad(3).connected:
        time.sleep(0.01)
    after = pad(4)
    assert not after.connected and not after.hold and after.manual.throttle == 0.0
    pad.close()

"""The CAN monitor: rates, gaps, decoded values and faults per message, and live on a bus."""

import threading
import time

import can
import pytest

from kartpilot.actuation.can_bus import CanConfig, open_bus
from kartpilot.actuation.monitor import format_traffic, summarise_traffic
from kartpilot.cli.main import main


def test_each_message_gets_its_rate_gap_values_and_faults():
    frames = [(k * 10_000_000, "rx", 0x1E5, bytes.fromhex("0000100000000000")) for k in range(11)]
    frames += [(120_000_000, "rx", 0x1E5, bytes.fromhex("0003840000000000")),  # 900 counts, 20 ms late
               (0, "tx", 0x330, bytes.fromhex("1400030000000000")),  # gear 3
               (0, "rx", 0x730, bytes.fromhex("0000010100000000")),  # idle
               (0, "rx", 0x440, bytes.fromhex("01")),  # short
               (0, "rx", 0x7FF, bytes(8))]
    rows = {(r.frame_id, r.direction): r for r in summarise_traffic(sorted(frames), "rdw")}
    sensor = rows[0x1E5, "rx"]
    assert sensor.count == 12 and sensor.max_gap_ns == 20_000_000
    assert sensor.rate_hz == pytest.approx(11 / 0.12)
    assert sensor.values == {"SteeringCounts": 900} and sensor.faults == ["out of range (900 counts)"]
    assert rows[0x330, "tx"].faults == ["gear 3: the motor ECU ignores this frame"]
    assert rows[0x730, "rx"].faults == ["motor ECU idle"]
    assert "1 bytes" in rows[0x440, "rx"].faults[0]
    assert rows[0x7FF, "rx"].faults == ["not in the protocol"]
    text = format_traffic(list(rows.values()))
    assert "0x1e5 rx SteeringSensor" in text and "!! out of range" in text


def test_the_monitor_listens_live_for_its_duration(capsys):
    channel = f"monitor-{time.monotonic_ns()}"
    kart = open_bus(CanConfig(channel=channel))
    stop = threading.Event()

    def speed_sensor() -> None:
        while not stop.is_set():
            kart.send(can.Message(arbitration_id=0x440, data=bytes.fromhex("014a000000000000"), is_extended_id=False))
            time.sleep(0.02)

    threading.Thread(target=speed_sensor, daemon=True).start()
    try:
        assert main(["can", "monitor", "--bus", "virtual", "--channel", channel, "--duration", "0.6"]) == 0
    finally:
        stop.set()
        time.sleep(0.05)
        kart.shutdown()
    out = capsys.readouterr().out
    print(out)
    assert "0x440 rx Speed" in out and "Speed=33" in out
    assert main(["can", "monitor", "--bus", "virtual", "--channel", channel, "--duration", "nan"]) == 2
    assert main(["can", "monitor", "--bus", "virtual", "--channel", channel, "--every", "-1"]) == 2
    assert main(["can", "monitor", "--bus", "virtual", "--channel", channel, "--duration", "0.1", "--json",
                 "/nonexistent/traffic.json"]) == 2
    assert "the folder /nonexistent does not exist" in capsys.readouterr().err

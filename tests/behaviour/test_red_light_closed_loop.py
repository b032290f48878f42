"""Closed loop on the venue track: the kart sees a red light and the stop line with its own camera, stops with its
front 0.2 to 1.5 m before the line, waits, and goes on when the light turns green."""

from dataclasses import replace

import numpy as np
import pytest

from kartpilot.runtime.lane_policy import LANE_PRESETS, LanePolicy
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import Prop, project_onto


@pytest.mark.slow
def test_the_kart_stops_before_the_line_at_red_and_goes_on_green():
    policy_config = replace(LANE_PRESETS["kart"], speed_mps=15 / 3.6, events=True)
    light = Prop(kind="traffic_light", s_m=36.0, offset_m=-2.5, phases=(("red", 14.0), ("green", 1e6)))
    config = SimConfig(track="lelystad", vehicle="sdc-kart", seed=3, camera_rate_hz=10.0,
                       speed_mode_mps=15 / 3.6, props=(light,), max_time_s=18.0)
    with Simulator(config) as sim:
        policy = LanePolicy(sim.cameras, policy_config, config.camera_rate_hz)
        front = sim.vehicle.wheelbase_m + sim.vehicle.front_overhang_m
        line = sim.track.spec.road_marks[0].s_m  # the stop line's near edge, 30 m along
        fronts, states = [], []
        while (frames := sim.read()) is not None:
            policy.measured_speed_mps = sim.state.vx_mps  # the kart's 0x440 report
            sim.send(policy(frames))
            fronts.append(project_onto(sim.track.route, np.array([sim.state.x_m, sim.state.y_m])).s_m + front)
            states.append(policy.last_behaviour.state)
        times = np.arange(len(fronts)) / config.camera_rate_hz
        waiting = np.asarray(fronts)[(times > 11) & (times < 14)]
        gap = line - waiting.max()
        print(f"\nstopped with the front {gap:.2f} m before the line; {fronts[-1] - line:.1f} m past it at the end")
        assert 0.2 <= gap <= 1.5 and np.ptp(waiting) < 0.02
        assert fronts[-1] > line + 3.0  # gone on green
        assert "wait_red" in states and states[-1] == "drive"
        assert not sim.referee.disqualified, sim.referee.reason


@pytest.mark.slow
def test_a_camera_freezing_mid_scenario_ends_in_a_safe_stop_with_its_reason(tmp_path):
    """The red-light scenario driven through the supervisor on the RDW kart's CAN protocol (its ECUs
    simulated): the centre camera freezes 3 s in, while the rules are stopping for the light. The supervisor
    stops the kart whatever the rules want, says why, and the recording keeps the rules' decisions up to then."""
    from kartpilot.record.recording import RecordingReader
    from kartpilot.runtime.config import StackConfig
    from kartpilot.runtime.faults import parse_injection
    from kartpilot.runtime.session import SessionOutputs
    from kartpilot.runtime.simulate import run_supervised_drive

    light = Prop(kind="traffic_light", s_m=36.0, offset_m=-2.5, phases=(("red", 30.0), ("green", 1e6)))
    config = SimConfig(track="lelystad", vehicle="sdc-kart", seed=4, cameras=("center",), camera_rate_hz=15.0,
                       speed_mode_mps=15 / 3.6, props=(light,))
    stack = StackConfig(lane_policy=replace(LANE_PRESETS["kart"], speed_mps=15 / 3.6, events=True))
    run = run_supervised_drive(config, "lanes", stack, bus="virtual", duration_s=5.0,
                               injections=[parse_injection("camera-freeze@3.0")],
                               outputs=SessionOutputs(record_dir=tmp_path / "rec"))
    payload = run.payload
    print(payload["transitions"][-1], payload["fault_to_stop_s"])
    assert payload["final_state"] == "fault" and "frozen frame" in payload["transitions"][-1]["reason"]
    assert payload["fault_to_stop_s"] is not None and payload["fault_to_stop_s"] <= 0.2
    states = [row["state"] for row in RecordingReader(tmp_path / "rec").outputs("behaviour")]
    assert states and states[-1] in ("drive", "stop_red")  # the rules ran until the fault


@pytest.mark.slow
def test_a_recorded_scenario_replays_to_the_same_decisions(tmp_path, capsys):
    """``kartpilot sim --scenario ... --record`` keeps what the pipeline was told the kart measured (the ``kart``
    topic) and its settings; ``kartpilot replay`` on it makes the same decisions, step by step."""
    import csv

    from kartpilot.cli.main import main
    from kartpilot.runtime.scenarios import run_scenario
    from kartpilot.runtime.session import SessionOutputs

    run_scenario("red-light", 2, max_time_s=6.0, outputs=SessionOutputs(record_dir=tmp_path / "drive"))
    assert main(["replay", str(tmp_path / "drive"), "--pipeline", "lanes", "--out", str(tmp_path / "again")]) == 0
    assert "settings: the recording's own" in capsys.readouterr().out

    def rows(folder, name):
        with (folder / "outputs" / f"{name}.csv").open(newline="") as f:
            # the stop point to the millimetre: the recorded speed is text of limited precision
            return [(r["stamp_ns"], r["state"], r["reason"], None if r["stop_distance_m"] == "nan"
                     else round(float(r["stop_distance_m"]), 3)) for r in csv.DictReader(f)]

    drive, again = rows(tmp_path / "drive", "behaviour"), rows(tmp_path / "again", "behaviour")
    assert len(drive) == len(again) >= 80 and drive == again
    assert len({state for _, state, _, _ in drive}) >= 2  # the rules did decide something on the way
    with (tmp_path / "drive" / "commands.csv").open() as a, (tmp_path / "again" / "commands.csv").open() as b:
        commands = [(list(csv.DictReader(a))), list(csv.DictReader(b))]
    assert len(commands[0]) == len(commands[1]) == len(drive)
    for x, y in zip(*commands, strict=True):
        assert all(abs(float(x[k]) - float(y[k])) < 1e-4 for k in ("steer_rad", "throttle", "brake")), (x, y)

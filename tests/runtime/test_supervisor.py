from kartpilot.core.types import ActuatorCommand, OperatorInput
from kartpilot.runtime.supervisor import Supervisor, SupervisorConfig

DRIVE = ActuatorCommand(0, 0.1, 0.5, 0.0)


def _op(**kw) -> OperatorInput:
    return OperatorInput(**{"source": "gamepad", "hold": True, **kw})


def test_arming_autonomy_passes_the_pipeline_s_command_and_a_fault_stops_it_in_the_same_step():
    supervisor = Supervisor()
    assert supervisor.step(0, [], _op(), DRIVE).brake == 1.0  # disarmed at the start
    assert supervisor.step(1, [], _op(request="autonomous"), DRIVE) == DRIVE
    command = supervisor.step(2, ["no status from the steer ECU for 0.12 s"], _op(), DRIVE)
    assert command == ActuatorCommand.stop(2) and supervisor.state == "fault"
    assert supervisor.transitions[-1].reason == "no status from the steer ECU for 0.12 s"


def test_a_fault_is_latched_until_a_person_re_arms_and_arming_is_then_explicit():
    supervisor = Supervisor()
    supervisor.step(0, [], _op(request="autonomous"), DRIVE)
    supervisor.step(1, ["camera left: frozen"], _op(), DRIVE)
    assert supervisor.step(2, [], _op(), DRIVE).brake == 1.0  # the fault is gone, the stop stays
    assert supervisor.step(3, [], _op(request="autonomous"), DRIVE).brake == 1.0  # no arming out of a fault
    supervisor.step(4, ["camera left: frozen"], _op(request="rearm"), DRIVE)
    assert supervisor.state == "fault" and supervisor.refused == 1  # not while the fault persists
    supervisor.step(5, [], _op(request="rearm"), DRIVE)
    assert supervisor.state == "disarmed"
    assert supervisor.step(6, [], _op(), DRIVE).brake == 1.0
    assert supervisor.step(7, [], _op(request="autonomous"), DRIVE) == DRIVE
    assert [t.state for t in supervisor.transitions] == ["autonomous", "fault", "disarmed", "autonomous"]


def test_the_emergency_stop_wins_in_every_state_even_disarmed():
    for setup in ([], ["manual"], ["autonomous"]):
        supervisor = Supervisor()
        for request in setup:
            supervisor.step(0, [], _op(request=request), DRIVE)
        assert supervisor.step(1, [], _op(estop=True), DRIVE).brake == 1.0
        assert supervisor.state == "fault" and "emergency stop (gamepad)" in supervisor.reason


def test_releasing_the_hold_button_pauses_autonomy_and_holding_it_resumes():
    supervisor = Supervisor()
    supervisor.step(0, [], _op(request="autonomous"), DRIVE)
    assert supervisor.step(1, [], _op(hold=False), DRIVE).brake == 1.0 and supervisor.state == "paused"
    assert supervisor.step(2, [], _op(hold=True), DRIVE) == DRIVE and supervisor.state == "autonomous"
    assert not Supervisor(SupervisorConfig(require_hold=False)).step(0, [], _op(request="autonomous", hold=False),
                                                                     DRIVE).brake


def test_manual_driving_passes_the_person_s_command_and_a_lost_link_is_a_fault():
    supervisor = Supervisor()
    mine = ActuatorCommand(0, -0.2, 0.3, 0.0)
    assert supervisor.step(0, [], _op(request="manual", manual=mine), DRIVE) == mine
    assert supervisor.step(1, [], _op(connected=False, manual=mine), DRIVE).brake == 1.0
    assert supervisor.reason == "operator link lost (gamepad)"


def test_switching_modes_and_disarming_are_logged_with_who_asked():
    supervisor = Supervisor()
    for k, request in enumerate(["manual", "autonomous", "manual", "disarm"]):
        supervisor.step(k, [], _op(request=request), DRIVE)
    assert [(t.state, t.reason) for t in supervisor.transitions] == [
        ("manual", "manual requested by the operator (gamepad)"),
        ("autonomous", "autonomous requested by the operator (gamepad)"),
        ("manual", "manual requested by the operator (gamepad)"),
        ("disarmed", "disarmed by the operator (gamepad)")]
    assert supervisor.transitions[1].to_json(0) == {"t_s": 0.0, "state": "autonomous",
                                                    "reason": "autonomous requested by the operator (gamepad)"}


def test_arming_is_refused_while_a_watchdog_reports_a_fault():
    supervisor = Supervisor()
    supervisor.step(0, ["camera center: black"], _op(request="autonomous"), DRIVE)
    assert supervisor.state == "disarmed" and supervisor.refused == 1


def test_an_overrun_is_a_fault_only_where_the_clock_is_real():
    """Three steps in a row slower than twice the period stop a live drive; the simulator's clock waits for the
    pipeline, so the same durations there are no fault (a busy machine is not a slow kart)."""
    from kartpilot.core.types import FrameSet
    from kartpilot.runtime.drive import WatchdogConfig, Watchdogs

    frames = FrameSet(index=0, stamp_ns=0, images={})
    config = WatchdogConfig(overrun_factor=2.0, overrun_steps=3)
    live = Watchdogs([], 0.05, config)
    simulated = Watchdogs([], 0.05, config, real_time=False)
    durations = [0.2, 0.2, 0.05, 0.2, 0.2, 0.2]  # the third is on time: the count starts again
    live_faults = [live.check(frames, "", d) for d in durations]
    assert [bool(f) for f in live_faults] == [False, False, False, False, False, True]
    assert "overran its 50 ms period 3 times" in live_faults[-1][0]
    assert all(simulated.check(frames, "", d) == [] for d in durations)

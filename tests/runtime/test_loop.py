import pytest

from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.runtime.loop import run_loop


class ListSource:
    def __init__(self, count: int) -> None:
        self.frames = [FrameSet(i, i * 1000, {}) for i in range(count)]

    def read(self) -> FrameSet | None:
        return self.frames.pop(0) if self.frames else None


class ListSink:
    def __init__(self) -> None:
        self.commands: list[ActuatorCommand] = []

    def send(self, command: ActuatorCommand) -> None:
        self.commands.append(command)


def test_the_loop_runs_until_the_source_ends():
    sink = ListSink()
    stats = run_loop(ListSource(5), lambda f: ActuatorCommand(f.stamp_ns, 0.1, 0.5, 0.0), sink)
    assert stats.steps == 5 and len(sink.commands) == 5
    assert set(stats.stage_ms()) == {"source", "policy", "sinks"}


def test_an_exception_in_the_pipeline_commands_a_stop_before_it_propagates():
    sink = ListSink()

    def policy(frames: FrameSet) -> ActuatorCommand:
        if frames.index == 3:
            raise RuntimeError("perception crashed")
        return ActuatorCommand(frames.stamp_ns, 0.2, 0.8, 0.0)

    with pytest.raises(RuntimeError, match="perception crashed"):
        run_loop(ListSource(10), policy, sink)
    assert sink.commands[-1] == ActuatorCommand.stop(3000)  # stamped with the frame that failed
    assert sink.commands[-1].throttle == 0.0 and sink.commands[-1].brake == 1.0


def test_a_slow_step_is_counted_as_a_missed_deadline_and_pacing_holds_the_rate():
    import time

    def slow(frames: FrameSet) -> ActuatorCommand:
        if frames.index == 2:
            time.sleep(0.03)
        return ActuatorCommand(frames.stamp_ns, 0.0, 0.0, 0.0)

    stats = run_loop(ListSource(4), slow, ListSink(), period_s=0.01)
    assert stats.missed_deadlines == 1 and stats.worst_step_ms >= 30.0
    start = time.perf_counter()
    paced = run_loop(ListSource(5), lambda f: ActuatorCommand(f.stamp_ns, 0.0, 0.0, 0.0), ListSink(),
                     period_s=0.02, pace=True)
    assert paced.missed_deadlines == 0
    assert time.perf_counter() - start >= 5 * 0.02 * 0.9  # the loop waited out each period


def test_a_policy_s_outputs_are_recorded_beside_its_commands(tmp_path):
    from kartpilot.core.camera import PinholeCamera
    from kartpilot.record.recording import RecordingReader, RecordingWriter

    class Counting:
        def __init__(self) -> None:
            self.steps = 0

        def __call__(self, frames: FrameSet) -> ActuatorCommand:
            self.steps += 1
            return ActuatorCommand(frames.stamp_ns, 0.0, 0.2, 0.0)

        def outputs(self) -> dict:
            return {"diagnostics": {"steps": self.steps, "state": "ok"}}

    camera = PinholeCamera(100.0, 100.0, 31.5, 23.5, 64, 48)
    with RecordingWriter(tmp_path / "run", {"center": camera}) as writer:
        run_loop(ListSource(4), Counting(), ListSink(), [writer])
    reader = RecordingReader(tmp_path / "run")
    assert [row["steps"] for row in reader.outputs("diagnostics")] == [1, 2, 3, 4]
    assert len(reader.commands()) == 4
    assert reader.manifest["missing_frames"] == {"center": 4}  # the source delivered no images


def test_ctrl_c_commands_a_stop_and_logs_no_error(caplog):
    sink = ListSink()

    def policy(frames: FrameSet) -> ActuatorCommand:
        if frames.index == 2:
            raise KeyboardInterrupt
        return ActuatorCommand(frames.stamp_ns, 0.2, 0.8, 0.0)

    with pytest.raises(KeyboardInterrupt):
        run_loop(ListSource(10), policy, sink)
    assert sink.commands[-1] == ActuatorCommand.stop(2000)
    assert not [r for r in caplog.records if r.levelname == "ERROR"]

"""A simulated run from end to end: simulator, driver, recorder, video, referee's result."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from tqdm import tqdm

from kartpilot.actuation.can_bus import (
    CanActuator,
    CanConfig,
    FrameLog,
    fan_out_frames,
    make_protocol,
    open_bus,
    protocol_database,
)
from kartpilot.calibration.rectify import StereoSetup
from kartpilot.core.config import config_to_dict
from kartpilot.core.errors import ConfigError, RecordingError
from kartpilot.core.geometry import invert_pose
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import ActuatorCommand, CommandSink, FrameSet, FrameSource, Image
from kartpilot.core.vehicle import VehicleParams
from kartpilot.record.recording import RecordingReader, RecordingWriter
from kartpilot.record.video import VideoFile
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.drive import ScriptedOperator, SupervisedDrive, Watchdogs
from kartpilot.runtime.faults import FaultyBus, InjectedSource, Injection, RaisingPipeline, failing_vo
from kartpilot.runtime.loop import LoopStats, Policy, Recorder, run_loop
from kartpilot.runtime.path_policy import DriveSample, PathFollowPolicy, write_drive_log
from kartpilot.runtime.pipelines import (
    PIPELINES,
    PipelineContext,
    Route,
    StereoInput,
    build_pipeline,
    path_policy_of,
)
from kartpilot.runtime.session import SessionOutputs, SessionResult
from kartpilot.runtime.supervisor import Supervisor
from kartpilot.sim.can_ecu import ECU_FAULTS, AppliedCommand, KartpilotEcus, RdwEcus, SimulatedEcus
from kartpilot.sim.drivers import CenterlineDriver, CenterlineDriverConfig, CommandsDriver
from kartpilot.sim.referee import RunResult
from kartpilot.sim.simulator import SimConfig, Simulator

if TYPE_CHECKING:
    from kartpilot.record.rerun_view import RerunView

__all__ = ["DRIVERS", "DriveVideo", "SimRun", "SupervisedRun", "load_commands", "run_simulation",
           "run_supervised_drive", "sim_context", "sim_recording"]

DRIVERS = ("centerline", "commands", "lanes", "path")
STOPPED_BEFORE_END_S = 1.5  # a path drive ends this long after the pipeline decided to stop


@dataclass(frozen=True)
class SimRun:
    """What a run produced. ``ground_truth`` is the main camera's true poses (the stereo pair's left);
    ``drive`` the path follower's log (``path`` driver only)."""

    result: RunResult
    steps: int
    dropped_frames: int
    stage_ms: dict[str, float]
    record_dir: Path | None
    ground_truth: Trajectory | None = None
    drive: tuple[DriveSample, ...] = ()
    missed_deadlines: int = 0
    extra: dict[str, object] = field(default_factory=dict)

    @property
    def stop_reason(self) -> str:
        """Why the path driver stopped the kart (empty for other drivers)."""
        return str(self.extra.get("stop_reason", ""))


def load_commands(path: str | Path) -> list[ActuatorCommand]:
    """Commands from a recording folder or its ``commands.csv``."""
    path = Path(path)
    folder = path.parent if path.name == "commands.csv" else path
    if not (folder / "manifest.json").is_file():
        raise RecordingError(f"{path} is not a recording (no manifest.json next to the commands)")
    return RecordingReader(folder).commands()


def run_simulation(config: SimConfig, driver: str = "centerline",
                   driver_config: CenterlineDriverConfig | None = None, commands: str | Path | None = None,
                   stack: StackConfig | None = None, route: Route | None = None,
                   outputs: SessionOutputs | None = None, taps: Sequence[Recorder] = ()) -> SimRun:
    """Drive one run and write what was asked for. The result JSON always goes next to the recording.
    ``taps`` are more sinks of every frame set, command and output, after the recording and the view.

    ``lanes`` is the lane pipeline; the ``path`` driver is the stereo-VO pipeline following the route's
    reference (relocalising against its visual map, if any). A path run does not end at the finish line but
    once the pipeline has stopped the kart (end of the reference, or localisation lost). ``stack`` gives
    the pipelines' settings.
    """
    stack = stack or StackConfig()
    outputs = outputs or SessionOutputs()
    outputs.check()
    if driver == "path":
        config = replace(config, referee=replace(config.referee, run_on_m=math.inf))
    with Simulator(config) as sim:
        policy = _driver(sim, driver, driver_config, commands, stack, route or Route())
        path_policy = path_policy_of(policy)
        writer = sim_recording(sim, outputs.record_dir, {
            "source": "kartpilot sim", "driver": driver, "sim": config_to_dict(config),
            "groundtruth_camera": _gt_camera(sim)})
        source = _UntilStopped(sim, path_policy) if path_policy is not None else sim
        view = outputs.open_view(sim.cameras if config.render_images else {}, lidars=sim.lidar_mounts)
        stats, wall_s = _run(sim, source, policy, sim, _Recorders(writer, view, tuple(taps)), outputs, path_policy)
        result = sim.result(wall_s)
        pipeline_ms, summary = path_policy.summary(stats.steps) if path_policy is not None else ({}, {})
        ended = "the pipeline stopped the kart" if path_policy is not None and path_policy.stopped else \
            "the simulation ended"
        session = SessionResult("sim", driver, sim.vehicle.name, stats.steps, ended, None, None, stats.missed_deadlines,
                                stats.stage_summary_ms(), pipeline_ms, details={
                                    **result.to_json(), "track": sim.track.name, "seed": config.seed,
                                    "dropped_frames": sim.dropped_frames, **summary})
        outputs.write_result(session)
        stage_ms = stats.stage_ms()
        if path_policy is not None:  # the pipeline's own stages instead of the policy's total
            del stage_ms["policy"]
            stage_ms.update(pipeline_ms)
        return SimRun(result, stats.steps, sim.dropped_frames, stage_ms,
                      Path(outputs.record_dir) if outputs.record_dir else None,
                      sim.ground_truth(_gt_camera(sim)) if sim.stamps_ns else None,
                      tuple(path_policy.samples) if path_policy else (), stats.missed_deadlines, summary)


def _driver(sim: Simulator, driver: str, driver_config: CenterlineDriverConfig | None, commands: str | Path | None,
            stack: StackConfig, route: Route) -> Policy:
    """What drives a ``kartpilot sim`` run: a scripted driver or a pipeline."""
    if driver == "centerline":
        return CenterlineDriver(sim, driver_config)
    if driver == "commands":
        if commands is None:
            raise ConfigError("the commands driver needs a recording or commands.csv to replay")
        return CommandsDriver(load_commands(commands))
    if driver in ("lanes", "path"):
        if not sim.config.render_images:
            raise ConfigError(f"the {driver} driver needs rendered images")
        return build_pipeline("lanes" if driver == "lanes" else "stereo-vo", sim_context(sim, stack, route))
    raise ConfigError(f"unknown driver {driver!r} ({', '.join(DRIVERS)})")


def sim_recording(sim: Simulator, record_dir: str | Path | None, metadata: dict[str, object]
                  ) -> RecordingWriter | None:
    """The simulated run's recording (it waits for the writer instead of dropping frames; its rendered, noisy frames
    as ``png-huffman``, :data:`~kartpilot.record.recording.IMAGE_FORMATS`), if one was asked for."""
    if record_dir is None:
        return None
    return RecordingWriter(record_dir, sim.cameras, stereo_pair=_recorded_pair(sim), metadata=metadata,
                           queue_frames=8, drop_when_full=False, lidars=sim.lidar_mounts or None,
                           image_format="png-huffman")


@dataclass
class _Recorders:
    """The run's recording and Rerun view (either may be absent)."""

    writer: RecordingWriter | None = None
    view: RerunView | None = None
    taps: tuple[Recorder, ...] = ()

    @property
    def sinks(self) -> list[Recorder]:
        return [*(r for r in (self.writer, self.view) if r is not None), *self.taps]

    def close(self, sim: Simulator, path_policy: PathFollowPolicy | None) -> None:
        """Both closed, with the ground truth (and the view with the reference path)."""
        if self.writer is not None:
            if sim.stamps_ns:
                self.writer.write_groundtruth(sim.ground_truth(_gt_camera(sim)))
            self.writer.close()
        if self.view is not None:
            if sim.stamps_ns and sim.cameras:
                truth = sim.ground_truth(_gt_camera(sim))  # the kart's own poses, through the camera's mount
                self.view.write_groundtruth(Trajectory(truth.stamps_s, truth.poses @ invert_pose(
                    sim.cameras[_gt_camera(sim)].pose_body_cam_array)))
            if path_policy is not None:
                self.view.write_reference(np.column_stack([path_policy.path.x_m, path_policy.path.y_m]))
            self.view.close()


def _run(sim: Simulator, source: FrameSource, policy: Policy, sink: CommandSink, recorders: _Recorders,
         outputs: SessionOutputs, path_policy: PathFollowPolicy | None,
         before_close: Callable[[], None] | None = None) -> tuple[LoopStats, float]:
    """The loop over the simulator, with the video, the Rerun view and the progress bar; however it ends, the
    video, the pipeline, its drive log (which says why a failed run failed), the recording and the view (with
    the ground truth) are closed, ``before_close`` first. Returns the loop's statistics and the wall time."""
    drawn = policy.pipeline if isinstance(policy, SupervisedDrive) else policy
    supervisor = policy.supervisor if isinstance(policy, SupervisedDrive) else None
    video = (DriveVideo(outputs.video_path, sim, getattr(drawn, "overlay", None), supervisor)
             if outputs.video_path else None)
    bar = tqdm(total=round(_goal_m(sim), 1), unit="m", disable=(not outputs.progress) or None, leave=False)

    truth_camera = _gt_camera(sim) if sim.cameras else None

    def on_step(frames: FrameSet, command: ActuatorCommand) -> None:
        if recorders.writer is not None and truth_camera is not None and sim.stamps_ns:
            # the truth as it is known: a run killed before it closes keeps it (the recording's own promise)
            recorders.writer.write_truth_pose(sim.stamps_ns[-1], sim.camera_poses[truth_camera][-1])
        if video is not None:
            video.write(frames)
        bar.update(round(min(max(sim.referee.progress_m, 0.0), bar.total), 1) - bar.n)

    start = time.perf_counter()
    try:
        stats = run_loop(source, policy, sink, recorders.sinks, on_step, period_s=sim.dt_s)
    finally:
        bar.close()
        wall_s = time.perf_counter() - start
        if video is not None:
            video.close()
        if path_policy is not None:
            path_policy.close()
            if outputs.drive_log is not None:
                write_drive_log(path_policy.samples, outputs.drive_log)
        if before_close is not None:
            before_close()
        recorders.close(sim, path_policy)
    return stats, wall_s


def sim_context(sim: Simulator, stack: StackConfig, route: Route) -> PipelineContext:
    """The simulator as a pipeline's backend: its rendered cameras, its rate, and the kart's stereo pair as
    ideal, already rectified cameras."""
    cameras = sim.cameras if sim.config.render_images else {}
    pair = _recorded_pair(sim) if cameras else None
    stereo = (StereoInput(pair, StereoSetup(sim.vehicle.stereo_rig(), None, sim.cameras[pair[0]].pose_body_cam_array))
              if pair is not None else None)
    return PipelineContext(sim.vehicle, cameras, sim.config.camera_rate_hz, stack, stereo, route)


class _UntilStopped:
    """The simulator as a source that ends once the path policy has held its stop for a while."""

    def __init__(self, sim: Simulator, policy: PathFollowPolicy) -> None:
        self.sim, self.policy = sim, policy

    def read(self) -> FrameSet | None:
        if self.policy.stopped_for_s(self.sim.time_ns) >= STOPPED_BEFORE_END_S:
            return None
        return self.sim.read()


def _recorded_pair(sim: Simulator) -> tuple[str, str] | None:
    """The vehicle's stereo pair, when both of its cameras are rendered."""
    pair = sim.vehicle.stereo_pair
    return pair if pair and set(pair) <= set(sim.cameras) else None


def _gt_camera(sim: Simulator) -> str:
    pair = sim.vehicle.stereo_pair
    if pair and pair[0] in sim.cameras:
        return pair[0]
    return next(iter(sim.cameras))


def _goal_m(sim: Simulator) -> float:
    track = sim.track
    if track.closed:
        return track.route.length_m * sim.config.referee.laps
    return track.finish_s_m - track.spec.start_s_m


def overlay_lines(sim: Simulator, supervisor: Supervisor | None = None) -> list[tuple[str, bool]]:
    """What a drive's video shows on each frame, and which lines are alarms: the time, speed and distance, the
    command, the referee's verdict, and the supervisor's state with its reason when it is not driving."""
    ref = sim.referee
    status = f"DISQUALIFIED: {ref.reason}" if ref.disqualified else ("FINISHED" if ref.finished else "on track")
    lines = [(f"t {sim.time_s:6.1f} s   v {sim.state.vx_mps:4.2f} m/s   s {ref.progress_m:7.1f} m", False),
             (f"steer {np.degrees(sim.last_command.steer_rad):+5.1f} deg   throttle {sim.last_command.throttle:.2f}",
              False),
             (f"referee: {status}", ref.disqualified)]
    if supervisor is not None:
        state, reason = supervisor.state, supervisor.reason
        text = f"supervisor: {state}" + (f": {reason}" if reason and state != "autonomous" else "")
        lines.append((text, state in ("fault", "paused")))
    return lines


def _wrapped(text: str, width_px: int) -> list[str]:
    """``text`` in lines that fit ``width_px`` in the overlay's font, broken between words."""
    lines: list[str] = []
    for word in text.split(" "):
        candidate = f"{lines[-1]} {word}" if lines else word
        if lines and cv2.getTextSize(candidate, cv2.FONT_HERSHEY_SIMPLEX, 0.7, 1)[0][0] <= width_px:
            lines[-1] = candidate
        else:
            lines.append(word if lines else candidate)
    return lines or [""]


class DriveVideo:
    """Writes the pipeline's view (the policy's ``overlay``, if it has one) or the main camera's image, with
    the referee's state and, for a supervised drive, the supervisor's state and reason drawn on every frame;
    ``more_lines`` adds lines of its own (a scenario's verdict), each with whether it is an alarm."""

    def __init__(self, path: str | Path, sim: Simulator,
                 overlay: Callable[[FrameSet], Image | None] | None = None,
                 supervisor: Supervisor | None = None,
                 more_lines: Callable[[], list[tuple[str, bool]]] | None = None) -> None:
        if not sim.config.render_images:
            raise ConfigError("a video needs rendered images")
        self.sim = sim
        self.overlay = overlay
        self.supervisor = supervisor
        self.more_lines = more_lines
        self.camera = "center" if "center" in sim.cameras else next(iter(sim.cameras))
        cam = sim.cameras[self.camera]
        self._size_hw = (cam.height_px, cam.width_px)
        self._video = VideoFile(path, sim.config.camera_rate_hz, (cam.width_px, cam.height_px))
        self._last: Image | None = None

    def write(self, frames: FrameSet) -> None:
        view = self.overlay(frames) if self.overlay is not None else None
        image = view if view is not None else frames.images.get(self.camera, self._last)
        if image is None:
            return
        if image.shape[:2] != self._size_hw:
            image = cv2.resize(image, self._size_hw[::-1])
        self._last = image
        canvas = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        width = canvas.shape[1] - 24
        lines = overlay_lines(self.sim, self.supervisor) + (self.more_lines() if self.more_lines else [])
        rows = [(part, alarm) for text, alarm in lines for part in _wrapped(text, width)]
        for k, (text, alarm) in enumerate(rows):
            colour = (0, 0, 255) if alarm else (255, 255, 255)
            cv2.putText(canvas, text, (12, 28 + 26 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 3, cv2.LINE_AA)
            cv2.putText(canvas, text, (12, 28 + 26 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.7, colour, 1, cv2.LINE_AA)
        self._video.write(canvas)

    def close(self) -> None:
        self._video.close()


FAULT_HELD_S = 1.0  # a supervised run ends once the kart has been held in a fault this long
BUS_STEP_S = 0.005  # the simulated bus's time step between two loop steps


@dataclass(frozen=True)
class SupervisedRun:
    """A supervised simulated drive: the referee's result and what the supervisor did. ``payload`` is what
    the result JSON holds."""

    result: RunResult
    payload: dict[str, object]
    error: BaseException | None = None


class _DirectSink:
    """The simulator as the actuators, without a bus; the commands it applied are kept."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.applied: list[AppliedCommand] = []

    def send(self, command: ActuatorCommand) -> None:
        self.applied.append(AppliedCommand(self.sim.time_ns, command, "command"))
        self.sim.send(command)


class _BusClock:
    """The simulated bus's own time, which runs on between two loop steps."""

    def __init__(self) -> None:
        self.ns = 0

    def __call__(self) -> int:
        return self.ns


class _CanSink:
    """Commands go onto the CAN bus; the simulated ECUs read them and drive the simulator.

    Between two loop steps the bus's clock runs in steps of at most ``BUS_STEP_S``: the actuator's
    periodic sender, the ECUs' timers and their reports keep their own rates, and faults switch on at
    their own time. The simulator is driven over the period with the mean of what the ECUs executed.
    ``loop-stall`` keeps the loop's commands from the actuator from its time on (a hung loop)."""

    def __init__(self, sim: Simulator, actuator: CanActuator, ecus: SimulatedEcus, clock: _BusClock,
                 at: dict[str, float]) -> None:
        self.sim, self.actuator, self.ecus, self.clock = sim, actuator, ecus, clock
        self.pending = {kind: at_s for kind, at_s in at.items() if kind in ECU_FAULTS}
        self.stall_at_s = at.get("loop-stall")

    @classmethod
    def open(cls, sim: Simulator, stack: StackConfig, at: dict[str, float], log_frame: FrameLog | None
             ) -> _CanSink:
        """The kart's actuator on a virtual bus of its own, the simulated ECUs of its protocol behind it, and the
        bus faults of ``at`` armed; the traffic goes to ``log_frame`` (the recording and the view)."""
        can_config = replace(stack.can, interface="virtual", channel=f"kartpilot-sim-{id(sim)}")
        clock = _BusClock()
        protocol = make_protocol(can_config, sim.vehicle)
        _check_ecu_faults(stack.can, sim.vehicle, at)
        ecus = _simulated_ecus(sim, protocol.name, can_config, clock)
        actuator = CanActuator(FaultyBus(open_bus(can_config), clock, at.get("can-bus-off")), protocol, can_config,
                               stack.limits.for_vehicle(sim.vehicle), clock, log_frame)
        return cls(sim, actuator, ecus, clock, at)

    @property
    def applied(self) -> list[AppliedCommand]:
        return self.ecus.applied

    def close(self) -> None:
        self.actuator.close()
        self.ecus.bus.shutdown()

    def traffic(self) -> dict[str, object]:
        """What went over the bus, for the result; on the RDW protocol, how far 0x440's speed was from the
        simulator's."""
        traffic = {**self.actuator.traffic(), "frames_rejected_by_ecus": self.ecus.rejected_frames}
        if isinstance(self.ecus, RdwEcus) and self.ecus.speed_reports:
            reports = np.array(self.ecus.speed_reports)
            traffic.update(speed_reports=len(reports),
                           speed_error_kmh_max=round(float(np.max(np.abs(reports[:, 2] - reports[:, 1] * 3.6))), 4))
        return traffic

    def send(self, command: ActuatorCommand) -> None:
        start_ns, period_ns = self.sim.time_ns, round(self.sim.dt_s * 1e9)
        self.clock.ns = start_ns
        if self.stall_at_s is None or start_ns * 1e-9 < self.stall_at_s:
            self.actuator.send(command)
        steps = max(1, math.ceil(self.sim.dt_s / BUS_STEP_S))
        executed = np.zeros(3)
        for k in range(1, steps + 1):
            self.clock.ns = start_ns + round(k * period_ns / steps)
            for kind, at_s in list(self.pending.items()):
                if self.clock.ns * 1e-9 >= at_s:
                    self.ecus.inject(kind)
                    del self.pending[kind]
            self.actuator.tick()
            done = self.ecus.step()
            executed += (done.steer_rad, done.throttle, done.brake)
        steer, throttle, brake = executed / steps
        self.sim.send(ActuatorCommand(start_ns, float(steer), float(throttle), float(brake)))


def _check_ecu_faults(config: CanConfig, vehicle: VehicleParams, at: dict[str, float]) -> None:
    """Refuse an ECU fault the simulated ECUs of the kart's protocol cannot show (before anything is written)."""
    name = vehicle.protocol if config.protocol == "vehicle" else config.protocol
    unsupported = sorted(set(at) & set(ECU_FAULTS) - (RdwEcus if name == "rdw" else KartpilotEcus).FAULTS)
    if unsupported:
        raise ConfigError(f"{', '.join(unsupported)}: the {name} protocol's simulated ECUs cannot show it "
                          f"({vehicle.name}; the rdw protocol's can)")


def _simulated_ecus(sim: Simulator, protocol: str, config: CanConfig, clock: _BusClock) -> SimulatedEcus:
    """The ECUs of the simulated kart, for the protocol its actuators speak."""
    def measured() -> tuple[float, float]:
        return sim.state.steer_rad, sim.state.vx_mps

    bus = open_bus(config)
    if protocol == "rdw":
        return RdwEcus(bus, clock, sim.vehicle.steering, measured)
    return KartpilotEcus(bus, clock, config.dbc, 0.1, config.ecus, measured)


class _UntilSettled:
    """The simulator as a source that ends once the drive has settled: a pipeline error or a fault held
    for a while, or the path policy's stop held."""

    def __init__(self, source: FrameSource, sim: Simulator, drive: SupervisedDrive,
                 path_policy: PathFollowPolicy | None) -> None:
        self.source, self.sim, self.drive, self.path_policy = source, sim, drive, path_policy
        self.ended = ""

    def read(self) -> FrameSet | None:
        now = self.sim.time_ns
        transitions = self.drive.supervisor.transitions
        if self.drive.supervisor.state == "fault" and transitions and (now - transitions[-1].stamp_ns) * 1e-9 >= \
                FAULT_HELD_S:
            self.ended = "held in a fault"
            return None
        if self.path_policy is not None and self.path_policy.stopped_for_s(now) >= STOPPED_BEFORE_END_S:
            self.ended = "the pipeline stopped the kart"
            return None
        frames = self.source.read()
        if frames is None:
            self.ended = "the simulation ended"
        return frames


def run_supervised_drive(config: SimConfig, pipeline: str, stack: StackConfig | None = None, bus: str = "none",
                         duration_s: float | None = None, injections: Sequence[Injection] = (),
                         route: Route | None = None, outputs: SessionOutputs | None = None) -> SupervisedRun:
    """Drive ``pipeline`` in the simulator through the supervisor, on the CAN bus (``bus="virtual"``, in the
    protocol the vehicle speaks, its ECUs simulated) or straight to the simulator (``"none"``), with faults
    injected; write the result (and recording). The simulator's own settings are ``config``; ``stack``
    gives every other component's."""
    stack = stack or StackConfig()
    outputs = outputs or SessionOutputs()
    outputs.check()
    at = _check_injections(pipeline, bus, injections)
    if duration_s is not None:
        config = replace(config, max_time_s=duration_s)
    late = [f"{i.kind}@{i.at_s:g}" for i in injections if 0 < config.max_time_s <= i.at_s]
    if late:
        raise ConfigError(f"{', '.join(late)} would come after the drive's end at {config.max_time_s:g} s: it would "
                          "never be injected")
    if pipeline != "lanes":
        config = replace(config, referee=replace(config.referee, run_on_m=math.inf))
    with Simulator(config) as sim:
        wrap_vo = failing_vo(Injection("vo-failure", at["vo-failure"])) if "vo-failure" in at else None
        policy = build_pipeline(pipeline, replace(sim_context(sim, stack, route or Route()), wrap_vo=wrap_vo))
        path_policy = path_policy_of(policy)
        if "stage-exception" in at:
            policy = RaisingPipeline(policy, at["stage-exception"])
        if bus == "virtual":
            _check_ecu_faults(stack.can, sim.vehicle, at)  # before the recording and the view are begun
        writer = sim_recording(sim, outputs.record_dir, {
            "source": "kartpilot drive --sim", "pipeline": pipeline, "bus": bus, "vehicle": sim.vehicle.name,
            "sim": config_to_dict(config), "injections": [f"{i.kind}@{i.at_s:g}" for i in injections]})
        view = outputs.open_view(sim.cameras if config.render_images else {},
                                 protocol_database(stack.can, sim.vehicle) if bus == "virtual" else None,
                                 lidars=sim.lidar_mounts)
        log_frame = fan_out_frames([s.write_can for s in (writer, view) if s is not None])
        sink = _CanSink.open(sim, stack, at, log_frame) if bus == "virtual" else _DirectSink(sim)
        actuator = sink.actuator if isinstance(sink, _CanSink) else None
        supervisor = Supervisor(stack.supervisor)
        watchdogs = Watchdogs(list(sim.cameras) if config.render_images else [], sim.dt_s, stack.watchdogs, actuator,
                              real_time=False)  # the simulated clock waits for the pipeline
        drive = SupervisedDrive(policy, supervisor, watchdogs, ScriptedOperator(at.get("gamepad-unplug")), actuator)
        source = _UntilSettled(InjectedSource(sim, list(injections)), sim, drive, path_policy)

        stats, wall_s = _run(sim, source, drive, sink, _Recorders(writer, view), outputs, path_policy,
                             sink.close if isinstance(sink, _CanSink) else None)
        result = sim.result(wall_s)
        pipeline_ms, summary = path_policy.summary(stats.steps) if path_policy is not None else ({}, {})
        details = {**result.to_json(), "track": sim.track.name, "seed": config.seed, "bus": bus,
                   "injections": [{"kind": i.kind, "at_s": i.at_s} for i in injections],
                   **_fault_to_stop(sink.applied, at), **summary}
        if isinstance(sink, _CanSink):
            details["can"] = sink.traffic()
        session = SessionResult("sim", pipeline, sim.vehicle.name, stats.steps, source.ended, supervisor.state,
                                drive.error_line, stats.missed_deadlines, stats.stage_summary_ms(), pipeline_ms,
                                tuple(t.to_json() for t in supervisor.transitions), details)
        payload = outputs.write_result(session, error_text=drive.error_text)
        return SupervisedRun(result, payload, drive.error)


def _check_injections(pipeline: str, bus: str, injections: Sequence[Injection]) -> dict[str, float]:
    """Each injection's time by kind, once the pipeline, the bus and the injections are known to fit."""
    if pipeline not in PIPELINES:
        raise ConfigError(f"unknown pipeline {pipeline!r} ({', '.join(PIPELINES)})")
    if bus not in ("virtual", "none"):
        raise ConfigError(f"the simulator sits behind the virtual bus or none, not {bus!r}")
    at = {i.kind: i.at_s for i in injections}
    if "vo-failure" in at and pipeline == "lanes":
        raise ConfigError("vo-failure needs the stereo-vo or mono-vo pipeline")
    bus_only = {"can-bus-off", "loop-stall", *ECU_FAULTS} & set(at)
    if bus == "none" and bus_only:
        raise ConfigError(f"{', '.join(sorted(bus_only))} need(s) --bus virtual")
    return at


def _fault_to_stop(applied: Sequence[AppliedCommand], at: dict[str, float]) -> dict[str, object]:
    """How long after the first injected fault the kart got its first stop, and from whom."""
    first = min(at.values()) if at else None
    stop = next((a for a in applied if first is not None and a.stamp_ns * 1e-9 >= first and a.command.is_stop), None)
    injected = first is not None and bool(applied) and applied[-1].stamp_ns * 1e-9 >= first
    return {"fault_to_stop_s": round(stop.stamp_ns * 1e-9 - first, 4) if stop and first is not None else None,
            "stop_by": stop.source if stop else None, "fault_injected": injected}

"""A drive on the real kart: live cameras, the pipeline, the supervisor, the CAN bus, a person.

The same pieces as a simulated drive, with the live backends: :class:`LiveFrameSource` paces the
loop (each step waits for the next camera set), :class:`CanActuator` sends on the kart's bus with
its own sender thread (which stops the kart by itself if the loop hangs), in the protocol the kart
speaks (the RDW kart's own, or ours), and the person is a
gamepad, the web page, or both (:class:`CombinedOperator`). Everything is recorded: frames
(JPEG), commands, the pipeline's outputs, the supervisor's state and the CAN traffic. However the
drive ends (duration, Ctrl-C, an error), the stop command goes out and the recording is closed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from typing import Any

from kartpilot.actuation.can_bus import CanActuator, fan_out_frames, make_protocol, open_bus, protocol_database
from kartpilot.calibration.rectify import stereo_setup
from kartpilot.calibration.rig import Rig, apply_camera_maps
from kartpilot.core.config import config_to_dict, merge_config
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, FrameSet, FrameSource, OperatorInput
from kartpilot.core.vehicle import VehicleParams
from kartpilot.record.recording import RecordingWriter
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.drive import SupervisedDrive, Watchdogs
from kartpilot.runtime.loop import LoopStats, Policy, run_loop
from kartpilot.runtime.pipelines import PipelineContext, Route, StereoInput, build_pipeline
from kartpilot.runtime.session import SessionOutputs, SessionResult
from kartpilot.runtime.supervisor import Supervisor
from kartpilot.runtime.webui import WebConfig, WebOperator, WebServer, terminal_qr
from kartpilot.sensors.capture import LiveFrameSource
from kartpilot.sensors.gamepad import Gamepad
from kartpilot.sensors.lidar import RplidarConfig, RplidarScanner, WithScans

__all__ = ["CombinedOperator", "LiveDriveSetup", "run_live_drive"]

log = logging.getLogger(__name__)

RECORD_QUEUE_FRAMES = 16


class CombinedOperator:
    """Several inputs as one person: any emergency stop or hold counts, every input must stay connected,
    the first request wins, and the manual command comes from the input that is driving."""

    def __init__(self, operators: Sequence[Callable[[int], OperatorInput]]) -> None:
        if not operators:
            raise ConfigError("a live drive needs a person in charge: give --gamepad DEVICE and/or --web PORT")
        self.operators = list(operators)

    def __call__(self, stamp_ns: int) -> OperatorInput:
        inputs = [operator(stamp_ns) for operator in self.operators]
        lost = [i.source for i in inputs if not i.connected]
        driving = [i for i in inputs if i.connected and i.manual is not None and
                   (i.manual.throttle > 0 or i.manual.brake > 0 or i.manual.steer_rad != 0)]
        manual = (driving or [i for i in inputs if i.connected] or [inputs[0]])[0].manual
        estops = [i.source for i in inputs if i.estop]
        return OperatorInput(connected=not lost, estop=bool(estops), hold=any(i.hold and i.connected for i in inputs),
                             request=next((i.request for i in inputs if i.request), ""),
                             manual=manual if manual is not None else ActuatorCommand.stop(stamp_ns),
                             source=", ".join(lost or estops or [i.source for i in inputs]))


@dataclass(frozen=True)
class LiveDriveSetup:
    """What a live drive runs with, besides the stack's configuration."""

    rig: Rig
    pipeline: str
    vehicle: VehicleParams
    route: Route = field(default_factory=Route)
    gamepad: str | None = None
    web_port: int | None = None
    outputs: SessionOutputs = field(default_factory=SessionOutputs)
    duration_s: float | None = None
    web_pair_code: str = ""  # empty: a random one-time code, printed with the pairing address
    web_host: str = "127.0.0.1"  # where the page listens: the hotspot's address to serve phones on it


def run_live_drive(setup: LiveDriveSetup, stack: StackConfig) -> dict[str, Any]:
    """Drive until the duration, the cameras' end, or Ctrl-C; return the result (also in the recording).
    However it ends, the stop command goes out, then the recording, the people's inputs and the cameras are
    closed."""
    setup.outputs.check()  # before the kart moves, not after
    rig = apply_camera_maps(setup.rig)
    # the rig's LiDAR, where it has one, is the kart's (its rules use it while it is healthy)
    vehicle = replace(setup.vehicle, lidar=rig.lidar) if rig.lidar is not None else setup.vehicle
    record_dir = setup.outputs.record_dir
    with ExitStack() as closing:
        source = LiveFrameSource(rig, stack.live)
        closing.callback(source.close)
        scanner = _lidar(rig, closing)
        period_s = 1.0 / rig.capture[source.reference].fps
        pipeline = _live_pipeline(replace(setup, vehicle=vehicle), stack, rig, list(source.threads), period_s)
        operator, web = _people(setup, stack, closing)
        lidars = {"lidar": rig.lidar} if scanner is not None and rig.lidar else None
        writer = None
        if record_dir is not None:
            writer = RecordingWriter(record_dir, {n: rig.cameras[n] for n in source.threads},
                                     stereo_pair=rig.stereo_pair, queue_frames=RECORD_QUEUE_FRAMES,
                                     drop_when_full=True, image_format="jpg",
                                     metadata={"source": "kartpilot drive --live", "pipeline": setup.pipeline,
                                               "vehicle": vehicle.name, "can": config_to_dict(stack.can)},
                                     lidars=lidars)
            closing.callback(writer.close)
        view = setup.outputs.open_view({n: rig.cameras[n] for n in source.threads},
                                       protocol_database(stack.can, vehicle), lidars=lidars)
        if view is not None:
            closing.callback(view.close)
        protocol = make_protocol(stack.can, vehicle, rig.steering, time.monotonic_ns())
        actuator = CanActuator(open_bus(stack.can), protocol, stack.can, stack.limits.for_vehicle(vehicle),
                               log_frame=fan_out_frames([s.write_can for s in (writer, view) if s is not None])
                               ).start()
        closing.callback(actuator.close)  # the stop command, one last time (before the recording closes)
        supervisor = Supervisor(stack.supervisor)
        drive = SupervisedDrive(pipeline, supervisor, Watchdogs(list(source.threads), period_s, stack.watchdogs,
                                                                actuator), operator, actuator)
        source.start()
        timed = _Timed(WithScans(source, scanner) if scanner is not None else source, setup.duration_s)

        def on_step(frames: FrameSet, command: ActuatorCommand) -> None:
            if web is not None:
                web.publish(supervisor.state, supervisor.reason, frames.images.get(source.reference),
                            steer_rad=round(command.steer_rad, 3), throttle=round(command.throttle, 3),
                            brake=round(command.brake, 3), camera_problems=source.problems)

        try:
            stats = run_loop(timed, drive, actuator, [r for r in (writer, view) if r is not None], on_step,
                             period_s=period_s)
        except KeyboardInterrupt:
            timed.ended = "stopped by the user (Ctrl-C)"
            stats = LoopStats(steps=len(drive.step_s), samples_s={"policy": drive.step_s})  # what the loop got done
        session = SessionResult(
            "live", setup.pipeline, vehicle.name, stats.steps, timed.ended, supervisor.state,
            drive.error_line, stats.missed_deadlines,
            stats.stage_summary_ms(), transitions=tuple(t.to_json(0) for t in supervisor.transitions),
            details={"seconds": round(time.monotonic() - timed.started, 2), "cameras": source.stats(),
                     "can": actuator.traffic()})
        return setup.outputs.write_result(session, error_text=drive.error_text)


def _lidar(rig: Rig, closing: ExitStack) -> RplidarScanner | None:
    """The rig's LiDAR device, started (its health checked first: a device in error is refused before the kart
    moves), and closed with the drive; None where the rig names no device."""
    if rig.lidar is None or not rig.lidar_device:
        return None
    scanner = RplidarScanner(merge_config(RplidarConfig(), rig.lidar_device, "lidar.device")).start()
    closing.callback(scanner.close)
    return scanner


class _Timed:
    """The live cameras (with the LiDAR's sweeps), until the drive's duration; says why the drive ended."""

    def __init__(self, source: FrameSource, duration_s: float | None) -> None:
        self.source, self.duration_s = source, duration_s
        self.started = time.monotonic()
        self.ended = "the cameras stopped"

    def read(self) -> FrameSet | None:
        if self.duration_s is not None and time.monotonic() - self.started > self.duration_s:
            self.ended = f"the {self.duration_s:g} s duration elapsed"
            return None
        return self.source.read()


def _live_pipeline(setup: LiveDriveSetup, stack: StackConfig, rig: Rig, cameras: list[str], period_s: float
                   ) -> Policy:
    """The pipeline on the live cameras (a raw stereo pair is rectified on the way in)."""
    pair = rig.stereo_pair
    stereo = (StereoInput(pair, stereo_setup(rig.cameras[pair[0]], rig.cameras[pair[1]]))
              if pair is not None and setup.pipeline == "stereo-vo" else None)
    context = PipelineContext(setup.vehicle, {n: rig.cameras[n] for n in cameras}, 1.0 / period_s, stack, stereo,
                              setup.route)
    return build_pipeline(setup.pipeline, context)


def _people(setup: LiveDriveSetup, stack: StackConfig, closing: ExitStack
            ) -> tuple[CombinedOperator, WebOperator | None]:
    """The person in charge: the gamepad, the web page, or both (each closed with the drive)."""
    operators: list[Callable[[int], OperatorInput]] = []
    if setup.gamepad:
        gamepad = Gamepad(setup.gamepad, stack.gamepad).start()
        closing.callback(gamepad.close)
        operators.append(gamepad)
    web = None
    if setup.web_port is not None:
        web = WebOperator(WebConfig(host=setup.web_host, port=setup.web_port, pair_code=setup.web_pair_code))
        server = WebServer(web)  # told each fresh code before it serves a pairing (it names the server's address)
        web.on_code = lambda code: print(f"web page: the next client pairs at {server.url}?pair={code}\n"
                                         f"{terminal_qr(f'{server.url}?pair={code}')}", flush=True)
        server.start()
        closing.callback(server.close)
        operators.append(web)
        print(f"web page: {', '.join(server.urls())} (view only); the operator opens {server.pairing_url} and "
              "presses the pairing button; or scans:", flush=True)
        print(terminal_qr(server.pairing_url), flush=True)
    return CombinedOperator(operators), web

"""A simulated run from end to end: simulator, driver, recorder, video, referee's result."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from kartpilot.core.config import config_to_dict
from kartpilot.core.errors import ConfigError, RecordingError
from kartpilot.core.types import ActuatorCommand, FrameSet, Image
from kartpilot.record.recording import RecordingReader, RecordingWriter
from kartpilot.runtime.lane_policy import LanePolicy, LanePolicyConfig
from kartpilot.runtime.loop import Policy, Recorder, run_loop
from kartpilot.sim.drivers import CenterlineDriver, CenterlineDriverConfig, CommandsDriver
from kartpilot.sim.referee import RunResult
from kartpilot.sim.simulator import SimConfig, Simulator

__all__ = ["SimRun", "load_commands", "run_simulation"]


@dataclass(frozen=True)
class SimRun:
    result: RunResult
    steps: int
    dropped_frames: int
    stage_ms: dict[str, float]
    record_dir: Path | None


def load_commands(path: str | Path) -> list[ActuatorCommand]:
    """Commands from a recording folder or its ``commands.csv``."""
    path = Path(path)
    folder = path.parent if path.name == "commands.csv" else path
    if not (folder / "manifest.json").is_file():
        raise RecordingError(f"{path} is not a recording (no manifest.json next to the commands)")
    return RecordingReader(folder).commands()


def run_simulation(config: SimConfig, driver: str = "centerline",
                   driver_config: CenterlineDriverConfig | None = None, commands: str | Path | None = None,
                   record_dir: str | Path | None = None, video_path: str | Path | None = None,
                   result_path: str | Path | None = None, progress: bool = False,
                   lane_config: LanePolicyConfig | None = None) -> SimRun:
    """Drive one run and write what was asked for. The result JSON always goes next to the recording."""
    with Simulator(config) as sim:
        policy: Policy
        if driver == "centerline":
            policy = CenterlineDriver(sim, driver_config)
        elif driver == "commands":
            if commands is None:
                raise ConfigError("the commands driver needs a recording or commands.csv to replay")
            policy = CommandsDriver(load_commands(commands))
        elif driver == "lanes":
            if not config.render_images:
                raise ConfigError("the lanes driver needs rendered images")
            policy = LanePolicy(sim.cameras, lane_config, config.camera_rate_hz)
        else:
            raise ConfigError(f"unknown driver {driver!r} (centerline, commands or lanes)")

        recorders: list[Recorder] = []
        writer: RecordingWriter | None = None
        if record_dir is not None:
            pair = sim.vehicle.stereo_pair if sim.vehicle.stereo_pair and set(sim.vehicle.stereo_pair) <= set(
                sim.cameras) else None
            writer = RecordingWriter(record_dir, sim.cameras, stereo_pair=pair, metadata={
                "source": "kartpilot sim", "driver": driver, "sim": config_to_dict(config),
                "groundtruth_camera": _gt_camera(sim)}, queue_frames=8, drop_when_full=False)
            recorders.append(writer)
        video = _VideoSink(video_path, sim) if video_path is not None else None
        bar = tqdm(total=round(_goal_m(sim), 1), unit="m", disable=(not progress) or None, leave=False)
        start = time.perf_counter()

        def on_step(frames: FrameSet, command: ActuatorCommand) -> None:
            if writer is not None and len(frames.images) < len(sim.cameras):
                writer.count_dropped(len(sim.cameras) - len(frames.images))
            if video is not None:
                video.write(frames)
            bar.update(round(min(max(sim.referee.progress_m, 0.0), bar.total), 1) - bar.n)

        try:
            stats = run_loop(sim, policy, sim, recorders, on_step)
        finally:
            bar.close()
            wall = time.perf_counter() - start
            if video is not None:
                video.close()
            if writer is not None:
                if sim.stamps_ns:
                    writer.write_groundtruth(sim.ground_truth(_gt_camera(sim)))
                writer.close()
        result = sim.result(wall)
        payload = {**result.to_json(), "track": sim.track.name, "vehicle": sim.vehicle.name, "seed": config.seed,
                   "driver": driver, "steps": stats.steps, "dropped_frames": sim.dropped_frames,
                   "stage_ms": {k: round(v, 3) for k, v in stats.stage_ms().items()}}
        targets = [Path(result_path)] if result_path else []
        if record_dir is not None:
            targets.append(Path(record_dir) / "result.json")
        for target in targets:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(json.dumps(payload, indent=2))
        return SimRun(result, stats.steps, sim.dropped_frames, stats.stage_ms(),
                      Path(record_dir) if record_dir else None)


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


class _VideoSink:
    """Writes the main camera's view with the referee's state drawn on it."""

    def __init__(self, path: str | Path, sim: Simulator) -> None:
        if not sim.config.render_images:
            raise ConfigError("a video needs rendered images")
        self.sim = sim
        self.camera = "center" if "center" in sim.cameras else next(iter(sim.cameras))
        cam = sim.cameras[self.camera]
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self._writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), sim.config.camera_rate_hz,
                                       (cam.width_px, cam.height_px))
        if not self._writer.isOpened():
            raise RecordingError(f"cannot write the video {path}")
        self._last: Image | None = None

    def write(self, frames: FrameSet) -> None:
        image = frames.images.get(self.camera, self._last)
        if image is None:
            return
        self._last = image
        sim, ref = self.sim, self.sim.referee
        canvas = image.copy()
        status = f"DISQUALIFIED: {ref.reason}" if ref.disqualified else ("FINISHED" if ref.finished else "OK")
        lines = [f"t {sim.time_s:6.1f} s   v {sim.state.vx_mps:4.2f} m/s   s {ref.progress_m:7.1f} m",
                 f"steer {np.degrees(sim.last_command.steer_rad):+5.1f} deg   throttle {sim.last_command.throttle:.2f}",
                 status]
        for k, text in enumerate(lines):
            colour = (0, 0, 255) if (k == 2 and ref.disqualified) else (255, 255, 255)
            cv2.putText(canvas, text, (12, 28 + 26 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 3, cv2.LINE_AA)
            cv2.putText(canvas, text, (12, 28 + 26 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.7, colour, 1, cv2.LINE_AA)
        self._writer.write(canvas)

    def close(self) -> None:
        self._writer.release()

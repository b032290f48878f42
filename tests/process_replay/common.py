"""Process replay, after openpilot's: short recordings made in the simulator are replayed through each
pipeline and the commands and outputs are compared with stored ones (``refs/<pipeline>.csv``), within
tolerances that allow for floating-point and rendering differences between machines, not for a change
of behaviour.

After an intended change of a pipeline's behaviour, regenerate the references and commit them with the
change (the diff of the CSV shows what changed)::

    .venv/bin/python -m tests.process_replay.update_refs
"""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

from kartpilot.core.geometry import ground_poses
from kartpilot.planning.reference_path import PathConfig, build_reference_path
from kartpilot.record.recording import RecordingReader, RecordingStereoSource
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.pipelines import Route
from kartpilot.runtime.replay import ReplayResult, replay_recording
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import SimConfig

REFS = Path(__file__).parent / "refs"

# each pipeline: the drive to record (the centerline driver: independent of the pipeline under test)
DRIVES = {
    "lanes": (SimConfig(track="sdc-assen", vehicle="sdc-kart", camera_rate_hz=15.0, max_time_s=4.0, seed=1),
              CenterlineDriverConfig(speed_mps=4.0)),
    "stereo-vo": (SimConfig(track="straight20", vehicle="rc-kart", cameras=("left", "right"), camera_rate_hz=10.0,
                            max_time_s=4.0, seed=1), CenterlineDriverConfig(speed_mps=0.8)),
}
# compared columns and the tolerance of each (absolute; None: must be equal). A boundary's bottom end lies
# where the line crosses the image's bottom row, often far outside the image: it moves most with its slope
COLUMNS: dict[str, dict[str, float | None]] = {
    "lanes": {"steer_rad": 0.0005, "throttle": 0.01, "brake": 0.01, "left_source": None, "right_source": None,
              "left_x_bottom_px": 10.0, "left_x_top_px": 2.0, "right_x_bottom_px": 10.0, "right_x_top_px": 2.0,
              "rule": None},
    "stereo-vo": {"steer_rad": 0.0005, "throttle": 0.01, "brake": 0.01, "x_m": 0.005, "y_m": 0.005,
                  "yaw_rad": 0.002, "status": None, "cross_track_m": 0.005},
}


def record_drive(pipeline: str, folder: Path) -> Path:
    """Record the pipeline's drive in a fresh Python process, as the references were.

    The renderer is not bit-identical across the history of a process: after other simulated runs, the first
    frames of a drive can differ near the horizon (Panda3D state carried between renderers; not yet found).
    A fresh process keeps this test about the pipeline."""
    code = ("import sys; from pathlib import Path; from tests.process_replay.common import _record; "
            "_record(sys.argv[1], Path(sys.argv[2]))")
    subprocess.run([sys.executable, "-c", code, pipeline, str(folder)], check=True, cwd=Path(__file__).parents[2])
    return folder


def _record(pipeline: str, folder: Path) -> None:
    sim, driver = DRIVES[pipeline]
    run_simulation(sim, "centerline", driver_config=driver, outputs=SessionOutputs(record_dir=folder))


def replay(pipeline: str, recording: Path, out: Path) -> ReplayResult:
    reference = None
    if pipeline == "stereo-vo":  # the path from the drive's true poses: independent of VO
        source = RecordingStereoSource(recording)
        truth = source.ground_truth()
        assert truth is not None
        reference = build_reference_path(ground_poses(truth.poses, source.pose_body_left)[:, :2],
                                         PathConfig(cruise_speed_mps=0.8))
    return replay_recording(recording, pipeline, StackConfig(), Route(reference),
                            outputs=SessionOutputs(record_dir=out))


def result_rows(recording: Path) -> list[dict[str, object]]:
    """One row per set: the command and the outputs, merged by time."""
    reader = RecordingReader(recording)
    rows = {c.stamp_ns: {"stamp_ns": c.stamp_ns, "steer_rad": c.steer_rad, "throttle": c.throttle, "brake": c.brake}
            for c in reader.commands()}
    for topic in reader.output_topics():
        for row in reader.outputs(topic):
            rows[int(row["stamp_ns"])].update({k: v for k, v in row.items() if k != "stamp_ns"})
    return [rows[stamp] for stamp in sorted(rows)]


def write_rows(rows: list[dict[str, object]], pipeline: str, target: Path) -> None:
    keys = ["stamp_ns", *COLUMNS[pipeline]]
    with target.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(keys)
        for row in rows:
            writer.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in (row[k] for k in keys)])


def read_rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def differences(pipeline: str, stored: list[dict[str, str]], new: list[dict[str, object]]) -> list[str]:
    """What differs beyond the tolerances, one line each."""
    if [int(r["stamp_ns"]) for r in stored] != [int(str(r["stamp_ns"])) for r in new]:
        return [f"the sets differ: {len(stored)} stored, {len(new)} now"]
    found = []
    for k, (old, now) in enumerate(zip(stored, new, strict=True)):
        for column, tolerance in COLUMNS[pipeline].items():
            a, b = old[column], now[column]
            if tolerance is None:
                if str(a) != str(b):
                    found.append(f"set {k} {column}: {a} stored, {b} now")
                continue
            x, y = float(a), float(str(b))
            if math.isnan(x) and math.isnan(y):
                continue
            if not abs(x - y) <= tolerance:
                found.append(f"set {k} {column}: {x:.6g} stored, {y:.6g} now (tolerance {tolerance})")
    return found

"""What a Rerun view costs a drive: the loop's time per frame with and without ``--view``, and the logging
thread's.

A short simulated lanes drive of the sdc-kart (three cameras, 960x540, 30 Hz) is recorded once; its frames then
go through the lane pipeline in the loop three times over, with no view and with a view to a ``.rrd`` file, in
alternation. What the drive waits for is the view's calls in the loop (queueing a step, and the pipeline's
outputs it asks for), timed around each call, plus how much slower the pipeline runs beside the logging thread
(they share Python's interpreter lock). The thread's own encoding and writing runs beside the loop, on a second
core if there is one. All are per frame (medians of the passes), against the pipeline's time per frame without
a view and against the 30 Hz period.

    python benchmarks/view_cost.py --out docs/results/view_cost.json
    python benchmarks/view_cost.py --docs      # the table in docs/viewing.md, from that JSON
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from common import write_json
from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.record.recording import RecordingReader
from kartpilot.record.replay import RecordingFrameSource
from kartpilot.record.rerun_view import RerunView, ViewConfig
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.lane_policy import LanePolicy
from kartpilot.runtime.loop import Outputs, run_loop
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.simulator import SimConfig
from vo_table import put_at_marker

RATE_HZ = 30.0


class _Null:
    def send(self, command: ActuatorCommand) -> None:
        pass


class _Timed:
    """The view as the loop sees it, with the time the loop spends in it summed: queueing a step, and the
    pipeline's outputs, which the loop asks for only when there is a sink for them."""

    def __init__(self, view: RerunView, policy: LanePolicy) -> None:
        self.view, self.policy, self.seconds = view, policy, 0.0

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        return self.policy(frames)

    def outputs(self) -> dict[str, dict[str, float | int | str]]:
        start = time.perf_counter()
        try:
            return self.policy.outputs()
        finally:
            self.seconds += time.perf_counter() - start

    def write_frames(self, frames: FrameSet) -> None:
        start = time.perf_counter()
        self.view.write_frames(frames)
        self.seconds += time.perf_counter() - start

    def send(self, command: ActuatorCommand) -> None:
        start = time.perf_counter()
        self.view.send(command)
        self.seconds += time.perf_counter() - start

    def write_outputs(self, stamp_ns: int, outputs: Outputs) -> None:
        start = time.perf_counter()
        self.view.write_outputs(stamp_ns, outputs)
        self.seconds += time.perf_counter() - start


def one_pass(recording: Path, view_path: Path | None) -> dict[str, float]:
    reader = RecordingReader(recording)
    source = RecordingFrameSource(recording, list(reader.cameras))
    policy = LanePolicy(reader.cameras, StackConfig().lane_policy, RATE_HZ)
    view = RerunView(view_path, reader.cameras, ViewConfig()) if view_path is not None else None
    timed = _Timed(view, policy) if view is not None else None
    stats = run_loop(source, timed or policy, _Null(), [timed] if timed is not None else [], period_s=1 / RATE_HZ)
    row = {"steps": stats.steps, "policy_ms": stats.stage_ms()["policy"]}
    if view is not None and timed is not None:
        row["loop_ms"] = 1e3 * timed.seconds / stats.steps
        start = time.perf_counter()
        view.close()
        row.update(close_s=time.perf_counter() - start, worker_ms=1e3 * view.worker_s / stats.steps,
                   dropped_images=view.dropped_images, rrd_mb=view_path.stat().st_size / 1e6 if view_path else 0.0)
    return row


ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "viewing.md"
MARKER = "view-cost"


def render(results: dict[str, Any]) -> str:
    """The docs' table of what a view costs, from the JSON :func:`main` writes."""
    view, what = results["view"], results["what"]
    return "\n".join([
        f"{what[:1].upper()}{what[1:]} ({results['frames']} frames, the median of {results['repeats']} passes; "
        f"images at scale {view['image_scale']:g}, JPEG quality {view['jpeg_quality']}; "
        "`benchmarks/view_cost.py`):", "",
        "| per frame | ms | share of the pipeline's time | share of the 30 Hz period |",
        "|---|---:|---:|---:|",
        f"| the pipeline, without a view | {results['pipeline_ms']:.2f} | 100 % | "
        f"{100 * results['pipeline_ms'] * RATE_HZ / 1e3:.1f} % |",
        f"| what the loop waits for with a view (its calls {results['calls_ms']:.3f} ms, the pipeline slowed "
        f"beside the thread) | {results['loop_cost_ms']:.2f} | {results['loop_cost_percent_of_pipeline']:.1f} % | "
        f"{results['loop_cost_percent_of_period']:.1f} % |",
        f"| the logging thread (beside the loop) | {results['worker_ms']:.2f} | "
        f"{100 * results['worker_ms'] / results['pipeline_ms']:.0f} % | {results['worker_percent_of_period']:.1f} % |",
        "", f"Images dropped because the thread lagged: {results['dropped_images']:.0f}. The file grows by about "
        f"{results['rrd_mb_per_minute']:.0f} MB a minute.", ""])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="docs/results/view_cost.json")
    parser.add_argument("--docs", action="store_true", help="only put the table from --out into docs/viewing.md")
    args = parser.parse_args()
    if args.docs:
        put_at_marker(PAGE, render(json.loads(Path(args.out).read_text(encoding="utf-8"))), MARKER)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        recording = Path(tmp) / "drive"
        config = SimConfig(track="sdc-assen", vehicle="sdc-kart", camera_rate_hz=RATE_HZ, max_time_s=args.seconds,
                           speed_mode_mps=15 / 3.6, seed=1)
        run_simulation(config, "lanes", outputs=SessionOutputs(record_dir=recording))
        passes: dict[str, list[dict[str, float]]] = {"without view": [], "with view": []}
        for repeat in range(args.repeats):
            passes["without view"].append(one_pass(recording, None))
            passes["with view"].append(one_pass(recording, Path(tmp) / f"view{repeat}.rrd"))
    median = {name: {key: statistics.median(r[key] for r in rows) for key in rows[0]} for name, rows in passes.items()}
    without, with_view = median["without view"], median["with view"]
    # what the drive waits for: the view's own calls, and the pipeline slowed by the thread (Python's lock)
    slowed_ms = with_view["policy_ms"] - without["policy_ms"]
    loop_ms = with_view["loop_ms"] + slowed_ms
    result: dict[str, Any] = {
        "what": "the lanes pipeline on the sdc-kart's three 960x540 cameras, a recorded 30 Hz sdc-assen drive",
        "frames": int(without["steps"]), "repeats": args.repeats, "view": ViewConfig().__dict__,
        "pipeline_ms": without["policy_ms"], "pipeline_with_view_ms": with_view["policy_ms"],
        "calls_ms": with_view["loop_ms"], "loop_cost_ms": loop_ms, "worker_ms": with_view["worker_ms"],
        "loop_cost_percent_of_pipeline": 100 * loop_ms / without["policy_ms"],
        "loop_cost_percent_of_period": 100 * loop_ms * RATE_HZ / 1e3,
        "worker_percent_of_period": 100 * with_view["worker_ms"] * RATE_HZ / 1e3,
        "dropped_images": with_view["dropped_images"], "rrd_mb_per_minute": with_view["rrd_mb"] * 60 / args.seconds,
        "passes": passes,
    }
    print(f"{result['frames']} frames: pipeline {result['pipeline_ms']:.2f} ms/frame; the view costs the loop "
          f"{loop_ms:.3f} ms/frame ({result['loop_cost_percent_of_pipeline']:.1f} % of the pipeline), its thread "
          f"{result['worker_ms']:.2f} ms/frame ({result['worker_percent_of_period']:.1f} % of the 30 Hz period); "
          f"{result['dropped_images']:.0f} images dropped; {result['rrd_mb_per_minute']:.0f} MB per minute")
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Place recognition on a simulated lap: Recall@1 and @5 within 2 m, the fix error, and the time per stage.

The SDC kart's centre camera on sdc-assen with roadside buildings: one drive builds the
database (positions from the simulator's truth, as a survey would give), a second drive on
the same line and light at another speed queries it, and a third 0.4 m to the left at dusk.

    python benchmarks/places.py --seconds 200 --out benchmarks/results/places.json
"""

from __future__ import annotations

import argparse
import itertools
import platform
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from common import write_json
from kartpilot.core.geometry import Array
from kartpilot.core.types import Image
from kartpilot.eval.places import evaluate_places
from kartpilot.odometry.places import build_places
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig


def drive(folder: Path, seconds: float, seed: int, speed_mps: float, time_of_day_h: float,
          offset_m: float) -> RecordingReader:
    config = SimConfig(track="sdc-assen", vehicle="sdc-kart-steep", cameras=("center",), camera_rate_hz=10.0,
                       max_time_s=seconds, seed=seed,
                       render=RenderConfig(time_of_day_h=time_of_day_h, scenery_spacing_m=15.0))
    run_simulation(config, "centerline", driver_config=CenterlineDriverConfig(speed_mps=speed_mps,
                                                                              edge_offset_m=offset_m),
                   outputs=SessionOutputs(record_dir=folder))
    return RecordingReader(folder)


def posed(reader: RecordingReader, every: int = 1, skip: int = 0) -> Iterator[tuple[int, Image, Array]]:
    truth = reader.camera_poses("center")
    assert truth is not None, "a simulated drive has ground truth"
    return itertools.islice(reader.posed_frames("center", truth), skip, None, every)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=200.0, help="simulated seconds per drive (200: a lap)")
    parser.add_argument("--every", type=int, default=2, help="query every n-th frame")
    parser.add_argument("--out", default="benchmarks/results/places.json")
    args = parser.parse_args()
    results: dict[str, object] = {"machine": platform.processor() or platform.machine(), "seconds": args.seconds}
    with tempfile.TemporaryDirectory() as tmp:
        reference = drive(Path(tmp) / "ref", args.seconds, 1, 5.0, 13.0, 0.0)
        start = time.perf_counter()
        database = build_places(posed(reference), reference.cameras["center"], "center")
        build_s = time.perf_counter() - start
        size_mb = database.save(Path(tmp) / "places.db").stat().st_size / 1e6
        print(f"{len(database)} places, built in {build_s:.1f} s, {size_mb:.1f} MB")
        results["database"] = {"places": len(database), "build_s": round(build_s, 2), "size_mb": round(size_mb, 2)}
        for name, seed, speed, hour, offset in (("same line and light", 2, 4.5, 13.0, 0.0),
                                                ("0.4 m left, dusk", 3, 4.5, 18.5, 0.4)):
            queries = drive(Path(tmp) / name.replace(" ", "_"), args.seconds, seed, speed, hour, offset)
            before = dict(database.timing_ms), database.queries
            frames = posed(queries, args.every, skip=5)
            recall = evaluate_places(database, frames)
            count = database.queries - before[1]
            stages = {k: round((v - before[0][k]) / count, 2) for k, v in database.timing_ms.items()}
            print(f"\n{name}\n{recall.table()}\nper stage (ms): {stages}")
            results[name] = {**recall.to_json(), "stage_ms": stages}
    write_json(args.out, results)


if __name__ == "__main__":
    main()

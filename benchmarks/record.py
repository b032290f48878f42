"""Can the recorder keep up with the SDC kart's three cameras without holding up the loop?

Sets of three 960x540 BGR camera images (rendered road-like texture with noise, so PNG has
real work) are handed to the recording writer at 30 Hz for a while, as the live loop does.
Prints the time the caller spent per set (what the control loop loses), frames written and
dropped per camera, and writes JSON.

    python benchmarks/record.py --seconds 10 --out benchmarks/results/record.json
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time

import numpy as np

from common import write_json
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.types import FrameSet
from kartpilot.record.recording import RecordingReader, RecordingWriter


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--cameras", type=int, default=3)
    parser.add_argument("--queue", type=int, default=16, help="frames queued per camera (kartpilot record: 16)")
    parser.add_argument("--image-format", choices=("jpg", "png"), default="jpg")
    parser.add_argument("--out", default="benchmarks/results/record.json")
    args = parser.parse_args()
    camera = PinholeCamera(743.0, 743.0, 479.5, 269.5, 960, 540)
    names = ["center", "left", "right"][: args.cameras]
    rng = np.random.default_rng(0)
    base = np.tile(np.linspace(60, 200, 960, dtype=np.float32), (540, 1))
    images = [np.clip(base[..., None] + rng.normal(0, 6, (540, 960, 3)), 0, 255).astype(np.uint8) for _ in range(8)]
    period = 1.0 / args.rate
    caller_ms: list[float] = []
    with tempfile.TemporaryDirectory() as folder:
        writer = RecordingWriter(f"{folder}/run", dict.fromkeys(names, camera), queue_frames=args.queue,
                                 drop_when_full=True, image_format=args.image_format)
        start = time.perf_counter()
        k = 0
        while (now := time.perf_counter()) - start < args.seconds:
            stamp = round((now - start) * 1e9)
            t0 = time.perf_counter()
            writer.write_frames(FrameSet(k, stamp, {n: images[(k + i) % 8] for i, n in enumerate(names)}))
            caller_ms.append((time.perf_counter() - t0) * 1e3)
            k += 1
            time.sleep(max(0.0, start + k * period - time.perf_counter()))
        t_close = time.perf_counter()
        writer.close()
        close_s = time.perf_counter() - t_close
        reader = RecordingReader(f"{folder}/run")
        written = {n: len(reader.frames(n)) for n in names}
        dropped = reader.manifest["dropped_frames"]
    ms = np.array(caller_ms)
    result = {
        "sets": k, "rate_hz": args.rate, "cameras": names, "queue_frames": args.queue,
        "image_format": args.image_format,
        "caller_ms": {"median": round(float(np.median(ms)), 3), "p99": round(float(np.percentile(ms, 99)), 3),
                      "max": round(float(ms.max()), 3)},
        "written": written, "dropped": dropped, "close_s": round(close_s, 2),
        "machine": platform.processor() or platform.machine(),
    }
    caller = result["caller_ms"]
    print(f"{k} sets of {len(names)} cameras at {args.rate:g} Hz ({args.image_format}): the caller spent "
          f"{caller['median']:.2f} ms per set (p99 {caller['p99']:.2f}, max {caller['max']:.2f})")
    for n in names:
        print(f"  {n}: {written[n]} written, {dropped[n]} dropped")
    print(f"closing (the queues drained) took {close_s:.2f} s")
    write_json(args.out, result)


if __name__ == "__main__":
    main()

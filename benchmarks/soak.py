"""A long drive stays healthy: a simulated drive of 30 minutes of kart time, recorded, watched from outside.

``kartpilot sim`` drives the lane pipeline round the venue track (``lelystad``, the sdc-kart's centre camera at
10 Hz, the 15 km/h mode) with ``--record``, as a separate process. Every few seconds this script reads the
process's resident memory and open files (``/proc``), the recording's size on disk and its frames so far. It
reports the memory's growth after the first minute of kart time (the caches and the renderer are warm by then),
whether the open files stay flat, the recording's bytes per frame over the drive, and whether every step's frame
was recorded (none dropped unreported). Not part of ``make test``: it takes about as long as the drive.

    python benchmarks/soak.py --out docs/results/soak.json
    python benchmarks/soak.py --render docs/results/soak.json   # into docs/live-and-replay.md
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from common import write_json
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "live-and-replay.md"
RATE_HZ = 10.0


def _proc(pid: int) -> tuple[float, int]:
    """(resident memory in MiB, open file descriptors) of a running process."""
    rss_kib = 0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss_kib = int(line.split()[1])
    return rss_kib / 1024, len(list(Path(f"/proc/{pid}/fd").iterdir()))


def _frames(folder: Path) -> int:
    frames = folder / "cameras" / "center" / "frames.csv"
    return max(frames.read_text().count("\n") - 1, 0) if frames.is_file() else 0


def _size_mib(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 2**20 if folder.is_dir() else 0.0


def soak(minutes: float, every_s: float = 5.0) -> dict[str, Any]:
    laps = int(minutes * 60 * 4.0 / 277.0) + 1  # about 4 m/s round a 277 m loop
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch) / "soak"
        command = [str(Path(sys.executable).with_name("kartpilot")), "sim", "--track", "lelystad", "--vehicle",
                   "sdc-kart", "--driver", "lanes", "--cameras", "center", "--rate", str(RATE_HZ), "--laps",
                   str(laps), "--speed-mode", "15", "--record", str(folder), "--result",
                   str(Path(scratch) / "result.json"), "--no-progress"]
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        samples = []
        start = time.monotonic()
        while process.poll() is None:
            try:
                rss, files = _proc(process.pid)
            except (FileNotFoundError, ProcessLookupError):
                break
            frames = _frames(folder)
            samples.append({"wall_s": round(time.monotonic() - start, 1), "kart_s": frames / RATE_HZ,
                            "rss_mib": round(rss, 1), "open_files": files, "frames": frames,
                            "recording_mib": round(_size_mib(folder), 2)})
            if frames / RATE_HZ >= minutes * 60:
                process.terminate()  # SIGTERM: the drive closes its recording as on Ctrl-C
                break
            time.sleep(every_s)
        _, err = process.communicate()
        result = json.loads((Path(scratch) / "result.json").read_text()) if (
            Path(scratch) / "result.json").is_file() else {}
        from kartpilot.record.recording import RecordingReader

        reader = RecordingReader(folder)
        recorded = len(reader.frames("center"))
        commands = len(reader.commands())
        closed = reader.closed
        size = _size_mib(folder)
    warm = [s for s in samples if s["kart_s"] >= 60.0]
    base = warm[0] if warm else samples[0]
    last = samples[-1]
    per_frame = [(s["recording_mib"] / s["frames"]) for s in samples if s["frames"] > 100]
    return {
        "kart_minutes": round(recorded / RATE_HZ / 60, 2), "wall_minutes": round(last["wall_s"] / 60, 2),
        "rss_after_first_minute_mib": base["rss_mib"], "rss_end_mib": last["rss_mib"],
        "rss_growth_after_first_minute": round(last["rss_mib"] / base["rss_mib"] - 1.0, 4),
        "open_files_min_max": [min(s["open_files"] for s in warm or samples),
                               max(s["open_files"] for s in warm or samples)],
        "recording_mib": round(size, 1), "recording_kib_per_frame_first_last": [
            round(1024 * per_frame[0], 1), round(1024 * per_frame[-1], 1)] if per_frame else [],
        "frames_recorded": recorded, "commands_recorded": commands, "closed_properly": closed,
        "exit_code": process.returncode, "stderr": err.strip().splitlines()[-1:] if err.strip() else [],
        "result": {k: result.get(k) for k in ("disqualified", "reason", "distance_m", "sim_time_s")} if result
        else "none (stopped before the finish)",
        "samples": samples,
    }


def render(results: dict[str, Any]) -> str:
    r = results
    files = r["open_files_min_max"]
    per_frame = r["recording_kib_per_frame_first_last"]
    return "\n".join([
        f"Measured by `benchmarks/soak.py`: {r['kart_minutes']:.1f} minutes of kart time (laps of `lelystad`, the "
        "lane pipeline on the sdc-kart's centre camera at 10 Hz, recorded as PNG), stopped with SIGTERM. Memory "
        "is the process's resident set, read from /proc every 5 s.", "",
        "| what | measured |", "|---|---|",
        "| resident memory after the first minute of kart time, at the end | "
        f"{r['rss_after_first_minute_mib']:.0f} MiB, {r['rss_end_mib']:.0f} MiB "
        f"({100 * r['rss_growth_after_first_minute']:+.1f} %) |",
        f"| open files, least and most after the first minute | {files[0]}, {files[1]} |",
        f"| recording, its size per frame early and at the end | {r['recording_mib']:.0f} MiB, "
        f"{per_frame[0] if per_frame else 0:.0f} and {per_frame[-1] if per_frame else 0:.0f} KiB a frame |",
        f"| frames and commands recorded | {r['frames_recorded']}, {r['commands_recorded']} |",
        f"| closed properly after SIGTERM | {'yes' if r['closed_properly'] else 'no'} (exit code {r['exit_code']}) |",
    ]) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0, help="kart time to drive")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "soak.json")
    parser.add_argument("--render", type=Path, help="write this JSON's table into docs/live-and-replay.md")
    args = parser.parse_args()
    if args.render:
        put_at_marker(PAGE, render(json.loads(args.render.read_text())), "soak")
        return 0
    write_json(args.out, soak(args.minutes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

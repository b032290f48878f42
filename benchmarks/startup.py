"""How long ``kartpilot`` takes to start: whole processes, as a user or a script runs them.

Each command runs ``--repeats`` times in turn (the median counts): ``kartpilot --help``, every subcommand's
``--help`` (what each pays before its first frame: its parser, no handler), and two real jobs on one 848x480 image
(a frame of the real kart's camera at the venue where ``--data`` has it, else a rendered stand-in of that size):
``kartpilot lanes IMAGE --out X.csv`` and ``kartpilot detect IMAGE --out X.csv``.

    python benchmarks/startup.py --data ../shared/data --out docs/results/startup.json
    python benchmarks/startup.py --docs        # the table in docs/contributing.md, from that JSON
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common import write_json
from kartpilot.cli.main import build_parser
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "contributing.md"
MARKER = "startup"
VENUE_FRAMES = Path("rdw-kart") / "lelystad-2024" / "frames"
LIMITS_S = {"kartpilot --help": 0.5, "kartpilot lanes --help": 0.5, "kartpilot lanes IMAGE --out X.csv": 1.2}
"""What issue 52 asks of a 2-core machine."""


def subcommands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every leaf subcommand of the CLI, as its words."""
    found: list[tuple[str, ...]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += subcommands(sub, (*prefix, name))
    return found or [prefix]


def time_process(argv: list[str], repeats: int) -> list[float]:
    """Wall seconds of each of ``repeats`` runs of ``argv`` (which must succeed)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=300)
        times.append(time.perf_counter() - start)
    return times


def test_image(data: Path, folder: Path) -> tuple[Path, str]:
    """An 848x480 image for the jobs: the venue's first frame, or a grey road with two white lines."""
    frames = sorted((data / VENUE_FRAMES).glob("*.jpg")) if (data / VENUE_FRAMES).is_dir() else []
    if frames:
        return frames[0], f"the real kart's camera at the venue ({frames[0].name})"
    image = np.full((480, 848, 3), 90, np.uint8)
    image[:200] = (200, 170, 140)
    for x_far, x_near in ((380, 100), (470, 750)):
        cv2.line(image, (x_far, 200), (x_near, 479), (235, 235, 235), 6)
    path = folder / "road.png"
    cv2.imwrite(str(path), image)
    return path, "a drawn 848x480 road (the venue's frames were not found)"


def render(results: dict[str, Any]) -> str:
    """The docs' table, from the JSON :func:`main` writes."""
    rows = results["rows"]
    jobs = [r for r in rows if not r["command"].endswith("--help")]
    helps = [r for r in rows if r["command"].endswith("--help")]
    sub_helps = [r for r in helps if r["command"] != "kartpilot --help"]
    slowest = max(sub_helps, key=lambda r: r["median_s"])
    lines = [f"Whole processes on {results['machine']}, the median of {results['repeats']} runs each "
             f"(`benchmarks/startup.py`, {results['date']}); the image is {results['image']}:", "",
             "| command | median | fastest | slowest | asked |", "|---|---:|---:|---:|---:|"]
    for row in [r for r in helps if r["command"] in LIMITS_S] + jobs:
        limit = LIMITS_S.get(row["command"])
        lines.append(f"| `{row['command']}` | {row['median_s']:.2f} s | {min(row['times_s']):.2f} s | "
                     f"{max(row['times_s']):.2f} s | {f'{limit:g} s' if limit else ''} |")
    fastest = min(r["median_s"] for r in sub_helps)
    lines += ["", f"Every one of the {len(sub_helps)} subcommands' `--help` takes {fastest:.2f} to "
              f"{slowest['median_s']:.2f} s (the slowest: `{slowest['command']}`): the parser imports no handler.", ""]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--out", default="docs/results/startup.json")
    parser.add_argument("--docs", action="store_true", help="only put the table from --out into the docs")
    args = parser.parse_args()
    if args.docs:
        put_at_marker(PAGE, render(json.loads(Path(args.out).read_text(encoding="utf-8"))), MARKER)
        return 0
    exe = shutil.which("kartpilot", path=str(Path(sys.executable).parent)) or "kartpilot"
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        image, about = test_image(Path(args.data), Path(tmp))
        runs: list[tuple[str, list[str]]] = [("kartpilot --help", [exe, "--help"])]
        runs += [(f"kartpilot {' '.join(words)} --help", [exe, *words, "--help"])
                 for words in subcommands(build_parser())]
        runs += [("kartpilot lanes IMAGE --out X.csv", [exe, "lanes", str(image), "--out", f"{tmp}/lanes.csv"]),
                 ("kartpilot detect IMAGE --out X.csv", [exe, "detect", str(image), "--out", f"{tmp}/objects.csv"])]
        for name, argv in runs:
            times = time_process(argv, args.repeats)
            rows.append({"command": name, "median_s": statistics.median(times), "times_s": times})
            print(f"{name}: {statistics.median(times):.3f} s")
    result = {"machine": f"{os.cpu_count()} cores, {sys.platform}, Python {sys.version.split()[0]}",
              "date": time.strftime("%Y-%m-%d"), "repeats": args.repeats, "image": about, "rows": rows}
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

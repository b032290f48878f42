"""Render ``vo_accuracy.py``'s JSON as a Markdown table, and put it into documents between markers.

    python benchmarks/vo_table.py docs/results/vo_accuracy.json --out docs/results/vo_accuracy.md --into README.md

``--into`` replaces what lies between ``<!-- vo-accuracy -->`` and ``<!-- /vo-accuracy -->`` in each file, so
the numbers in the docs are always the measured ones.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

START, END = "<!-- vo-accuracy -->", "<!-- /vo-accuracy -->"


def _number(value: Any, digits: int, unit: str = "") -> str:
    return "-" if value is None else f"{value:.{digits}f}{unit}"


def _rotation(row: dict[str, Any]) -> str:
    if row.get("end_rotation_deg") is None:
        return "-"
    return f"{row['end_rotation_deg']:.2f}° ({row['end_rotation_deg_per_m']:.3f}°/m)"


def render(results: dict[str, Any]) -> str:
    """The table, with the date, the machine and what each column means (the end rotation's column where the
    results measured it)."""
    machine = results["machine"]
    rotation = any("end_rotation_deg" in row for row in results["rows"])
    lines = [
        f"Measured on {results['date']} on a {machine['cpus']}-core {machine['processor']} machine (no GPU), "
        f"Python {machine['python']}, OpenCV {machine['opencv']}, {results['configuration']} configuration, "
        "by `benchmarks/vo_accuracy.py`. *Tuned on*: the defaults were set on this sequence; every other row "
        "is held out. Drift is the end point's error over the distance driven; "
        + ("end rotation the angle between the estimated and true final orientations (and per metre driven); "
           if rotation else "")
        + "ATE after an SE(3) alignment; RPE over 1 m.",
        "",
        "| sequence | kind | VO | | frames | distance | end drift | " + ("end rotation | " if rotation else "")
        + "ATE | RPE 1 m | bridged | frames/s | note |",
        "|---|---|---|---|---:|---:|---:|" + ("---:|" if rotation else "") + "---:|---:|---:|---:|---|",
    ]
    for row in results["rows"]:
        note = row["note"]
        if "stereo_over_mono_distance" in row:
            note += f"; stereo / mono distance {row['stereo_over_mono_distance']:.3f}"
        if "excursion_m" in row:
            note += f": {row['excursion_m'] * 1000:.1f} mm"
        rpe = (row.get("rpe_percent") or {}).get("1m")
        lines.append(
            f"| {row['name']} | {row['kind']} | {row['mode']} | {'tuned on' if row['tuned_on'] else 'held out'} "
            f"| {row['frames']} | {_number(row['distance_m'], 1, ' m')} "
            f"| {_number(row.get('end_drift_percent'), 2, ' %')} " + (f"| {_rotation(row)} " if rotation else "")
            + f"| {_number(row.get('ate_rmse_m'), 3, ' m')} "
            f"| {_number(rpe, 2, ' %')} | {row['bridged_frames']} | {_number(row['frames_per_second'], 0)} "
            f"| {note} |")
    return "\n".join(lines) + "\n"


def put_between_markers(path: Path, table: str, start_marker: str = START, end_marker: str = END) -> None:
    text = path.read_text(encoding="utf-8")
    start, end = text.find(start_marker), text.find(end_marker)
    if start < 0 or end < start:
        raise SystemExit(f"{path}: no {start_marker} ... {end_marker} markers to put the table between")
    path.write_text(text[:start + len(start_marker)] + "\n" + table + text[end:], encoding="utf-8")
    print(f"updated {path}")


def put_at_marker(path: Path, text: str, name: str) -> None:
    """:func:`put_between_markers` with the markers every page uses: ``<!-- name -->`` and ``<!-- /name -->``."""
    put_between_markers(path, text, f"<!-- {name} -->", f"<!-- /{name} -->")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", help="the JSON vo_accuracy.py wrote")
    parser.add_argument("--out", help="write the table to this Markdown file")
    parser.add_argument("--into", nargs="*", default=[], help="documents whose marked section to replace")
    args = parser.parse_args()
    table = render(json.loads(Path(args.results).read_text(encoding="utf-8")))
    if args.out:
        Path(args.out).write_text(table, encoding="utf-8")
        print(f"wrote {args.out}")
    for path in args.into:
        put_between_markers(Path(path), table)
    if not args.out and not args.into:
        print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

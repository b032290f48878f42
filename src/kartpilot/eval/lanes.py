"""Scoring the lane finder against a team's own labelled frames: boundary points placed by hand, and how far the
boundary the finder reports lies from each, along its row.

The labels are read from (:func:`read_lane_labels`):

- **a CSV** of boundary points, a point per line: ``image,side,row,x`` (a header line with those names; ``side`` is
  ``left`` or ``right``, the ego lane's boundary; ``row`` and ``x`` in the image's pixels; ``image`` the path
  relative to the frames' folder). Any spreadsheet, or a point tool that exports clicks, writes it.
- **kartpilot JSON**: ``{"frames": {"IMAGE": {"left": [[row, x], ...], "right": [...]}}}`` (the venue's truth in
  ``tests/data/rdw_lelystad_lane_truth.json`` is one).

A point is met where the finder detected that side (not an image edge it fell back on) and its boundary crosses
the point's row within ``within_px`` of it; the error of a side not found is infinite.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kartpilot.core.errors import DataError
from kartpilot.core.files import csv_records, parse_json, read_text_file
from kartpilot.perception.lanes import LaneObservation

__all__ = ["LaneScore", "boundary_errors", "read_lane_labels", "score_lanes"]

SIDES = ("left", "right")
LanePoints = dict[str, list[tuple[float, float]]]
"""One image's labelled points: by side, each (row, x) in pixels."""


def boundary_errors(observation: LaneObservation, points: Mapping[str, Sequence[Sequence[float]]]
                    ) -> list[tuple[str, float, float]]:
    """Each labelled point's (side, row, error in pixels along its row): where the finder's boundary of that side
    (its curve where it has one) crosses the row, against the point; infinite where the side was not detected."""
    errors = []
    for side in SIDES:
        curve = getattr(observation, f"{side}_curve")
        line = getattr(observation, side)
        found = getattr(observation, f"{side}_source") == "detected"
        for row, x in points.get(side, []):
            at = (float(curve.x_at(row)) if curve is not None else float(line.x_at(row))) if found else math.inf
            errors.append((side, float(row), abs(at - x)))
    return errors


@dataclass
class LaneScore:
    """What :func:`score_lanes` measured: every point's error, by image, and the summaries."""

    within_px: float
    errors: dict[str, list[tuple[str, float, float]]] = field(default_factory=dict)
    both_found: int = 0

    @property
    def points(self) -> int:
        return sum(len(e) for e in self.errors.values())

    def share_within(self, rows: tuple[float, float] = (-math.inf, math.inf)) -> float:
        values = [e for errs in self.errors.values() for _, r, e in errs if rows[0] <= r < rows[1]]
        return float(np.mean(np.asarray(values) <= self.within_px)) if values else math.nan

    def median_px(self) -> float:
        values = [e for errs in self.errors.values() for _, _, e in errs]
        return float(np.median(values)) if values else math.nan

    def by_row(self) -> list[dict[str, Any]]:
        """Per labelled row: the points, the share within ``within_px``, the median error."""
        rows: dict[float, list[float]] = {}
        for errs in self.errors.values():
            for _, row, error in errs:
                rows.setdefault(row, []).append(error)
        return [{"row_px": row, "points": len(values), "within": float(np.mean(np.asarray(values) <= self.within_px)),
                 "median_px": float(np.median(values))} for row, values in sorted(rows.items())]

    def to_json(self) -> dict[str, Any]:
        finite = lambda v: v if math.isfinite(v) else None  # noqa: E731 (JSON has no infinity)
        return {"images": len(self.errors), "both_found": self.both_found, "points": self.points,
                "within_px": self.within_px, "share_within": finite(self.share_within()),
                "median_px": finite(self.median_px()),
                "by_row": [{k: finite(v) if isinstance(v, float) else v for k, v in r.items()} for r in self.by_row()],
                "errors": {name: [[side, row, finite(e)] for side, row, e in errs]
                           for name, errs in self.errors.items()}}

    def table(self) -> str:
        """A Markdown table: per labelled row, then all."""
        lines = [f"| row (px) | points | within {self.within_px:g} px | median error |", "|---:|---:|---:|---:|"]
        for r in self.by_row():
            lines.append(f"| {r['row_px']:g} | {r['points']} | {100 * r['within']:.0f} % | {r['median_px']:.1f} px |")
        lines.append(f"| all | {self.points} | {100 * self.share_within():.0f} % | {self.median_px():.1f} px |")
        return "\n".join(lines)


def score_lanes(observations: Mapping[str, LaneObservation], labels: Mapping[str, LanePoints],
                within_px: float = 25.0) -> LaneScore:
    """Each labelled image's points against the finder's observation of it (by the labels' image names)."""
    score = LaneScore(within_px)
    for name, points in labels.items():
        observation = observations[name]
        score.errors[name] = boundary_errors(observation, points)
        score.both_found += int(observation.both_detected)
    return score


def _number(text: Any, where: str) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise DataError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise DataError(f"{where}: {text!r} is not a finite number")
    return value


def _from_csv(text: str, path: Path) -> dict[str, LanePoints]:
    records = csv_records(text)
    fields = list(records[0]) if records else text.splitlines()[0].split(",") if text.strip() else []
    wanted = {"image", "side", "row", "x"}
    if not wanted <= {str(f).strip() for f in fields if f is not None}:
        raise DataError(f"{path}: a lane label CSV starts with the header image,side,row,x (got "
                        f"{','.join(str(f) for f in fields if f is not None)})")
    labels: dict[str, LanePoints] = {}
    for n, line in enumerate(records, start=2):
        where = f"{path}, line {n}"
        row = {k.strip(): (v or "").strip() for k, v in line.items() if k is not None}
        side = row["side"].lower()
        if side not in SIDES:
            raise DataError(f"{where}: side {row['side']!r}; left or right")
        if not row["image"]:
            raise DataError(f"{where}: no image named")
        labels.setdefault(row["image"], {}).setdefault(side, []).append(
            (_number(row["row"], where), _number(row["x"], where)))
    return labels


def _from_json(text: str, path: Path) -> dict[str, LanePoints]:
    try:
        frames = parse_json(text, path)["frames"]
    except (DataError, KeyError, TypeError):
        raise DataError(f"{path}: lane labels in JSON are {{\"frames\": {{IMAGE: {{\"left\": [[row, x], ...], "
                        "\"right\": [...]}}}") from None
    labels: dict[str, LanePoints] = {}
    for name, sides in frames.items():
        where = f"{path}: {name}"
        if not isinstance(sides, dict) or not set(sides) <= set(SIDES):
            raise DataError(f"{where}: each image maps left and right to their points")
        labels[str(name)] = {side: [(_number(p[0], where), _number(p[1], where)) for p in points]
                             for side, points in sides.items()}
    return labels


def read_lane_labels(path: str | Path) -> dict[str, LanePoints]:
    """The boundary points in ``path`` (a CSV or kartpilot JSON, by its suffix), by image name."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"lane labels not found: {path}" if not path.exists() else f"{path} is not a file")
    text = read_text_file(path)
    labels = _from_json(text, path) if path.suffix.lower() == ".json" else _from_csv(text, path)
    if not labels:
        raise DataError(f"{path}: no labelled point")
    return labels

"""Place recognition against ground truth: Recall@K within a radius, as in the retrieval literature.

A query counts for Recall@K when one of its K nearest database places (by VLAD distance) lies
within ``radius_m`` of where the query image was truly taken. Recall@1 after the geometric check
takes the place the check ranked best instead, and counts a rejected query as a miss. The
position error is that of the combined fix, over the accepted queries; its part across the track
(along the true camera's x axis) and the heading error (the angle between the fix's and the true
camera's orientation) are also given over the fixes registered on the road. Along the track (the true
camera's z axis) the error is set against the fix's own standard deviation there: a fix that says it
is good to half a metre and is two metres off is worse than one that admits it is ambiguous.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np

from kartpilot.core.errors import EvaluationError
from kartpilot.core.geometry import Array
from kartpilot.core.types import Image
from kartpilot.odometry.places import PlaceDatabase, PlaceFix

__all__ = ["PlaceRecall", "evaluate_places", "recall_at_k"]


def recall_at_k(truth_xyz: Array, retrieved_xyz: Array, k: int, radius_m: float) -> float:
    """The share of queries with one of their first ``k`` retrieved positions within ``radius_m`` of the
    truth. ``truth_xyz`` is ``(N, 3)``, ``retrieved_xyz`` ``(N, K, 3)`` with NaN where nothing was retrieved."""
    if len(truth_xyz) == 0:
        raise EvaluationError("no queries to measure recall on")
    with np.errstate(invalid="ignore"):
        distances = np.linalg.norm(retrieved_xyz[:, :k] - truth_xyz[:, None], axis=2)
    return float(np.mean(np.any(distances <= radius_m, axis=1)))


@dataclass(frozen=True)
class PlaceRecall:
    """How well a database places a run's images."""

    queries: int
    radius_m: float
    recall_at_1: float
    recall_at_5: float
    checked_recall_at_1: float
    accepted: float
    median_error_m: float
    p90_error_m: float
    median_along_error_m: float
    p90_along_error_m: float
    along_within_2_sigma: float
    registered: float
    median_cross_track_error_m: float
    p90_cross_track_error_m: float
    median_heading_error_deg: float
    p90_heading_error_deg: float
    ms_per_query: float

    def to_json(self) -> dict[str, float | int]:
        return {k: round(v, 4) if isinstance(v, float) else v for k, v in asdict(self).items()}

    def table(self) -> str:
        return "\n".join([
            f"queries              {self.queries}",
            f"Recall@1 (VLAD)      {100 * self.recall_at_1:.1f} %   within {self.radius_m:g} m",
            f"Recall@5 (VLAD)      {100 * self.recall_at_5:.1f} %",
            f"Recall@1 (checked)   {100 * self.checked_recall_at_1:.1f} %   after the geometric check",
            f"accepted             {100 * self.accepted:.1f} %",
            f"fix error            median {self.median_error_m:.2f} m, 90 % {self.p90_error_m:.2f} m",
            f"  along the track    median {self.median_along_error_m:.2f} m, 90 % {self.p90_along_error_m:.2f} m; "
            f"{100 * self.along_within_2_sigma:.1f} % within twice the fix's own sigma",
            f"registered on road   {100 * self.registered:.1f} %",
            f"  across the track   median {self.median_cross_track_error_m:.3f} m, "
            f"90 % {self.p90_cross_track_error_m:.3f} m",
            f"  heading            median {self.median_heading_error_deg:.2f} deg, "
            f"90 % {self.p90_heading_error_deg:.2f} deg",
            f"time                 {self.ms_per_query:.1f} ms per query",
        ])


def evaluate_places(database: PlaceDatabase, queries: Iterable[tuple[int, Image, Array]], radius_m: float = 2.0,
                    fixes: list[PlaceFix] | None = None) -> PlaceRecall:
    """Recall of ``database`` on ``(stamp_ns, image, true pose_world_cam)`` queries (the truth in the database's
    frame). The fixes are appended to ``fixes`` when a list is given."""
    truth: list[Array] = []
    retrieved: list[Array] = []
    checked: list[Array] = []
    errors: list[float] = []
    across: list[float] = []
    heading: list[float] = []
    along: list[float] = []
    honest = 0
    accepted = 0
    elapsed = 0.0
    width = max(5, database.config.top_k)
    for stamp_ns, image, pose in queries:
        start = time.perf_counter()
        fix = database.locate(image, stamp_ns)
        elapsed += time.perf_counter() - start
        if fixes is not None:
            fixes.append(fix)
        position = np.asarray(pose, float)[:3, 3]
        rotation = np.asarray(pose, float)[:3, :3]
        truth.append(position)
        row = np.full((width, 3), np.nan)
        found = database.positions_m[list(fix.candidates[:width])]
        row[:len(found)] = found
        retrieved.append(row)
        checked.append(database.positions_m[fix.place] if fix.accepted else np.full(3, np.nan))
        if fix.accepted:
            accepted += 1
            errors.append(float(np.linalg.norm(fix.position_m - position)))
            along.append(abs(float((rotation.T @ (fix.position_m - position))[2])))
            honest += along[-1] <= 2 * fix.sigma_m
        if fix.registered:
            across.append(abs(float((rotation.T @ (fix.position_m - position))[0])))
            turn = fix.pose_world_cam[:3, :3].T @ rotation
            heading.append(float(np.degrees(np.arccos(np.clip((np.trace(turn) - 1) / 2, -1.0, 1.0)))))
    t = np.array(truth).reshape(-1, 3)
    if len(t) == 0:
        raise EvaluationError("no query image had a true pose")
    r = np.array(retrieved)
    error, cross, turned, ahead = (np.array(v) if v else np.array([np.nan]) for v in (errors, across, heading, along))
    return PlaceRecall(len(t), radius_m, recall_at_k(t, r, 1, radius_m), recall_at_k(t, r, 5, radius_m),
                       recall_at_k(t, np.array(checked)[:, None], 1, radius_m), accepted / len(t),
                       float(np.median(error)), float(np.percentile(error, 90)), float(np.median(ahead)),
                       float(np.percentile(ahead, 90)), honest / accepted if accepted else float("nan"),
                       len(across) / len(t),
                       float(np.median(cross)), float(np.percentile(cross, 90)), float(np.median(turned)),
                       float(np.percentile(turned, 90)), 1e3 * elapsed / len(t))

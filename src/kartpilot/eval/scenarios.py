"""Scoring many scenario events: the pass rate per scenario with its interval, and why each failure happened.

A scenario's referee says what went wrong (a fault); the rules' own record of the drive (each change of their state
and of the limit they held, ``result["states"]``) says where in the chain it went wrong:

- **not seen**: the rules never entered the state the fault's object calls for (no ``stop_red`` before a red
  light's fault, no lower limit before a speeding fault, no ``yield`` at the crossing, no ``overtake`` or
  ``park``, no green at the start);
- **seen late**: they entered it, too late to keep the rule (passed the line on red after ``stop_red``, still over
  the limit after lowering it, still rolling at the crossing after ``yield``);
- **wrong decision**: they saw it and decided wrongly (left before green, never went on at green or after the
  pedestrian);
- **controller**: the decision was right and the kart did not carry it out (stopped too near or too far from the
  line, touched the car or a barrier, not back in the lane, not wholly in the bay, a line touched);
- **seen what is not there**: the rules entered a state for an object the scenario does not hold (a red light's
  stop in a scenario without a light, a yield without a person): every fault of that event is put down to it
  (the result's ``kinds``, the kinds of its props, tell).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["CAUSES", "failure_causes", "mount_pitch_recovered", "pass_rate", "phantom_states", "sweep_summary"]

CAUSES = ("not seen", "seen late", "wrong decision", "controller", "seen what is not there")

_OBJECT_OF_STATE = {"stop_red": "traffic_light", "wait_red": "traffic_light", "yield": "person",
                    "overtake": "car", "wait_car": "car", "park": "barrier", "parked": "barrier"}


def _visited(result: Mapping[str, Any], *states: str) -> bool:
    return any(row[1] in states for row in result.get("states", ()))


def _lowered(result: Mapping[str, Any]) -> bool:
    limits = [row[2] for row in result.get("states", ()) if isinstance(row[2], (int, float)) and
              math.isfinite(row[2])]
    return bool(limits) and min(limits) < limits[0]


def failure_causes(result: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Each fault of a scenario's result with its cause (:data:`CAUSES`)."""
    kinds = result.get("kinds")
    if kinds is not None and phantom_states(result, kinds):
        return [(fault, "seen what is not there") for fault in result.get("faults", ())]
    out = []
    for fault in result.get("faults", ()):
        if fault.startswith("left before green"):
            cause = "wrong decision"
        elif fault.startswith("did not start on green"):
            cause = "not seen"
        elif fault.startswith("over the limit"):
            cause = "seen late" if _lowered(result) else "not seen"
        elif fault.startswith(("passed the line on red", "did not stop at the red light")):
            cause = "seen late" if _visited(result, "stop_red", "wait_red") else "not seen"
        elif fault.startswith(("did not go on at green", "did not go on after the pedestrian")):
            cause = "wrong decision"
        elif fault.startswith("moved at the crossing"):
            cause = "seen late" if _visited(result, "yield") else "not seen"
        elif fault.startswith(("did not pass the car", "touched the car")):
            cause = "controller" if _visited(result, "overtake") else "not seen"
        elif fault.startswith(("touched the barrier", "did not end wholly inside the bay", "did not stop in the bay")):
            cause = "controller" if _visited(result, "park", "parked") else "not seen"
        else:  # stopped at the wrong place, not back in the lane, the track's own referee (a line touched)
            cause = "controller"
        out.append((fault, cause))
    return out


def phantom_states(result: Mapping[str, Any], kinds: Iterable[str]) -> list[str]:
    """The rules' states of a result that answer an object the scenario does not hold (``kinds``: its props'
    kinds, and ``barrier`` for a bay)."""
    held = set(kinds)
    return [row[1] for row in result.get("states", ()) if row[1] in _OBJECT_OF_STATE
            and _OBJECT_OF_STATE[row[1]] not in held]


def pass_rate(passed: int, total: int, z: float = 1.96) -> tuple[float, float, float]:
    """The share passed and its Wilson score interval (95 % by default): honest at 0 and at all passed."""
    if total <= 0:
        return math.nan, 0.0, 1.0
    p = passed / total
    centre = (p + z * z / (2 * total)) / (1 + z * z / total)
    half = z * math.sqrt(p * (1 - p) / total + z * z / (4 * total * total)) / (1 + z * z / total)
    return p, max(0.0, centre - half), min(1.0, centre + half)


def sweep_summary(rows: Iterable[Mapping[str, Any]], scenarios: Sequence[str]) -> dict[str, Any]:
    """Per scenario: events, passed, the pass rate and its interval; every failure with its causes; the causes
    counted per scenario; the camera's pitch as measured against the mount's (:func:`mount_pitch_recovered`)."""
    by: dict[str, list[Mapping[str, Any]]] = {name: [] for name in scenarios}
    failures = []
    for row in rows:
        by.setdefault(row["scenario"], []).append(row)
        if not row.get("passed", False):
            failures.append({"scenario": row["scenario"], "seed": row["seed"], "file": row.get("file", ""),
                             "faults": [{"fault": f, "cause": c} for f, c in failure_causes(row)]
                             or [{"fault": row.get("error", "no result"), "cause": "error"}]})
    table = {}
    for name, mine in by.items():
        passed = sum(1 for row in mine if row.get("passed", False))
        rate, low, high = pass_rate(passed, len(mine))
        causes = Counter(item["cause"] for failure in failures if failure["scenario"] == name
                         for item in failure["faults"])
        table[name] = {"events": len(mine), "passed": passed, "pass_rate": rate, "interval": [low, high],
                       "causes": dict(causes)}
    return {"scenarios": table, "failures": failures, "pitch": mount_pitch_recovered(
        [row for mine in by.values() for row in mine])}


def mount_pitch_recovered(rows: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """How well the lanes measured the camera's pitch: over the events that carry both the mount's true pitch
    off the rig (``mount_pitch_deg``) and the measured one (``pitch_off_deg``; exactly 0 where the drive never
    measured it and kept the rig's mount), the median and the largest error left, against the error that was there
    (the mount's own); over all events and over those measured."""
    pairs = [(float(row["mount_pitch_deg"]), float(row["pitch_off_deg"])) for row in rows
             if "mount_pitch_deg" in row and "pitch_off_deg" in row]
    if not pairs:
        return {"events": 0}
    true, measured = np.array(pairs).T
    left = np.abs(measured - true)
    seen = measured != 0.0
    return {"events": len(pairs), "median_off_deg": float(np.median(np.abs(true))), "max_off_deg":
            float(np.max(np.abs(true))), "median_error_deg": float(np.median(left)), "max_error_deg":
            float(np.max(left)), "measured_share": float(np.mean(seen)),
            "measured_median_error_deg": float(np.median(left[seen])) if seen.any() else math.nan,
            "measured_max_error_deg": float(np.max(left[seen])) if seen.any() else math.nan}

"""Scenario sweeps: many events, each a built-in scenario on its own seed varied as the day may
(:mod:`kartpilot.sim.variation`), run as study cells on Ray (locally or on a cluster, each row cached by its
cell's hash, :class:`kartpilot.study.run.CellRunner`), scored per scenario with the failures' causes
(:mod:`kartpilot.eval.scenarios`), and every failure written as the scenario file that reproduces it."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kartpilot.core.config import config_to_dict
from kartpilot.core.errors import ConfigError
from kartpilot.core.files import write_text_atomic
from kartpilot.eval.scenarios import sweep_summary
from kartpilot.runtime.config import load_stack_config
from kartpilot.sim.scenarios import SCENARIOS
from kartpilot.sim.variation import DayRanges
from kartpilot.study.run import CellRunner, study_context
from kartpilot.study.spec import Cell, cell_key

__all__ = ["SINGLE_SCENARIOS", "SweepRun", "run_sweep", "sweep_cells"]

SINGLE_SCENARIOS = tuple(name for name in SCENARIOS if name != "event")
"""The six scenarios a sweep draws its events from (the ``event`` course holds them all, four minutes a drive)."""


@dataclass(frozen=True)
class SweepRun:
    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    computed: int
    cached: int
    wall_s: float
    cpus: float


MAX_SWEEP_EVENTS = 20_000
"""The most events one sweep runs: 20,000 drives are about two weeks of one core."""


def sweep_cells(events: int, first_seed: int, ranges: DayRanges | None = None,
                scenarios: Sequence[str] = SINGLE_SCENARIOS) -> list[Cell]:
    """``events`` cells: seeds ``first_seed`` on, the scenarios in turn; the stack is the scenarios' own (the kart
    preset)."""
    unknown = [name for name in scenarios if name not in SCENARIOS]
    if unknown or events < 1:
        raise ConfigError(f"a sweep needs at least one event of known scenarios, got {events} of {list(scenarios)}")
    if events > MAX_SWEEP_EVENTS:
        raise ConfigError(f"a sweep of {events} events: at most {MAX_SWEEP_EVENTS} (each is a closed-loop drive of "
                          "a minute on one core; split it by --first-seed)")
    stack = config_to_dict(load_stack_config(None, "kart"))
    variation = config_to_dict(ranges or DayRanges())
    cells = []
    for k in range(events):
        name, seed = scenarios[k % len(scenarios)], first_seed + k
        params = {"scenario": name, "variation": variation}
        cells.append(Cell("scenario-sweep", "events", "scenario", "varied", name, "lelystad", seed, params, stack,
                          cell_key("scenario", "lelystad", seed, params, stack)))
    return cells


def run_sweep(out: str | Path, events: int, first_seed: int, ranges: DayRanges | None = None,
              scenarios: Sequence[str] = SINGLE_SCENARIOS, address: str | None = None, cpus: int | None = None,
              progress: bool = False) -> SweepRun:
    """Run (or complete) a sweep into ``out``: the rows in ``out/cells``, each failure's scenario file in
    ``out/failures/<scenario>-<seed>.yaml`` (``kartpilot sim --scenario FILE`` drives it again)."""
    out = Path(out)
    start = time.perf_counter()
    cells = sweep_cells(events, first_seed, ranges, scenarios)
    with CellRunner(out, study_context(out, out, None), address, cpus, progress) as runner:
        by_key = runner.run(cells)
        cpus_used = runner.cluster_cpus
    rows = []
    for cell in cells:
        row = dict(by_key[cell.key])
        row.setdefault("scenario", cell.params["scenario"])
        if not row.get("passed", False) and row.get("scenario_file"):
            path = out / "failures" / f"{row['scenario']}-{cell.seed}.yaml"
            path.parent.mkdir(parents=True, exist_ok=True)
            write_text_atomic(path, row["scenario_file"])
            row["file"] = str(path)
        rows.append(row)
    return SweepRun(rows, sweep_summary(rows, scenarios), runner.computed, runner.cached,
                    time.perf_counter() - start, cpus_used)

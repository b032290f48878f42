"""``kartpilot study tune``: search a study's space with Optuna, each trial's cells as Ray tasks, and report
the best settings on held-out seeds and tracks, never on the ones they were tuned on.

A spec's ``tune`` section::

    tune:
      part: path follower           # whose job, parameters and base configuration the trials use
      space:                        # dotted stack keys: [low, high] or [low, high, log]
        drive.follow.stanley.k_heading: [0.1, 2.0]
        drive.follow.stanley.k_cross_track: [0.2, 5.0, log]
      minimize: {max_offset_m: 1.0, steer_rate_rms_radps: 0.05}   # a weighted sum, the mean over the cells
      failure_penalty: 1.0          # added for each failed run (a touch, a crash)
      tune_on: {sources: [utrack], seeds: [1, 2]}
      held_out: {sources: [utrack, sdc-assen], seeds: [3, 4, 5]}
      trials: 40
      quick: {trials: 12}

Trials are asked in batches as wide as the cluster (Optuna's TPE sampler, seeded), so the search uses every
worker. The best trial and the defaults are then run on the held-out cells, and both are reported; the best
settings are written as a stack YAML file to pass to ``--config``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from kartpilot.core.config import merge_config
from kartpilot.core.errors import ConfigError
from kartpilot.core.files import write_json_atomic, write_text_atomic
from kartpilot.runtime.config import StackConfig
from kartpilot.study.report import estimate
from kartpilot.study.run import CellRunner, study_context
from kartpilot.study.spec import Cell, Part, StudySpec, Variant, dotted_overrides, nested_override, part_cells

__all__ = ["TuneResult", "TuneSpec", "parse_tune", "tune_page", "tune_study"]


@dataclass(frozen=True)
class Dimension:
    key: str
    low: float
    high: float
    log: bool


@dataclass(frozen=True)
class TuneSpec:
    part: Part
    space: tuple[Dimension, ...]
    minimize: Mapping[str, float]
    failure_penalty: float
    tune_sources: tuple[str, ...]
    tune_seeds: tuple[int, ...]
    held_sources: tuple[str, ...]
    held_seeds: tuple[int, ...]
    trials: int
    quick_trials: int


@dataclass(frozen=True)
class TuneResult:
    best_params: dict[str, float]
    best_value: float
    trials: int
    held_out: dict[str, dict[str, float]]
    wall_s: float


def _names_and_seeds(data: Any, where: str) -> tuple[tuple[str, ...], tuple[int, ...]]:
    if not isinstance(data, Mapping) or not data.get("sources") or not data.get("seeds"):
        raise ConfigError(f"study key 'tune.{where}' needs 'sources' and 'seeds'")
    return tuple(str(s) for s in data["sources"]), tuple(int(s) for s in data["seeds"])


def parse_tune(spec: StudySpec) -> TuneSpec:
    data = dict(spec.tune)
    if not data:
        raise ConfigError(f"study {spec.name} has no 'tune' section")
    known = {"part", "space", "minimize", "failure_penalty", "tune_on", "held_out", "trials", "quick"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"unknown study key 'tune.{unknown[0]}' (known here: {', '.join(sorted(known))})")
    parts = {p.name: p for p in spec.parts}
    part = parts.get(str(data.get("part", spec.parts[0].name)))
    if part is None:
        raise ConfigError(f"study key 'tune.part' must name a part ({', '.join(parts)})")
    space = []
    for key, bounds in dict(data.get("space") or {}).items():
        if not isinstance(bounds, list) or len(bounds) not in (2, 3) or not bounds[0] < bounds[1] \
                or (len(bounds) == 3 and bounds[2] != "log") or (len(bounds) == 3 and bounds[0] <= 0):
            raise ConfigError(f"study key 'tune.space.{key}' must be [low, high] or [low, high, log] (low > 0)")
        merge_config(StackConfig(), nested_override(key, float(bounds[0])), "tune.space")  # the key must exist
        space.append(Dimension(key, float(bounds[0]), float(bounds[1]), len(bounds) == 3))
    if not space:
        raise ConfigError("study key 'tune.space' must list at least one dotted key")
    minimize = {str(k): float(v) for k, v in dict(data.get("minimize") or {}).items()}
    if not minimize:
        raise ConfigError("study key 'tune.minimize' must weigh at least one metric")
    tune_sources, tune_seeds = _names_and_seeds(data.get("tune_on"), "tune_on")
    held_sources, held_seeds = _names_and_seeds(data.get("held_out"), "held_out")
    if set(tune_seeds) & set(held_seeds):
        raise ConfigError(f"tune.held_out.seeds must differ from tune.tune_on.seeds (both have "
                          f"{sorted(set(tune_seeds) & set(held_seeds))})")
    trials = int(data.get("trials", 30))
    quick = dict(data.get("quick") or {})
    return TuneSpec(part, tuple(space), minimize, float(data.get("failure_penalty", 1.0)), tune_sources, tune_seeds,
                    held_sources, held_seeds, trials, int(quick.get("trials", max(4, trials // 4))))


def _cells(study: str, tune: TuneSpec, variant: str, params: Mapping[str, float], sources: Sequence[str],
           seeds: Sequence[int], quick: bool) -> list[Cell]:
    return part_cells(study, tune.part, Variant(variant, dotted_overrides(params), "tune"), sources, seeds, quick)


def _failed(row: Mapping[str, Any]) -> bool:
    """A run that failed: the cell itself, or the drive (off the track, a touch)."""
    return row.get("status") != "ok" or row.get("success") is False or row.get("touched") is True


def objective(rows: Sequence[Mapping[str, Any]], tune: TuneSpec) -> float:
    """The weighted metrics' mean over the cells, plus the penalty for each run that failed."""
    total = 0.0
    for row in rows:
        for metric, weight in tune.minimize.items():
            value = row.get(metric)
            total += weight * (float(value) if isinstance(value, (int, float)) and math.isfinite(value) else 0.0)
        total += tune.failure_penalty * _failed(row)
    return total / max(len(rows), 1)


def _summary(rows: Sequence[Mapping[str, Any]], tune: TuneSpec) -> dict[str, float]:
    out = {"objective": objective(rows, tune), "runs": float(len(rows)),
           "failed_runs": float(sum(map(_failed, rows)))}
    for metric in tune.minimize:
        values = [float(r[metric]) for r in rows if isinstance(r.get(metric), (int, float))]
        out[metric] = sum(values) / len(values) if values else math.nan
    return out


def tune_study(spec: StudySpec, out: str | Path, data_dir: str | Path, quick: bool = False,
               address: str | None = None, cpus: int | None = None, trials: int | None = None,
               progress: bool = False) -> TuneResult:
    """Search, then compare the best trial with the defaults on the held-out cells; writes ``tune.json``,
    ``best.yaml`` and ``tune.md`` into ``out``."""
    import optuna

    tune = parse_tune(spec)
    out = Path(out)
    count = trials or (tune.quick_trials if quick else tune.trials)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    search = optuna.create_study(direction="minimize", sampler=optuna.samplers.TPESampler(seed=0))
    history: list[dict[str, Any]] = []
    start = time.perf_counter()
    with CellRunner(out, study_context(out, data_dir, None), address, cpus, progress) as runner:
        write_json_atomic(out / "study.json", {"name": spec.name, "title": spec.title, "tune": True,
                                               "quick": quick, "code_version": runner.version})
        per_trial = len(tune.tune_sources) * len(tune.tune_seeds)
        width = max(1, round(runner.start() / per_trial))  # trials at once: enough cells for every CPU
        while len(history) < count:
            batch = [search.ask() for _ in range(min(width, count - len(history)))]
            chosen = [{d.key: trial.suggest_float(d.key, d.low, d.high, log=d.log) for d in tune.space}
                      for trial in batch]
            cells = [_cells(spec.name, tune, f"trial {t.number}", p, tune.tune_sources, tune.tune_seeds, quick)
                     for t, p in zip(batch, chosen, strict=True)]
            rows = runner.run([c for group in cells for c in group])
            for trial, params, group in zip(batch, chosen, cells, strict=True):
                value = objective([rows[c.key] for c in group], tune)
                search.tell(trial, value)
                history.append({"trial": trial.number, "params": params, "value": value})
        best = dict(search.best_params)
        defaults = {d.key: _default(d.key) for d in tune.space}
        held: dict[str, dict[str, float]] = {}
        per_run: dict[str, list[float]] = {}
        for name, params in (("defaults", defaults), ("tuned", best)):
            group = _cells(spec.name, tune, name, params, tune.held_sources, tune.held_seeds, quick)
            rows = runner.run(group)
            held[name] = _summary([rows[c.key] for c in group], tune)
            per_run[name] = [objective([rows[c.key]], tune) for c in group]  # the same runs, in the same order
        change = estimate(t - d for t, d in zip(per_run["tuned"], per_run["defaults"], strict=True))
        held["change"] = {"objective": change.mean, "half_width_95": change.half_width, "runs": float(change.n)}
    wall = time.perf_counter() - start
    result = TuneResult(best, float(search.best_value), len(history), held, wall)
    _write(out, spec, tune, result, history, defaults)
    return result


def _default(key: str) -> float:
    node: Any = StackConfig()
    for part in key.split("."):
        node = getattr(node, part)
    return float(node)


def _write(out: Path, spec: StudySpec, tune: TuneSpec, result: TuneResult, history: list[dict[str, Any]],
           defaults: dict[str, float]) -> None:
    data = {"study": spec.name, "title": spec.title, "part": tune.part.name, "minimize": dict(tune.minimize),
            "failure_penalty": tune.failure_penalty,
            "tuned_on": {"sources": list(tune.tune_sources), "seeds": list(tune.tune_seeds)},
            "held_out": {"sources": list(tune.held_sources), "seeds": list(tune.held_seeds)},
            "best_params": result.best_params, "best_value_tuned_on": result.best_value, "defaults": defaults,
            "held_out_results": result.held_out, "trials": history, "wall_s": result.wall_s}
    write_json_atomic(out / "tune.json", data)
    write_text_atomic(out / "best.yaml", "# kartpilot study tune: the best trial, for --config\n"
                      + yaml.safe_dump(dotted_overrides(result.best_params), sort_keys=True))
    write_text_atomic(out / "tune.md", tune_page(data))


def tune_page(data: Mapping[str, Any]) -> str:
    """The tuning's report, from its ``tune.json``."""
    held = {k: v for k, v in data["held_out_results"].items() if k != "change"}
    change = data["held_out_results"]["change"]
    metrics = list(next(iter(held.values())))
    weights = " + ".join(f"{w:g} × {m}" for m, w in data["minimize"].items())
    lines = [f"# Tuning: {data['title']}", "",
             f"{len(data['trials'])} Optuna trials (TPE) of part '{data['part']}', each on "
             f"{', '.join(data['tuned_on']['sources'])} seeds {data['tuned_on']['seeds']}, minimising the mean of "
             f"{weights}, plus {data['failure_penalty']:g} for each failed run. The best trial and the defaults "
             f"were then run on the held-out {', '.join(data['held_out']['sources'])} seeds "
             f"{data['held_out']['seeds']}: only those numbers compare them.", "",
             "| setting | defaults | tuned |", "|---|---|---|"]
    lines += [f"| {k} | {data['defaults'][k]:g} | {v:.3g} |" for k, v in data["best_params"].items()]
    lines += ["", "Held out (means over the held-out runs):", "", "| | " + " | ".join(metrics) + " |",
              "|---|" + "---|" * len(metrics)]
    for name, summary in held.items():
        lines.append(f"| {name} | " + " | ".join(f"{summary[m]:.4g}" for m in metrics) + " |")
    low, high = change["objective"] - change["half_width_95"], change["objective"] + change["half_width_95"]
    verdict = ("better beyond the interval: the tuning carries over" if high < 0 else
               "worse beyond the interval: keep the defaults" if low > 0 else
               "within the run-to-run spread: the tuning does not clearly carry over")
    lines += ["", f"On the held-out runs the tuned settings score {held['tuned']['objective']:.4g} against the "
              f"defaults' {held['defaults']['objective']:.4g}; paired run by run, the change is "
              f"{change['objective']:+.4g} ± {change['half_width_95']:.2g} (95 %), {verdict}."]
    return "\n".join(lines) + "\n"

"""Running a study's cells on Ray, locally or on a cluster, with every row cached by its cell's hash.

``run_study`` expands the spec into cells, keeps every row already computed by the same code for the same
cell hash (``DIR/cells/<hash>.json``), and submits the rest as Ray tasks of one CPU each. Without an
address Ray starts on this machine's cores and stops at the end; with one (``ray start --head`` on one
machine, ``ray start --address HEAD:6379`` on the others) the tasks spread over the cluster's CPUs. Each
row is written as soon as it arrives, so an interrupted study loses only the cells that were running.
A failed cell is stored with its error and run again by the next ``study run``.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from kartpilot.core.errors import ConfigError, DataError
from kartpilot.core.files import read_json_file, write_json_atomic
from kartpilot.study.jobs import JobContext, run_cell
from kartpilot.study.spec import Cell, StudySpec, code_version, expand_cells

__all__ = ["CellRunner", "StudyRun", "code_version", "load_rows", "run_study", "study_context"]


@dataclass(frozen=True)
class StudyRun:
    """What one ``study run`` did. ``computed`` cells ran now, ``cached`` ones were found."""

    rows: list[dict[str, Any]]
    computed: int
    cached: int
    failed: int
    wall_s: float
    cpus: float


def _cell_file(out: Path, key: str) -> Path:
    return out / "cells" / f"{key}.json"


def _stored(out: Path, key: str, version: str) -> dict[str, Any] | None:
    path = _cell_file(out, key)
    if not path.is_file():
        return None
    try:
        row = read_json_file(path)
    except DataError:
        return None  # a damaged cache file is computed again
    if row.get("status") != "ok" or row.get("code_version") != version:
        return None
    return dict(row)


@contextmanager
def _ray(address: str | None, cpus: int | None) -> Iterator[Any]:
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - ray is a dependency of the study extra
        raise ConfigError("studies run on Ray: pip install 'kartpilot[study]'") from exc
    options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                               "logging_level": logging.ERROR, "configure_logging": True}
    try:
        if address:
            ray.init(address=address, **options)
        else:
            ray.init(num_cpus=cpus or os.cpu_count() or 1, **options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise ConfigError(f"cannot reach the Ray cluster at {address}: {exc}" if address else
                          f"cannot start Ray on this machine: {exc}") from exc
    try:
        yield ray
    finally:
        ray.shutdown()


def _failed(cell: Cell, error: str) -> dict[str, Any]:
    return {**cell.labels(), "status": "failed", "error": error[:500], "cell_seconds": 0.0}


class CellRunner:
    """Rows for cells: from the cache in ``out/cells``, or computed as Ray tasks (Ray starts at the first
    cell that needs computing and stops with ``close``)."""

    def __init__(self, out: Path, context: JobContext, address: str | None = None, cpus: int | None = None,
                 progress: bool = False) -> None:
        self.out, self.context, self.address, self.cpus, self.progress = out, context, address, cpus, progress
        self.version = code_version()
        self.computed = self.cached = 0
        self.cluster_cpus = 0.0
        self._session = ExitStack()
        self._ray: Any = None
        (out / "cells").mkdir(parents=True, exist_ok=True)

    def __enter__(self) -> CellRunner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._session.close()
        self._ray = None

    def start(self) -> float:
        """Start (or join) Ray now; returns the cluster's CPUs."""
        if self._ray is None:
            self._ray = self._session.enter_context(_ray(self.address, self.cpus))
            self.cluster_cpus = float(self._ray.cluster_resources().get("CPU", 1.0))
        return self.cluster_cpus

    def run(self, cells: Sequence[Cell]) -> dict[str, dict[str, Any]]:
        """Each distinct cell's row, by key."""
        rows: dict[str, dict[str, Any]] = {}
        pending: dict[str, Cell] = {}
        for cell in cells:
            if cell.key in rows or cell.key in pending:
                continue
            row = _stored(self.out, cell.key, self.version)
            if row is None:
                pending[cell.key] = cell
            else:
                rows[cell.key] = row
        self.cached += len(rows)
        if pending:
            rows |= self._compute(list(pending.values()))
        return rows

    def _compute(self, pending: Sequence[Cell]) -> dict[str, dict[str, Any]]:
        self.start()
        ray = self._ray
        done: dict[str, dict[str, Any]] = {}
        task = ray.remote(num_cpus=1, max_retries=0)(run_cell)
        waiting = {task.remote(cell, self.context): cell for cell in pending}
        bar = tqdm(total=len(pending), unit="cell", disable=not self.progress, dynamic_ncols=True)
        while waiting:
            bar.set_postfix_str(f"{min(len(waiting), int(self.cluster_cpus))} running")
            ready, _ = ray.wait(list(waiting), num_returns=1, timeout=1.0)
            for ref in ready:
                cell = waiting.pop(ref)
                try:
                    row = dict(ray.get(ref))
                except Exception as exc:  # the worker died (out of memory, a crash): the cell's error
                    row = _failed(cell, f"{type(exc).__name__}: {exc}")
                worker = row.pop("worker_code_version", self.version)
                if worker != self.version:  # a machine of the cluster has other code: its row is not this code's
                    row = _failed(cell, f"the worker runs kartpilot {worker}, this study {self.version}: install "
                                        "the same commit on every machine")
                row["code_version"] = self.version
                write_json_atomic(_cell_file(self.out, cell.key), row)
                done[cell.key] = row
                bar.update(1)
        bar.close()
        self.computed += len(done)
        return done


def study_context(out: Path, data_dir: str | Path, cache_dir: str | Path | None) -> JobContext:
    return JobContext(Path(data_dir).resolve(), Path(cache_dir or out / "cache").resolve())


def run_study(spec: StudySpec, out: str | Path, data_dir: str | Path, quick: bool = False,
              address: str | None = None, cpus: int | None = None, cache_dir: str | Path | None = None,
              progress: bool = False) -> StudyRun:
    """Run (or complete) ``spec`` into ``out``; returns every cell's row, in the spec's order.

    ``cpus`` caps the local cluster's size (ignored with an ``address``); ``cache_dir`` is where simulated
    recordings are kept (default ``out/cache``).
    """
    out = Path(out)
    cells = expand_cells(spec, quick)
    start = time.perf_counter()
    with CellRunner(out, study_context(out, data_dir, cache_dir), address, cpus, progress) as runner:
        write_json_atomic(out / "study.json", {"name": spec.name, "title": spec.title, "report": spec.report,
                                               "questions": dict(spec.questions), "quick": quick,
                                               "code_version": runner.version, "cells": len(cells)})
        stored = runner.run(cells)
    wall = time.perf_counter() - start
    rows = [{**stored[cell.key], **cell.labels()} for cell in cells]
    write_json_atomic(out / "rows.json", {"code_version": runner.version, "quick": quick, "rows": rows})
    failed = sum(1 for row in stored.values() if row.get("status") != "ok")
    return StudyRun(rows, runner.computed, runner.cached, failed, wall, runner.cluster_cpus)


def load_rows(out: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A study folder's ``study.json`` and its rows."""
    out = Path(out)
    for name in ("study.json", "rows.json"):
        if not (out / name).is_file():
            raise DataError(f"{out} holds no study results ({name} is missing): run `kartpilot study run` first")
    try:
        meta = read_json_file(out / "study.json")
        rows = read_json_file(out / "rows.json")["rows"]
    except (DataError, KeyError, TypeError) as exc:
        raise DataError(f"{out}: damaged study results: {exc}") from exc
    return meta, list(rows)

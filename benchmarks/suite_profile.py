"""How long ``make test`` takes, and where the time goes: the suite run as ``make test`` runs it, its wall time, its
slowest 30 tests (setup, call and teardown together, from pytest's JUnit report) and each module's seconds (which
``tests/conftest.py`` uses to start the longest modules first).

    python benchmarks/suite_profile.py --out docs/results/suite_profile.json
    python benchmarks/suite_profile.py --docs    # the table in docs/contributing.md and the line in README.md

The run is the machine's whole suite: where ``../shared/data`` is missing, the tests that need it skip (and say so in
the JSON's count of skipped tests).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from typing import Any

from common import write_json
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "contributing.md"
README = ROOT / "README.md"
MARKER = "suite-profile"
README_MARKER = "suite-time"
PYTEST_ARGS = ["-q", "-n", "auto", "--maxprocesses", "4", "--dist", "loadscope", "--no-loadscope-reorder"]
"""As the Makefile's ``test`` target runs it."""


def read_junit(path: Path) -> list[dict[str, Any]]:
    """Each test case of a JUnit report: its id, its seconds, and whether it passed, failed or was skipped."""
    cases = []
    for case in ElementTree.parse(path).getroot().iter("testcase"):
        outcome = "skipped" if case.find("skipped") is not None else (
            "failed" if case.find("failure") is not None or case.find("error") is not None else "passed")
        module = case.get("classname", "").replace(".", "/")
        cases.append({"test": f"{module}.py::{case.get('name')}", "seconds": float(case.get("time", 0.0)),
                      "outcome": outcome})
    return cases


def module_seconds(cases: list[dict[str, Any]]) -> dict[str, float]:
    """Each test module's seconds, its tests' sum, the longest first (``tests/conftest.py`` starts them so)."""
    seconds: dict[str, float] = {}
    for case in cases:
        module = case["test"].split("::")[0]
        seconds[module] = seconds.get(module, 0.0) + case["seconds"]
    return dict(sorted(seconds.items(), key=lambda item: -item[1]))


def render(results: dict[str, Any]) -> str:
    """The docs' table, from the JSON :func:`main` writes."""
    minutes, seconds = divmod(round(results["wall_s"]), 60)
    lines = [f"`make test` on {results['machine']} ({results['date']}): {results['passed']} passed, "
             f"{results['skipped']} skipped, {results['failed']} failed, in {minutes} min {seconds:02d} s of wall "
             "time; "
             f"the tests' own times add up to {results['test_s'] / 60:.1f} min over {results['workers']} workers "
             "(`benchmarks/suite_profile.py`). The slowest 30:", "",
             "| test | seconds |", "|---|---:|"]
    lines += [f"| `{row['test']}` | {row['seconds']:.1f} |" for row in results["slowest"]]
    return "\n".join(lines) + "\n"


def render_readme(results: dict[str, Any]) -> str:
    minutes, seconds = divmod(round(results["wall_s"]), 60)
    return (f"On {results['machine']}, `make test` ran {results['passed'] + results['skipped'] + results['failed']} "
            f"tests in {minutes} min {seconds:02d} s of wall time on {results['date']} (after the install; "
            "[where the time goes](docs/contributing.md)).\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/results/suite_profile.json")
    parser.add_argument("--docs", action="store_true", help="only put the table from --out into the docs")
    args = parser.parse_args()
    if args.docs:
        results = json.loads(Path(args.out).read_text(encoding="utf-8"))
        put_at_marker(PAGE, render(results), MARKER)
        put_at_marker(README, render_readme(results), README_MARKER)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "junit.xml"
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "compileall", "-q", "src"], cwd=ROOT, stdout=subprocess.DEVNULL,
                       check=True)  # as the Makefile's test target does first
        done = subprocess.run([sys.executable, "-m", "pytest", *PYTEST_ARGS, f"--junitxml={report}"], cwd=ROOT)
        wall_s = time.perf_counter() - start
        cases = read_junit(report)
    cores = os.cpu_count() or 1
    result = {"machine": f"{cores} cores, {sys.platform}, Python {sys.version.split()[0]}",
              "date": time.strftime("%Y-%m-%d"), "workers": min(cores, 4), "exit_code": done.returncode,
              "wall_s": wall_s, "test_s": sum(c["seconds"] for c in cases),
              **{outcome: sum(c["outcome"] == outcome for c in cases) for outcome in ("passed", "skipped", "failed")},
              "slowest": sorted(cases, key=lambda c: -c["seconds"])[:30], "modules": module_seconds(cases)}
    print(f"{len(cases)} tests in {wall_s / 60:.1f} min of wall time")
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

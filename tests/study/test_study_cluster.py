"""A study on a real Ray cluster: a head and a worker node started with ``ray start``, in a temporary folder.

The study is small and cheap (the path follower on the true pose needs no rendering), with one cell that
fails on purpose: its rows, its cache (a rerun computes nothing) and its report are checked."""

from __future__ import annotations

import contextlib
import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from kartpilot.cli.main import main
from kartpilot.runtime.config import load_stack_config
from kartpilot.study.run import run_study
from kartpilot.study.spec import load_spec
from kartpilot.study.tune import tune_study

ray = pytest.importorskip("ray")

RAY = Path(sys.executable).with_name("ray")

SPEC = {
    "name": "tiny",
    "title": "A tiny study",
    "questions": {"gain": "Does a higher cross-track gain keep the kart nearer the path?"},
    "parts": [{
        "name": "gains", "job": "path_follow", "sources": ["straight20", "no-such-track"], "seeds": [1, 2],
        "params": {"pose_noise_m": 0.02, "camera_rate_hz": 15.0},
        "base": {"sim": {"disturbances": {"steer_bias_rad": 0.03}}},
        "sweep": {"drive.follow.stanley.k_cross_track": [0.6, 2.4]},
        "quick": {"sources": ["straight20", "no-such-track"], "seeds": [1]},
    }],
}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# Ray 2.59 and newer turn token authentication on for a new head whenever ~/.ray holds a token, but a client
# joining with an address does not send it unless told to (ray-project/ray#64755): this test's cluster is
# local and throwaway, so it runs without (Ray's own switch, for the commands the test starts)
RAY_ENV = {**os.environ, "RAY_AUTH_MODE": "disabled"}


def _start(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen([str(RAY), "start", "--block", "--disable-usage-stats", *args], env=RAY_ENV,
                            stdout=log.open("wb"), stderr=subprocess.STDOUT, start_new_session=True)


def _status(address: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(RAY), "status", f"--address={address}"], capture_output=True, text=True,
                          env=RAY_ENV)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """``ray start --head`` and ``ray start --address`` (a second node), one CPU each; stopped afterwards."""
    tmp_path = tmp_path_factory.mktemp("ray-logs")
    if not RAY.is_file():
        pytest.skip(f"no ray command beside {sys.executable}")
    port = _free_port()
    address = f"127.0.0.1:{port}"
    temp = Path("/tmp") / f"kp-ray-{os.getpid()}-{port}"  # Ray's socket paths must stay short
    head = _start(["--head", f"--port={port}", "--num-cpus=1", "--include-dashboard=false",
                   f"--temp-dir={temp}", "--node-ip-address=127.0.0.1"], tmp_path / "head.log")
    processes = [head]
    try:
        deadline = time.monotonic() + 60
        while _status(address).returncode:
            if time.monotonic() > deadline or head.poll() is not None:
                pytest.fail("the Ray head did not start:\n" + (tmp_path / "head.log").read_text())
            time.sleep(1)
        processes.append(_start([f"--address={address}", "--num-cpus=1", "--node-ip-address=127.0.0.1"],
                                tmp_path / "worker.log"))
        deadline = time.monotonic() + 60
        while _cpus(address) < 2:
            if time.monotonic() > deadline:
                pytest.fail("the worker node did not join:\n" + (tmp_path / "worker.log").read_text())
            time.sleep(1)
        yield address
    finally:
        for process in reversed(processes):
            os.killpg(process.pid, signal.SIGTERM)  # --block: the command stops the node it started
        deadline = time.monotonic() + 10
        for process in processes:
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=max(0.1, deadline - time.monotonic()))
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)  # and whatever of its group is left
        shutil.rmtree(temp, ignore_errors=True)


def _cpus(address: str) -> float:
    for line in _status(address).stdout.splitlines():
        if "CPU" in line and "/" in line:
            return float(line.split("/")[1].split()[0])
    return 0.0


def test_a_study_runs_on_a_cluster_caches_its_rows_and_reports(cluster: str, tmp_path: Path, capsys):
    spec_file = tmp_path / "tiny.yaml"
    spec_file.write_text(yaml.safe_dump(SPEC))
    out = tmp_path / "study"
    run = run_study(load_spec(spec_file), out, tmp_path / "no-data", quick=True, address=cluster)
    assert run.cpus == 2
    assert len(run.rows) == 4 and run.computed == 4 and run.cached == 0
    ok = [r for r in run.rows if r["source"] == "straight20"]
    assert all(r["status"] == "ok" and r["success"] for r in ok), ok
    assert ok[0]["config_hash"] != ok[1]["config_hash"]
    assert all(r["code_version"] == ok[0]["code_version"] for r in ok)
    # the gain changes the drive (the rows are the cells' own, not one row copied)
    assert ok[0]["max_offset_m"] != ok[1]["max_offset_m"]
    failed = [r for r in run.rows if r["source"] == "no-such-track"]
    assert run.failed == 2 and all(r["status"] == "failed" and "no-such-track" in r["error"] for r in failed)

    # a rerun through the command line, on the same cluster: the good cells come from the cache
    assert main(["study", "run", str(spec_file), "--out", str(out), "--quick", "--address", cluster,
                 "--data", str(tmp_path / "no-data")]) == 0
    printed = capsys.readouterr().out
    assert "2 computed, 2 from the cache, 2 failed" in printed, printed

    assert (out / "report.md").is_file() and (out / "figures").is_dir()
    report = (out / "report.md").read_text()
    assert "Does a higher cross-track gain" in report and "## Failed cells" in report
    with (out / "rows.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 and {r["source"] for r in rows} == {"straight20", "no-such-track"}
    assert list((out / "figures").glob("*.png"))


def test_tuning_searches_on_the_cluster_and_reports_on_held_out_seeds(cluster: str, tmp_path: Path):
    spec = {**SPEC, "parts": [{**SPEC["parts"][0], "sources": ["straight20"]}], "tune": {
        "part": "gains",
        "space": {"drive.follow.stanley.k_cross_track": [0.2, 5.0, "log"],
                  "drive.follow.stanley.k_heading": [0.1, 2.0]},
        "minimize": {"max_offset_m": 1.0, "steer_rate_rms_radps": 0.1},
        "tune_on": {"sources": ["straight20"], "seeds": [1]},
        "held_out": {"sources": ["straight20"], "seeds": [2, 3]}, "trials": 4}}
    spec_file = tmp_path / "tiny.yaml"
    spec_file.write_text(yaml.safe_dump(spec))
    out = tmp_path / "tune"
    result = tune_study(load_spec(spec_file), out, tmp_path, address=cluster)
    assert result.trials == 4 and set(result.best_params) == {"drive.follow.stanley.k_cross_track",
                                                              "drive.follow.stanley.k_heading"}
    assert set(result.held_out) == {"defaults", "tuned", "change"}
    assert all(summary["runs"] == 2 for summary in result.held_out.values())  # seeds 2 and 3, not 1
    change = result.held_out["change"]["objective"]
    assert change == pytest.approx(result.held_out["tuned"]["objective"] - result.held_out["defaults"]["objective"])
    saved = json.loads((out / "tune.json").read_text())
    assert saved["tuned_on"]["seeds"] == [1] and saved["held_out"]["seeds"] == [2, 3] and len(saved["trials"]) == 4
    stack = load_stack_config(out / "best.yaml")  # the best settings load as a stack configuration
    assert stack.drive.follow.stanley.k_cross_track == pytest.approx(
        result.best_params["drive.follow.stanley.k_cross_track"])
    assert "Held out" in (out / "tune.md").read_text()

"""A study on a real Ray cluster: a head and a worker node started with ``ray start``, in a temporary folder.

The study is small and cheap (the path follower on the true pose needs no rendering), with one cell that
fails on purpose: its rows, its cache (a rerun computes nothing) and its report are checked."""

from __future__ import annotations

import csv
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
from kartpilot.study.run import run_study
from kartpilot.study.spec import load_spec

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


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[str]:
    """``ray start --head`` and ``ray start --address`` (a second node), one CPU each; stopped afterwards."""
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
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
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

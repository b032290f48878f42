"""A crowd on the kart's network during a live drive: does the holder's page still drive, and does the kart's CAN
keep its rhythm? (Issue 55's acceptance: 200 slow or half-open connections and 20 parallel 10 MB bodies during a
drive; the holder's controls arrive, the CAN command gap stays under 0.1 s, the log names each address once.)

The drive is ``kartpilot drive --live`` as a team runs it, without a kart: a rendered video of the SDC kart's
centre camera stands in for the camera, python-can's virtual bus for the CAN, a thread of simulated RDW ECUs
answers. The holder's page pairs, arms autonomy and posts its control every 100 ms for the whole drive, on a
kept-alive connection as the page does. From ``--crowd-from`` to ``--crowd-until`` seconds into the drive, strangers
open 200 requests and never finish them, and 20 more announce 10 MB bodies and send the first 64 KB. Measured: every
holder's post (status and round trip), the gaps between the kart's sent commands (each CAN id, from the recording)
inside and outside the crowd's window, the supervisor's states, and the refusals logged per address.

    python benchmarks/web_crowd.py --out docs/results/web_crowd.json
    python benchmarks/web_crowd.py --docs      # the table in docs/real-kart.md, from that JSON

Wall-clock timing on purpose: this is the machine's measure, kept out of the tests (``tests/runtime/test_webui.py``
checks the same crowd's outcome without timing it).
"""

from __future__ import annotations

import argparse
import contextlib
import http.client
import itertools
import json
import logging
import os
import socket
import statistics
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2

from common import write_json
from kartpilot.actuation.can_bus import CanConfig, open_bus
from kartpilot.actuation.rdw_protocol import RdwConfig
from kartpilot.calibration.rig import Rig
from kartpilot.core.camera import CaptureSettings
from kartpilot.core.vehicle import get_vehicle
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.drive import WatchdogConfig
from kartpilot.runtime.live_drive import LiveDriveSetup, run_live_drive
from kartpilot.runtime.pipelines import Route
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sensors.health import HealthConfig
from kartpilot.sim.can_ecu import RdwEcus
from kartpilot.sim.simulator import SimConfig
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "real-kart.md"
MARKER = "web-crowd"
PAIR_CODE = "bench-code"


def camera_video(folder: Path, seconds: float) -> tuple[Path, Any]:
    """A rendered drive of the SDC kart's centre camera (the 640x480 camera of ``sdc-kart-steep``) as an MP4
    video, and its calibration."""
    config = SimConfig(track="sdc-assen", vehicle="sdc-kart-steep", cameras=("center",), camera_rate_hz=15.0,
                       max_time_s=seconds, seed=1)
    run_simulation(config, "centerline", outputs=SessionOutputs(record_dir=folder / "rendered"))
    reader = RecordingReader(folder / "rendered")
    frames = reader.frames("center")
    first = cv2.imread(str(frames[0][1]))
    path = folder / "center.mp4"
    video = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 15.0, (first.shape[1], first.shape[0]))
    for _, frame in frames:
        video.write(cv2.imread(str(frame)))
    video.release()
    return path, reader.cameras["center"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Holder(threading.Thread):
    """The operator's phone: pairs, arms autonomy, then posts its control every 100 ms on one kept-alive
    connection until told to stop; every post's status and round trip kept."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.posts: list[tuple[float, int, float]] = []  # (monotonic s, status, round trip s)
        self.stop = threading.Event()

    def _request(self, connection: http.client.HTTPConnection, path: str, body: dict[str, Any],
                 cookie: str = "") -> tuple[int, http.client.HTTPResponse]:
        headers = {"Content-Type": "application/json", "Origin": f"http://127.0.0.1:{self.port}"}
        if cookie:
            headers["Cookie"] = cookie
        connection.request("POST", path, json.dumps(body).encode(), headers)
        reply = connection.getresponse()
        reply.read()
        return reply.status, reply

    def run(self) -> None:
        deadline = time.monotonic() + 10.0
        connection = http.client.HTTPConnection("127.0.0.1", self.port, timeout=5.0)
        while True:
            try:
                status, reply = self._request(connection, "/pair", {"code": PAIR_CODE})
                break
            except OSError:  # the page is not up yet
                connection.close()
                if time.monotonic() > deadline:
                    return
                time.sleep(0.05)
        cookie = (reply.getheader("Set-Cookie") or "").split(";")[0]
        self._request(connection, "/input", {"hold": True}, cookie)
        self._request(connection, "/request", {"request": "autonomous"}, cookie)
        while not self.stop.is_set():
            start = time.monotonic()
            try:
                status, _ = self._request(connection, "/input", {"hold": True, "steer": 0.0, "throttle": 0.0,
                                                                  "brake": 0.0}, cookie)
            except OSError:  # the drive has ended and the page with it
                return
            self.posts.append((start, status, time.monotonic() - start))
            time.sleep(max(0.0, 0.1 - (time.monotonic() - start)))
        connection.close()


def crowd(port: int, slow: int, big: int, hold_s: float) -> dict[str, int]:
    """``slow`` requests opened and never finished, ``big`` announced 10 MB bodies (the first 64 KB sent), all
    held ``hold_s`` seconds, then closed. Returns how many connections were opened of each."""
    opened_slow, opened_big = [], []
    for _ in range(slow):
        with contextlib.suppress(OSError):
            sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
            sock.sendall(b"POST /input HTTP/1.1\r\nHost: x\r\n")
            opened_slow.append(sock)
    for _ in range(big):
        with contextlib.suppress(OSError):
            sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
            sock.sendall(b"POST /estop HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                         b"Content-Length: 10000000\r\n\r\n" + b" " * 65536)
            opened_big.append(sock)
    time.sleep(hold_s)
    for sock in opened_slow + opened_big:
        sock.close()
    return {"slow": len(opened_slow), "big": len(opened_big)}


def gaps_s(stamps_ns: list[int], start_ns: int, end_ns: int) -> list[float]:
    """The gaps between consecutive stamps, each counted in the window where it ends."""
    return [(b - a) * 1e-9 for a, b in itertools.pairwise(stamps_ns) if start_ns <= b < end_ns]


class Refusals(logging.Handler):
    """Counts the web page's refusal lines per address."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if "refused" in message:
            self.lines.append(message)


def run(seconds: float, crowd_from_s: float, crowd_until_s: float) -> dict[str, Any]:
    sdc = get_vehicle("sdc-kart")
    refusals = Refusals()
    logging.getLogger("kartpilot.runtime.webui").addHandler(refusals)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        video, camera = camera_video(folder, seconds + 2.0)
        rig = Rig({"center": camera}, None, {"center": CaptureSettings(str(video), fps=15.0)})
        channel = f"web-crowd-{time.monotonic_ns()}"
        ecu_bus = open_bus(CanConfig(channel=channel))
        ecus = RdwEcus(ecu_bus, time.monotonic_ns, sdc.steering)
        stop = threading.Event()

        def ecu_loop() -> None:
            while not stop.is_set():
                ecus.step()
                time.sleep(0.005)

        port = free_port()
        holder = Holder(port)
        opened: dict[str, int] = {}
        started_ns: list[int] = []

        def strangers() -> None:
            while not started_ns:
                time.sleep(0.01)
            time.sleep(max(0.0, crowd_from_s - (time.monotonic_ns() - started_ns[0]) * 1e-9))
            opened.update(crowd(port, 200, 20, crowd_until_s - crowd_from_s))

        ecu_thread = threading.Thread(target=ecu_loop, daemon=True)
        ecu_thread.start()
        holder.start()
        crowd_thread = threading.Thread(target=strangers, daemon=True)
        crowd_thread.start()
        can_config = CanConfig(channel=channel, protocol="rdw", rdw=RdwConfig())
        stack = replace(StackConfig(), can=can_config,
                        watchdogs=WatchdogConfig(health=HealthConfig(timeout_s=2.0), overrun_steps=1000))
        setup = LiveDriveSetup(rig, "lanes", sdc, Route(), web_port=port, web_pair_code=PAIR_CODE,
                               outputs=SessionOutputs(record_dir=folder / "live"), duration_s=seconds)
        started_ns.append(time.monotonic_ns())
        try:
            summary = run_live_drive(setup, stack)
        finally:
            holder.stop.set()
            stop.set()
            ecu_thread.join(timeout=2.0)
            crowd_thread.join(timeout=crowd_until_s + 10.0)
            ecu_bus.shutdown()
            logging.getLogger("kartpilot.runtime.webui").removeHandler(refusals)
        reader = RecordingReader(folder / "live")
        sent = [(stamp, i) for stamp, direction, i, _ in reader.can_frames() if direction == "tx"]
    t0 = started_ns[0]
    window = (t0 + round(crowd_from_s * 1e9), t0 + round(crowd_until_s * 1e9))
    ids = sorted({i for _, i in sent})
    commands = []
    for i in ids:
        stamps = [stamp for stamp, j in sent if j == i]
        inside = gaps_s(stamps, *window)
        outside = gaps_s(stamps, stamps[0], window[0]) + gaps_s(stamps, window[1], stamps[-1] + 1)
        commands.append({"id": f"0x{i:03X}", "sent": len(stamps),
                         "max_gap_in_crowd_s": max(inside, default=float("nan")),
                         "median_gap_in_crowd_s": statistics.median(inside) if inside else float("nan"),
                         "max_gap_outside_s": max(outside, default=float("nan"))})
    in_crowd = [(status, rtt) for at, status, rtt in holder.posts
                if window[0] <= round(at * 1e9) < window[1]]
    addresses: dict[str, int] = {}
    for line in refusals.lines:
        address = line.split("refused ", 1)[1].split(" ", 1)[0]
        addresses[address] = addresses.get(address, 0) + 1
    states = [(t["state"], t["reason"]) for t in summary["transitions"]]
    return {"machine": f"{os.cpu_count()} cores, {sys.platform}, Python {sys.version.split()[0]}",
            "date": time.strftime("%Y-%m-%d"), "drive_s": seconds, "crowd_s": [crowd_from_s, crowd_until_s],
            "crowd_opened": opened, "holder_posts": len(holder.posts),
            "holder_posts_in_crowd": len(in_crowd),
            "holder_posts_refused": sum(status != 200 for _, status, _ in holder.posts),
            "holder_round_trip_max_in_crowd_s": max((rtt for _, rtt in in_crowd), default=float("nan")),
            "holder_round_trip_median_in_crowd_s": statistics.median([rtt for _, rtt in in_crowd])
            if in_crowd else float("nan"),
            "commands": commands, "states": states, "ended": summary["ended"],
            "refusal_lines_per_address": addresses}


def render(results: dict[str, Any]) -> str:
    start, end = results["crowd_s"]
    opened = results["crowd_opened"]
    lines = [f"A live drive of {results['drive_s']:g} s on {results['machine']} ({results['date']}, "
             "`benchmarks/web_crowd.py`): the holder's page posting every 100 ms; from "
             f"{start:g} to {end:g} s, {opened.get('slow', 0)} half-open requests and {opened.get('big', 0)} announced "
             "10 MB bodies from strangers. "
             f"The holder's posts: {results['holder_posts']}, {results['holder_posts_in_crowd']} in the crowd, "
             f"{results['holder_posts_refused']} refused; round trip in the crowd median "
             f"{results['holder_round_trip_median_in_crowd_s'] * 1000:.1f} ms, max "
             f"{results['holder_round_trip_max_in_crowd_s'] * 1000:.1f} ms. "
             f"The supervisor's states: {', '.join(state for state, _ in results['states'])}. "
             "Refusal lines in the log: " + (", ".join(f"{address} {count}" for address, count in
                                                       results["refusal_lines_per_address"].items()) or "none")
             + ".", "",
             "| CAN id | sent | gap in the crowd: median, max (s) | max gap outside it (s) |", "|---|---:|---:|---:|"]
    lines += [f"| {row['id']} | {row['sent']} | {row['median_gap_in_crowd_s']:.3f}, {row['max_gap_in_crowd_s']:.3f} "
              f"| {row['max_gap_outside_s']:.3f} |" for row in results["commands"]]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="the drive's length")
    parser.add_argument("--crowd-from", type=float, default=3.0)
    parser.add_argument("--crowd-until", type=float, default=8.0)
    parser.add_argument("--out", default="docs/results/web_crowd.json")
    parser.add_argument("--docs", action="store_true", help="only put the table from --out into the docs")
    args = parser.parse_args()
    if not args.docs:
        results = run(args.seconds, args.crowd_from, args.crowd_until)
        write_json(args.out, results)
    put_at_marker(PAGE, render(json.loads(Path(args.out).read_text(encoding="utf-8"))), MARKER)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

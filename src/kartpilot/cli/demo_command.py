"""``kartpilot demo``: what kartpilot is for, closed loop in the simulator, in about two minutes on two cores.

First the Self Driving Challenge's day: the SDC kart, with the real kart's camera model, drives each of the event's
six scenarios at the venue (``lelystad``): start on green, a speed sign, a red light at its stop line, a pedestrian
at a zebra, a car to overtake, a bay to park in, on its lane pipeline and the event's rules, judged as the event
judges. Beside them, the small kart of the thesis's second part: taught a drive, it builds its reference with
stereo VO and repeats it. Each drive is one core's work (the simulator's software renderer and the pipeline), so
the drives share the machine's cores, each in a process of its own. Each writes a video of what the pipeline saw and
decided, and its result; warnings go to ``demo.log``; the summary says what was measured and where it is.

``--full`` drives the ``event`` course instead (all six in a row), a lap of the venue at 30 km/h, and a
teach-and-repeat lap of ``utrack``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import multiprocessing
import os
import time
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kartpilot.runtime.experiment import TeachRepeatConfig, run_teach_repeat, summary_line
from kartpilot.runtime.scenarios import run_scenario
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.scenarios import SCENARIOS
from kartpilot.sim.simulator import SimConfig

__all__ = ["FULL_DEMO", "QUICK_DEMO", "DemoPlan", "demo"]


@dataclass(frozen=True)
class DemoPlan:
    """What ``kartpilot demo`` drives.

    Attributes:
        scenarios: the event's scenarios to drive, each on its own.
        seed: their seed (where the props stand, when the lights change, how the pedestrian walks).
        venue_lap_kmh: a lap of the venue on lane following in this speed mode; 0 for none.
        vo_track, vo_speed_mps: the small kart's teach-and-repeat.
    """

    scenarios: tuple[str, ...]
    seed: int
    venue_lap_kmh: float
    vo_track: str
    vo_speed_mps: float


SIX = tuple(name for name in SCENARIOS if name != "event")
"""The event's six scenarios, each on its own (``event`` drives them in a row)."""
QUICK_DEMO = DemoPlan(scenarios=SIX, seed=3, venue_lap_kmh=0.0, vo_track="straight20", vo_speed_mps=1.0)
FULL_DEMO = DemoPlan(scenarios=("event",), seed=3, venue_lap_kmh=30.0, vo_track="utrack", vo_speed_mps=2.0)


@contextlib.contextmanager
def _log_to(log_path: Path, mode: str, quiet_console: bool) -> Iterator[None]:
    """Warnings and details to ``log_path``; with ``quiet_console`` the terminal keeps only errors (the progress
    and the summary are printed, not logged)."""
    handler = logging.FileHandler(log_path, mode=mode, encoding="utf-8")
    handler.setFormatter(logging.Formatter(f"%(asctime)s %(levelname)s %(name)s [{os.getpid()}]: %(message)s"))
    root = logging.getLogger()
    consoles = [h for h in root.handlers if isinstance(h, logging.StreamHandler) and h.level < logging.ERROR] \
        if quiet_console else []
    levels = [h.level for h in consoles]
    root.addHandler(handler)
    for console in consoles:
        console.setLevel(logging.ERROR)
    try:
        yield
    finally:
        root.removeHandler(handler)
        handler.close()
        for console, level in zip(consoles, levels, strict=True):
            console.setLevel(level)


def _scenario_drive(name: str, seed: int, out: Path, log_path: Path) -> dict[str, Any]:
    """One scenario, in a worker process: its result (written beside its video too)."""
    with _log_to(log_path, "a", False):
        return run_scenario(name, seed, outputs=SessionOutputs(video_path=out / f"{name}.mp4",
                                                               result_path=out / f"{name}.json"))


def _venue_lap(kmh: float, out: Path, log_path: Path) -> dict[str, Any]:
    """A lap of the venue on lane following, in a worker process: its result."""
    with _log_to(log_path, "a", False):
        config = SimConfig(track="lelystad", vehicle="sdc-kart", seed=1, camera_rate_hz=30.0,
                           speed_mode_mps=kmh / 3.6)
        run = run_simulation(config, "lanes", outputs=SessionOutputs(video_path=out / "lelystad-lap.mp4",
                                                                       result_path=out / "lelystad-lap.json"))
        return run.result.to_json()


def _teach_and_repeat(plan: DemoPlan, folder: Path, log_path: Path) -> tuple[dict[str, Any], str]:
    """The small kart's part, in a worker process: its result, and what it printed (shown once it is done, not
    through the others' lines)."""
    printed = io.StringIO()
    with _log_to(log_path, "a", False), contextlib.redirect_stdout(printed):
        result = run_teach_repeat(TeachRepeatConfig(track=plan.vo_track, speed_mps=plan.vo_speed_mps, seed=1),
                                  folder, keep_teach=False)
    return result, printed.getvalue()


def _verdict(result: dict[str, Any]) -> str:
    verdict = "passed" if result["passed"] else "FAILED: " + "; ".join(result["faults"])
    stop = f" (stopped {result['stopped_before_line_m']:.2f} m before the line at red)" \
        if "stopped_before_line_m" in result else ""
    return verdict + stop


def _lap_line(kmh: float, lap: dict[str, Any]) -> str:
    verdict = f"disqualified: {lap['reason']}" if lap["disqualified"] else "no disqualification"
    return (f"a lap of lelystad at {kmh:g} km/h: {lap['distance_m']:.0f} m in {lap['sim_time_s']:.0f} s, {verdict}, "
            f"centre offset mean {lap['mean_center_offset_m']:.2f} m, max {lap['max_center_offset_m']:.2f} m")


def demo(args: argparse.Namespace) -> int:
    """Run the showcase into ``--out``; exit 1 if a scenario was not passed (the summary says which and why)."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plan = DemoPlan(FULL_DEMO.scenarios, FULL_DEMO.seed, FULL_DEMO.venue_lap_kmh, FULL_DEMO.vo_track, args.vo_speed) \
        if args.full else QUICK_DEMO
    log_path = out / "demo.log"
    start = time.perf_counter()
    workers = max(1, min(2, os.cpu_count() or 1))
    print(f"the SDC kart drives the event's scenarios at the venue (lelystad), seed {plan.seed}, on its lane "
          f"pipeline and the event's rules: {', '.join(plan.scenarios)}"
          + (f"; then a lap of the venue at {plan.venue_lap_kmh:g} km/h" if plan.venue_lap_kmh else ""))
    print(f"the small kart is taught {plan.vo_track} at {plan.vo_speed_mps:g} m/s, builds its reference with stereo "
          f"VO, then drives it on VO and the taught map ({workers} drive(s) at a time, one per core)")
    results: dict[str, dict[str, Any]] = {}
    with _log_to(log_path, "w", True), ProcessPoolExecutor(workers, multiprocessing.get_context("spawn")) as pool:
        small = pool.submit(_teach_and_repeat, plan, out / f"{plan.vo_track}-vo", log_path)  # the longest first
        lap = pool.submit(_venue_lap, plan.venue_lap_kmh, out, log_path) if plan.venue_lap_kmh else None
        drives: dict[Future[dict[str, Any]], str] = {
            pool.submit(_scenario_drive, name, plan.seed, out, log_path): name for name in plan.scenarios}
        for done in as_completed(drives):
            results[drives[done]] = done.result()
            print(f"  {drives[done]}: {_verdict(results[drives[done]])}  ({time.perf_counter() - start:.0f} s)")
        repeat, printed = small.result()
        print(printed.rstrip("\n"))
        lap_result = lap.result() if lap is not None else None
    minutes, seconds = divmod(round(time.perf_counter() - start), 60)
    passed = sum(r["passed"] for r in results.values())
    print(f"\ndone in {minutes} min {seconds:02d} s. What was measured:")
    print(f"  the event's scenarios, seed {plan.seed}: {passed} of {len(results)} passed")
    for name in plan.scenarios:
        print(f"    {name}: {_verdict(results[name])}")
    if lap_result is not None:
        print(f"  {_lap_line(plan.venue_lap_kmh, lap_result)}")
    print(f"  teach and repeat, {plan.vo_track}: {summary_line(repeat)}")
    print("Where it is:")
    print(f"  {out}/SCENARIO.mp4, .json   what the kart saw and decided, the referee's state on every frame; the "
          "verdict")
    if lap_result is not None:
        print(f"  {out / 'lelystad-lap.mp4'}, {out / 'lelystad-lap.json'}   the lap")
    print(f"  {out / f'{plan.vo_track}-vo'}/  the VO reference and its map, the repeat drive's video, result and plots")
    print(f"  {log_path}   warnings and details" + ("" if args.full else "; `kartpilot demo --full` drives more"))
    return 0 if passed == len(results) else 1

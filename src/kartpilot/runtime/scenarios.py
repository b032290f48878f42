"""One of the event's scenarios, closed loop: the lane pipeline with the event's rules on the simulated kart, and
the scenario's referee (:mod:`kartpilot.sim.scenarios`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from kartpilot.core.config import config_to_dict
from kartpilot.core.files import write_json_atomic
from kartpilot.core.types import ActuatorCommand, FrameSet, FrameSource, VehicleFeedback
from kartpilot.runtime.config import StackConfig, load_stack_config
from kartpilot.runtime.drive import ToldPipeline
from kartpilot.runtime.faults import InjectedSource, Injection
from kartpilot.runtime.lane_policy import LanePolicy, LanePolicyConfig
from kartpilot.runtime.loop import run_loop
from kartpilot.runtime.session import SessionOutputs
from kartpilot.runtime.simulate import DriveVideo, sim_recording
from kartpilot.sim.referee import RefereeConfig
from kartpilot.sim.scenarios import Scenario, ScenarioReferee, footprints_touch, scenario, start_pose_s
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import Track, build_track, load_track_spec, project_onto

__all__ = ["SCENARIO_SPEED_KMH", "run_scenario"]

SCENARIO_SPEED_KMH = 15.0
"""The speed mode the scenarios run at (the event's limits are 10 to 20 km/h)."""


def run_scenario(name: str | Scenario, seed: int | None = None, stack: StackConfig | None = None,
                 camera_rate_hz: float = 15.0, max_time_s: float | None = None,
                 outputs: SessionOutputs | None = None, vehicle: str = "sdc-kart",
                 injections: Sequence[Injection] = ()) -> dict[str, Any]:
    """Drive one scenario: a built-in one by name on ``seed``, or a :class:`Scenario` (from a file; ``seed`` replaces
    its seed); its result in the session result's ``scenarios`` form (``name``, ``seed``, ``passed``, ``faults``).
    The kart's measured speed and steering angle are the simulator's. The drive ends at the scenario's time, or a
    second after the kart has parked or the verdict on the rules is sure (:meth:`ScenarioReferee.decided`);
    ``max_time_s`` ends it earlier (a test's short drive: then judged as far as it went).

    ``outputs`` (none by default): ``record_dir`` records the drive as every drive is (frames, commands, the
    ``lanes`` and ``behaviour`` topics, and the ``kart`` topic of what the pipeline was told the kart measured),
    with the lane pipeline's settings in its manifest, so ``kartpilot replay`` gives the same decisions;
    ``video_path`` writes the lane pipeline's view with what the rules saw and decided, the referee's state and
    the scenario's faults so far; ``view`` a Rerun view; ``result_path`` the result as ``{"scenarios": [...]}``;
    ``progress`` a bar over the scenario's time.

    ``vehicle``: ``sdc-kart``, or ``sdc-kart-2026`` whose rules use its LiDAR while it is healthy (the result's
    ``lidar``: when it stopped and started again, and why). ``injections``: faults (:mod:`kartpilot.runtime.faults`)."""
    cv2.setNumThreads(1)
    plan = _plan(name, seed)
    seed, name = plan.seed, plan.name
    policy_config = _rules_for(stack or load_stack_config(None, "kart"), plan)
    track = _course_for(plan)
    config = replace(_sim_config(plan, camera_rate_hz, max_time_s), vehicle=vehicle)
    referee = ScenarioReferee(plan)
    with Simulator(config, track=track) as sim:
        policy = LanePolicy(sim.cameras, policy_config, camera_rate_hz, sim.vehicle.max_steer_rad, sim.vehicle.lidar)
        judge = _Judge(sim, referee, policy, plan, track)
        # told what the kart measured, as a drive tells it: the simulator's speed and the RDW steering ECU's angle
        told = ToldPipeline(policy, lambda frames: VehicleFeedback(frames.stamp_ns, sim.state.vx_mps,
                                                                   sim.state.steer_rad), kart_topic=True)
        outputs = outputs or SessionOutputs()
        writer = sim_recording(sim, outputs.record_dir, {
            "source": "kartpilot sim --scenario", "scenario": name, "seed": seed, "vehicle": sim.vehicle.name,
            "pipeline": "lanes", "config": {"lane_policy": config_to_dict(policy_config)}})
        view = outputs.open_view(sim.cameras, lidars=sim.lidar_mounts)
        video = DriveVideo(outputs.video_path, sim, policy.overlay, more_lines=lambda: _verdict_line(name, referee)) \
            if outputs.video_path is not None else None
        bar = tqdm(total=round(config.max_time_s), unit="s", disable=(not outputs.progress) or None, leave=False)

        def step(frames: FrameSet, command: ActuatorCommand) -> None:
            judge(frames, command)
            if video is not None:
                video.write(frames)
            bar.update(min(round(sim.time_s), bar.total) - bar.n)

        try:  # the drive ends at the scenario's time, or a second after the kart has parked or the verdict is sure
            source: FrameSource = _Until(sim, lambda: judge.parked_s >= 1.0 or judge.decided_s >= 1.0)
            run_loop(InjectedSource(source, list(injections)) if injections else source, told, sim,
                     [sink for sink in (writer, view) if sink is not None], on_step=step)
        finally:
            bar.close()
            for sink in (writer, video, view):
                if sink is not None:
                    sink.close()
        result = _result(referee, judge, sim, policy)
    if outputs.result_path is not None:
        write_json_atomic(outputs.result_path, {"scenarios": [result]})
    return result


def _result(referee: ScenarioReferee, judge: _Judge, sim: Simulator, policy: LanePolicy) -> dict[str, Any]:
    """The referee's verdict, the rules' states, the camera's pitch as the lanes measured it (``pitch_off_deg``,
    off the rig's mount), the simulator's own disqualification, and on a kart with a LiDAR when it stopped and
    started giving good sweeps (``lidar``: [time, why] each)."""
    result = referee.result(judge.front_s_m)
    result["states"] = judge.states
    result["pitch_off_deg"] = round(policy.horizon.pitch_deg, 3)  # the camera's pitch as measured while driving
    if sim.vehicle.lidar is not None:
        result["lidar"] = [[round(stamp * 1e-9, 2), problem or "recovered"] for stamp, problem in policy.lidar_events]
    if sim.referee.disqualified:
        result["faults"].append(str(sim.referee.reason))
        result["passed"] = False
    return result


def _sim_config(plan: Scenario, camera_rate_hz: float, max_time_s: float | None) -> SimConfig:
    """The simulated SDC kart for ``plan``: its world and camera, the scenarios' speed mode, its time."""
    return SimConfig(track=plan.track, vehicle="sdc-kart", seed=plan.seed, render=plan.render, effects=plan.effects,
                     camera_rate_hz=camera_rate_hz, speed_mode_mps=SCENARIO_SPEED_KMH / 3.6,
                     max_time_s=plan.duration_s if max_time_s is None else min(max_time_s, plan.duration_s),
                     referee=RefereeConfig(laps=plan.laps, may_cross_dashed=plan.overtake or plan.park))


def _plan(name: str | Scenario, seed: int | None) -> Scenario:
    if isinstance(name, Scenario):
        return name if seed is None else replace(name, seed=seed)
    return scenario(name, 1 if seed is None else seed)


class _Judge:
    """Each step, where the kart is for the scenario's referee: its front along the route (laps counted), its
    footprint along and across the route, what it touches (the car's box, a barrier), how long it has stood
    parked, and how long the referee's verdict has been sure (:meth:`ScenarioReferee.decided`)."""

    def __init__(self, sim: Simulator, referee: ScenarioReferee, policy: LanePolicy, plan: Scenario,
                 track: Track) -> None:
        self.sim, self.referee, self.policy = sim, referee, policy
        self.props: list[tuple[str, np.ndarray]] = [(p.kind, track.prop_corners(p)[:4, :2]) for p in plan.props
                                                    if p.kind == "car"]
        self.props += [("barrier", footprint) for footprint in track.barrier_blocks]
        self.front_m = sim.vehicle.wheelbase_m + sim.vehicle.front_overhang_m
        self.length_m = sim.track.route.length_m
        self.front_s_m, self.parked_s = math.nan, 0.0
        self.decided_s = 0.0  # how long the referee's verdict has been sure
        self._lap_m, self._last_s_m = 0.0, math.nan
        self.states: list[list[Any]] = []  # each change of the rules' state or limit: [time, state, limit km/h]

    def __call__(self, frames: FrameSet, command: ActuatorCommand) -> None:
        sim, length = self.sim, self.length_m
        here = project_onto(sim.track.route, np.array([sim.state.x_m, sim.state.y_m]))
        if here.s_m < self._last_s_m - length / 2:  # a new lap: the route's s starts again
            self._lap_m += length
        self._last_s_m = here.s_m
        self.front_s_m = here.s_m + self._lap_m + self.front_m  # the front along the route, laps counted
        kart = _footprint(sim)
        corners = [project_onto(sim.track.route, corner, here.index) for corner in kart]
        along = [self.front_s_m - self.front_m + math.remainder(c.s_m - here.s_m, length) for c in corners]
        self.referee.step(sim.time_s, self.front_s_m, sim.state.vx_mps, sim.dt_s, _touching(kart, self.props),
                          here.offset_m, np.array([[a, c.offset_m] for a, c in zip(along, corners, strict=True)]))
        behaviour = self.policy.last_behaviour
        if behaviour is not None:
            limit = self.policy.behaviour.limit_kmh
            if not self.states or self.states[-1][1:] != [behaviour.state, limit]:
                self.states.append([round(sim.time_s, 2), behaviour.state, limit])
        if self.referee.decided(sim.time_s, self.front_s_m):
            self.decided_s += sim.dt_s
        parked = behaviour is not None and behaviour.state == "parked"
        self.parked_s = self.parked_s + sim.dt_s if parked and abs(sim.state.vx_mps) < 0.05 else 0.0


def _verdict_line(name: str, referee: ScenarioReferee) -> list[tuple[str, bool]]:
    """The video's line for the scenario: its faults so far (an alarm), or none."""
    faults = referee.faults
    return [(f"{name}: " + ("; ".join(faults) if faults else "no fault so far"), bool(faults))]


def _footprint(sim: Simulator) -> np.ndarray:
    """The kart's footprint's corners in the world (4 x 2, in order)."""
    x0, x1, y0, y1 = sim.vehicle.footprint_body()
    c, s = math.cos(sim.state.yaw_rad), math.sin(sim.state.yaw_rad)
    body = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    return body @ np.array([[c, s], [-s, c]]) + [sim.state.x_m, sim.state.y_m]


def _touching(kart: np.ndarray, things: list[tuple[str, np.ndarray]]) -> str:
    """What the kart's footprint overlaps now ('' for nothing): a car's box (corners 0, 1, 3, 2 in order) or a
    barrier's footprint (in order)."""
    for kind, corners in things:
        if footprints_touch(kart, corners[[0, 1, 3, 2]] if kind == "car" else corners):
            return kind
    return ""


def _rules_for(stack: StackConfig, plan: Scenario) -> LanePolicyConfig:
    """The lane pipeline with the event's rules, set for the scenario (what it holds, where to park)."""
    behaviour = replace(stack.lane_policy.behaviour, overtake=plan.overtake, park=plan.park,
                        park_after_m=plan.park_after_m, start_on_green=plan.start_on_green, limit_kmh=plan.limit_kmh)
    return replace(stack.lane_policy, events=True, speed_mps=SCENARIO_SPEED_KMH / 3.6, behaviour=behaviour)


def _course_for(plan: Scenario) -> Track:
    """The venue track with the scenario's props, barriers and dashed lines, starting where the plan says."""
    spec = load_track_spec(plan.track)
    track = build_track(replace(spec, props=plan.props, barrier_blocks=spec.barrier_blocks + plan.barriers,
                                dashed=spec.dashed + plan.dashed))
    return replace(track, spec=replace(track.spec, start_s_m=start_pose_s(track, plan)))


class _Until:
    """The simulator as a frame source that ends once ``done()`` says so."""

    def __init__(self, sim: Simulator, done: Callable[[], bool]) -> None:
        self.sim, self.done = sim, done

    def read(self) -> FrameSet | None:
        return None if self.done() else self.sim.read()

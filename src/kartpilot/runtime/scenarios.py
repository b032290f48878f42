"""One of the event's scenarios, closed loop: the lane pipeline with the event's rules on the simulated kart, and
the scenario's referee (:mod:`kartpilot.sim.scenarios`)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np

from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.runtime.config import StackConfig, load_stack_config
from kartpilot.runtime.lane_policy import LanePolicy
from kartpilot.runtime.loop import run_loop
from kartpilot.sim.scenarios import ScenarioReferee, scenario, start_pose_s
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import build_track, load_track_spec, project_onto

__all__ = ["SCENARIO_SPEED_KMH", "run_scenario"]

SCENARIO_SPEED_KMH = 15.0
"""The speed mode the scenarios run at (the event's limits are 10 to 20 km/h)."""


def run_scenario(name: str, seed: int, stack: StackConfig | None = None, camera_rate_hz: float = 15.0
                 ) -> dict[str, Any]:
    """Drive one scenario on one seed; its result in the session result's ``scenarios`` form (``name``,
    ``seed``, ``passed``, ``faults``). The kart's measured speed (its 0x440 report) is the simulator's."""
    cv2.setNumThreads(1)
    plan = scenario(name, seed)
    stack = stack or load_stack_config(None, "kart")
    policy_config = replace(stack.lane_policy, events=True, speed_mps=SCENARIO_SPEED_KMH / 3.6,
                            behaviour=replace(stack.lane_policy.behaviour,
                                              start_on_green=plan.start_on_green, limit_kmh=plan.limit_kmh))
    spec = load_track_spec("lelystad")
    track = build_track(replace(spec, props=plan.props))
    track = replace(track, spec=replace(track.spec, start_s_m=start_pose_s(track, plan)))
    config = SimConfig(track="lelystad", vehicle="sdc-kart", seed=seed, camera_rate_hz=camera_rate_hz,
                       speed_mode_mps=SCENARIO_SPEED_KMH / 3.6, max_time_s=plan.duration_s)
    referee = ScenarioReferee(plan)
    with Simulator(config, track=track) as sim:
        policy = LanePolicy(sim.cameras, policy_config, camera_rate_hz, sim.vehicle.max_steer_rad)
        front = sim.vehicle.wheelbase_m + sim.vehicle.front_overhang_m
        where = {"s": 0.0}

        def step(frames: FrameSet) -> ActuatorCommand:
            policy.measured_speed_mps = sim.state.vx_mps
            return policy(frames)

        def judge(frames: FrameSet, command: ActuatorCommand) -> None:
            where["s"] = project_onto(sim.track.route, np.array([sim.state.x_m, sim.state.y_m])).s_m + front
            referee.step(sim.time_s, where["s"], sim.state.vx_mps, sim.dt_s)

        run_loop(sim, step, sim, on_step=judge)
        result = referee.result(where["s"])
        if sim.referee.disqualified:
            result["faults"].append(str(sim.referee.reason))
            result["passed"] = False
    return result

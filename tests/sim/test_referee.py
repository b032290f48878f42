import math

import numpy as np
import pytest

from kartpilot.control.pure_pursuit import pure_pursuit_steer
from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.runtime.loop import run_loop
from kartpilot.sim.drivers import CenterlineDriver, CenterlineDriverConfig, CommandsDriver
from kartpilot.sim.simulator import SimConfig, Simulator
from kartpilot.sim.track import project_onto


def physics_only(track: str, vehicle: str = "rc-kart", **kwargs) -> Simulator:
    return Simulator(SimConfig(track=track, vehicle=vehicle, render_images=False, **kwargs))


@pytest.mark.parametrize(("track", "vehicle", "speed"), [("utrack", "rc-kart", 2.0), ("sdc-assen", "sdc-kart", 8.0)])
def test_centerline_driver_completes_a_lap_without_disqualification(track, vehicle, speed):
    with physics_only(track, vehicle) as sim:
        run_loop(sim, CenterlineDriver(sim, CenterlineDriverConfig(speed_mps=speed)), sim)
        result = sim.result(1.0)
    print(result)
    assert result.finished and not result.disqualified, result.reason
    assert result.laps_completed == 1 and result.cones_hit == 0
    assert result.distance_m == pytest.approx(sim.track.route.length_m, rel=0.02)
    assert result.lap_time_s == pytest.approx(result.distance_m / speed, rel=0.1)
    assert result.max_center_offset_m < 0.25


def test_leaving_the_lane_is_disqualified_where_the_tyre_crosses_the_boundary():
    """Constant left steer from the start of straight20: the front-left tyre's path is a circle,
    so the place where it reaches the boundary (0.75 m left of the centre) is known in closed form."""
    steer = 0.05
    with physics_only("straight20", show_cones=False) as sim:
        run_loop(sim, lambda f: ActuatorCommand(f.stamp_ns, steer, 0.0, 0.0), sim, max_steps=1)
        sim.state = type(sim.state)(x_m=sim.state.x_m, y_m=0.0, yaw_rad=0.0, vx_mps=0.62, steer_rad=steer)
        run_loop(sim, lambda f: ActuatorCommand(f.stamp_ns, steer, 0.1, 0.0), sim)
        result = sim.result(1.0)
    assert result.disqualified and "left the track on the left" in result.reason
    radius = sim.vehicle.wheelbase_m / math.tan(steer)  # rear axle's circle, centre at (x0, radius)
    half_kart, half_lane, wheelbase = sim.vehicle.width_m / 2, 0.75, sim.vehicle.wheelbase_m
    # front-left tyre at body (L, w/2): its distance from the circle's centre is constant
    r_tyre = math.hypot(wheelbase, radius - half_kart)
    # it reaches y = half_lane where (x - xc)^2 + (half_lane - radius)^2 = r_tyre^2
    dx = math.sqrt(r_tyre**2 - (radius - half_lane) ** 2)
    x0 = sim.track.start_pose()[0] + 0.62 * sim.dt_s  # one step was driven before the reset
    assert result.disqualified_at_xy_m[1] == pytest.approx(half_lane, abs=0.03)
    assert result.disqualified_at_xy_m[0] == pytest.approx(x0 + dx, abs=0.1)


def test_touching_a_painted_line_and_hitting_a_cone_disqualify():
    with physics_only("sdc-assen", "sdc-kart") as sim:
        run_loop(sim, CenterlineDriver(sim, CenterlineDriverConfig(speed_mps=3.0, edge_offset_m=-2.2)), sim)
        result = sim.result(1.0)
    assert result.disqualified and "touched the right line" in result.reason
    with physics_only("utrack") as sim:
        # no trim: the run is to cross the line where a cone stands
        driver = CenterlineDriverConfig(speed_mps=1.0, edge_offset_m=0.5, trim_gain_rad_per_m_s=0.0)
        run_loop(sim, CenterlineDriver(sim, driver), sim)
        result = sim.result(1.0)
    assert result.disqualified and result.cones_hit == 1 and "cone" in result.reason


def test_taking_the_branch_at_the_split_is_a_wrong_route():
    with physics_only("sdc-assen", "sdc-kart") as sim:
        branch = sim.track.branches[0]
        route_driver = CenterlineDriver(sim, CenterlineDriverConfig(speed_mps=5.0))

        def follow_branch(frames: FrameSet) -> ActuatorCommand:
            state = sim.state
            here = project_onto(branch, np.array([state.x_m, state.y_m]))
            if here.index == 0 or abs(here.offset_m) > 3.0:
                return route_driver(frames)
            target = branch.xy_m[min(here.index + 100, len(branch.s_m) - 1)]
            steer = pure_pursuit_steer(state.x_m, state.y_m, state.yaw_rad, *target, sim.vehicle.wheelbase_m)
            return ActuatorCommand(frames.stamp_ns, steer, 0.3, 0.0)

        run_loop(sim, follow_branch, sim)
        result = sim.result(1.0)
    assert result.disqualified and "wrong route" in result.reason
    assert 200 < result.disqualified_at_s_m < 300


def test_commands_driver_replays_by_time_then_stops():
    commands = [ActuatorCommand(1_000_000_000 + k * 100_000_000, 0.01 * k, 0.5, 0.0) for k in range(5)]
    driver = CommandsDriver(commands)
    assert driver(FrameSet(0, 5_000, {})).steer_rad == 0.0
    assert driver(FrameSet(1, 5_000 + 250_000_000, {})).steer_rad == pytest.approx(0.02)
    assert driver(FrameSet(2, 5_000 + 3_000_000_000, {})) == ActuatorCommand.stop(5_000 + 3_000_000_000)

"""The venue track (lelystad) with the real kart's camera model: the real kart's preset sees the rendered lines
where the track's geometry puts them, and drives the S-bend closed loop; a simulated drive takes its track's
lane preset."""

import numpy as np
import pytest

from kartpilot.core.geometry import invert_pose, transform_points
from kartpilot.perception.lanes import detect_lanes
from kartpilot.runtime.config import load_stack_config, sim_lane_preset
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.dynamics import VehicleState
from kartpilot.sim.simulator import SimConfig, Simulator


def _column(boundary_xy: np.ndarray, pose_world_cam: np.ndarray, camera, row: float) -> float | None:
    """The boundary's column at ``row`` (its nearest stretch ahead of the camera), None if not in view."""
    cam = transform_points(invert_pose(pose_world_cam), np.column_stack([boundary_xy, np.zeros(len(boundary_xy))]))
    ahead = (cam[:, 2] > 0.3) & (cam[:, 2] < 30)
    px = camera.project(np.where(ahead[:, None], cam, 1.0))
    best = None
    for k in np.flatnonzero(ahead[:-1] & ahead[1:]):
        (x0, y0), (x1, y1) = px[k], px[k + 1]
        if (y0 - row) * (y1 - row) <= 0 and y0 != y1 and (best is None or cam[k, 2] < best[0]):
            best = (cam[k, 2], x0 + (row - y0) * (x1 - x0) / (y1 - y0))
    return float(best[1]) if best is not None and 0 <= best[1] < camera.width_px else None


def test_the_real_kart_preset_finds_the_rendered_venue_lines_where_they_are():
    preset = load_stack_config(None, "kart").lane_policy.lanes
    with Simulator(SimConfig(track="lelystad", vehicle="sdc-kart", seed=3, cameras=("center",))) as sim:
        route, camera = sim.track.route, sim.cameras["center"]
        assert (camera.width_px, camera.height_px) == (848, 480)
        checked = 0
        for s, offset in ((10.0, 0.0), (20.0, 0.3), (37.0, -0.2), (150.0, 0.0)):  # a straight, the bend, the zebra
            i = route.index_at(s)
            x, y = route.xy_m[i] + offset * route.normal()[i]
            sim.state = VehicleState(x_m=float(x), y_m=float(y), yaw_rad=float(route.heading_rad[i]))
            frame = sim.read()
            observation = detect_lanes(frame.images["center"], preset)
            assert observation.both_detected, s
            pose = sim.camera_poses["center"][-1]
            for side in ("left", "right"):
                curve = getattr(observation, f"{side}_curve")
                for row in (300.0, 360.0, 420.0):
                    truth = _column(route.boundary(side), pose, camera, row)
                    if truth is not None:
                        assert abs(float(curve.x_at(row)) - truth) < 12.0, (s, side, row)
                        checked += 1
        assert checked >= 8


@pytest.mark.slow
def test_the_real_kart_preset_drives_the_venue_s_bend_closed_loop():
    stack = load_stack_config(None, sim_lane_preset(None, "lelystad"))
    config = SimConfig(track="lelystad", vehicle="sdc-kart", seed=4, speed_mode_mps=15 / 3.6, camera_rate_hz=10.0,
                       max_time_s=24.0)
    result = run_simulation(config, "lanes", stack=stack).result
    print(result)
    assert not result.disqualified, result.reason
    assert result.distance_m > 60.0  # through the S-bend (40 to 56 m; the start is at 5 m)


def test_a_simulated_drive_takes_its_track_s_lane_preset():
    assert sim_lane_preset(None, "lelystad") == "kart"
    assert sim_lane_preset(None, "sdc-assen") == "kart-sim"
    assert sim_lane_preset("dashcam", "lelystad") == "dashcam"


def test_scenario_props_are_rendered_as_they_are_and_their_truth_comes_with_each_frame():
    """A signal head that turns from red to green, a 20 km/h sign, a person walking across and the car: each
    in the exact truth with its state and place; the traffic-light detector reads the rendered phase."""
    from kartpilot.perception.detect import DetectorConfig, detect_classical
    from kartpilot.perception.signals import detect_traffic_lights
    from kartpilot.sim.track import PROP_SIZES_M, Prop

    props = (Prop(kind="traffic_light", s_m=30.5, offset_m=-2.0, phases=(("red", 1.0), ("green", 10.0))),
             Prop(kind="speed_sign", s_m=40.0, offset_m=-2.2, value_kmh=20),
             Prop(kind="person", s_m=26.0, offset_m=-2.5, walk_to_offset_m=2.5, walk_start_s=1.0,
                  walk_speed_mps=1.0),
             Prop(kind="car", s_m=36.0, offset_m=0.0))
    with Simulator(SimConfig(track="lelystad", vehicle="sdc-kart", seed=1, cameras=("center",), props=props,
                             camera_rate_hz=2.0)) as sim:
        route = sim.track.route
        i = route.index_at(18.0)
        sim.state = VehicleState(x_m=float(route.xy_m[i, 0]), y_m=float(route.xy_m[i, 1]),
                                 yaw_rad=float(route.heading_rad[i]))
        states = []
        for _ in range(4):  # t = 0, 0.5, 1.0, 1.5 s: red, red, green, green
            truth = {d.label: d for d in sim.object_truth("center")}
            frame = sim.read()
            seen = detect_traffic_lights(frame.images["center"], camera=sim.cameras["center"])
            states.append((truth["traffic_light"].state, [d.state for d in seen]))
            for light in seen:  # placed from its lamp's size: within 10 % (12.5 m ahead)
                assert light.distance_m == pytest.approx(truth["traffic_light"].distance_m, rel=0.1)
            # the car's distance is to the face the kart meets, half its length before its middle
            assert truth["car"].distance_m == pytest.approx(36.0 - 18.0 - PROP_SIZES_M["car"][1] / 2, abs=0.3)
            assert truth["stop_line"].distance_m == pytest.approx(30.0 - 18.0, abs=0.3)
            sim.step_index += 1
        assert states == [("red", ["red"]), ("red", ["red"]), ("green", ["green"]), ("green", ["green"])]
        assert truth["speed_sign"].state == "20"
        # the person has walked from 2.5 m right toward the left
        assert truth["person"].lateral_m == pytest.approx(-2.0, abs=0.05)
        # the upright-thing finder sees the rendered person and car where they are (within 10 %)
        found = {d.label: d for d in detect_classical(frame.images["center"], sim.cameras["center"],
                                                      DetectorConfig(people=False))}
        for label in ("person", "car"):
            print(label, "truth", round(truth[label].distance_m, 2), "found", round(found[label].distance_m, 2))
            assert found[label].distance_m == pytest.approx(truth[label].distance_m, rel=0.1)


@pytest.mark.parametrize(("label", "before_m"), [("stop_line", 5.0), ("stop_line", 13.0), ("crosswalk", 6.0),
                                                 ("crosswalk", 13.0)])
def test_rendered_stop_lines_and_zebras_are_found_at_their_near_edge(label, before_m):
    """The detectors against the renderer's exact truth: 13 m before the zebra, the road bends and the crossing
    lies 3 m or more to the side, where a search straight ahead would not see it; only the mark that is there is
    reported."""
    from kartpilot.perception.detect import DetectorConfig, detect_classical

    with Simulator(SimConfig(track="lelystad", vehicle="sdc-kart", seed=1, cameras=("center",))) as sim:
        kind = "zebra" if label == "crosswalk" else label  # the track's paint, the detectors' class
        mark = next(m for m in sim.track.spec.road_marks if m.kind == kind)
        route = sim.track.route
        i = route.index_at(mark.s_m - before_m)
        sim.state = VehicleState(x_m=float(route.xy_m[i, 0]), y_m=float(route.xy_m[i, 1]),
                                 yaw_rad=float(route.heading_rad[i]))
        truth = next(d for d in sim.object_truth("center") if d.label == label)
        frame = sim.read()
        found = [d for d in detect_classical(frame.images["center"], sim.cameras["center"],
                                             DetectorConfig(people=False)) if d.label in ("stop_line", "crosswalk")]
        lane_m = sim.track.spec.width_m
    # the paint reaches across the lane: a stop line from one side to the other, a zebra's stripes (a stripe and a
    # gap each) to its outer stripes' outer edges
    spacing = 2 * mark.stripe_m
    paint_m = lane_m if label == "stop_line" else (lane_m // spacing - 1) * spacing + mark.stripe_m
    print(label, "truth", round(truth.distance_m, 2), round(truth.lateral_m, 2),
          "found", [(d.label, round(d.distance_m, 2), round(d.lateral_m, 2), round(d.width_m, 2)) for d in found])
    assert [d.label for d in found] == [label]
    assert found[0].distance_m == pytest.approx(truth.distance_m, abs=0.05 * truth.distance_m)
    if before_m < 10:
        assert found[0].width_m == pytest.approx(paint_m, rel=0.1)
    if label == "crosswalk" and before_m > 10:
        assert truth.lateral_m > 2.0 and found[0].lateral_m > 1.0


def test_rendered_barriers_their_parking_bay_and_a_speed_sign_are_found_where_they_are():
    """A bay between two barriers beside the road (the parking scenario's, 7 m free) and a 20 km/h sign, rendered
    with their exact truth: the barriers placed at their near end, the bay's free length and start, the sign's
    value and distance, each within 10 %."""
    from dataclasses import replace

    from kartpilot.perception.detect import DetectorConfig, detect_classical
    from kartpilot.sim.track import BarrierBlock, Prop, build_track, load_track_spec

    spec = load_track_spec("lelystad")
    bay = (BarrierBlock(side="right", s_m=19.6, offset_m=0.3, length_m=0.4, depth_m=1.5),
           BarrierBlock(side="right", s_m=27.0, offset_m=0.3, length_m=0.4, depth_m=1.5))
    sign = Prop(kind="speed_sign", s_m=22.0, offset_m=-2.3, value_kmh=20)
    track = build_track(replace(spec, props=(sign,), barrier_blocks=spec.barrier_blocks + bay))
    with Simulator(SimConfig(track="lelystad", vehicle="sdc-kart", seed=1, cameras=("center",)), track=track) as sim:
        i = sim.track.route.index_at(11.0)
        sim.state = VehicleState(x_m=float(sim.track.route.xy_m[i, 0]), y_m=float(sim.track.route.xy_m[i, 1]),
                                 yaw_rad=float(sim.track.route.heading_rad[i]))
        truth = sim.object_truth("center")
        found = detect_classical(sim.read().images["center"], sim.cameras["center"], DetectorConfig(people=False))
    near, far = sorted((d for d in truth if d.label == "barrier" and d.distance_m < 20), key=lambda d: d.distance_m)
    barriers = sorted((d for d in found if d.label == "barrier"), key=lambda d: d.distance_m)
    bays = [d for d in found if d.label == "parking_bay"]
    signs = [d for d in found if d.label == "speed_sign"]
    print("barriers", [(round(d.distance_m, 2), round(d.far_m, 2)) for d in barriers], "truth",
          [round(near.distance_m, 2), round(far.distance_m, 2)], "bays",
          [(d.state, round(d.distance_m, 2)) for d in bays], "signs",
          [(d.state, round(d.distance_m, 2)) for d in signs])
    assert [round(d.distance_m / t.distance_m, 1) for d, t in zip(barriers, (near, far), strict=True)] == [1.0, 1.0]
    assert len(bays) == 1 and float(bays[0].state) == pytest.approx(7.0, rel=0.1)
    assert bays[0].distance_m == pytest.approx(near.distance_m + 0.4, rel=0.1)  # the near barrier's far end
    truth_sign = next(d for d in truth if d.label == "speed_sign")
    assert [d.state for d in signs] == ["20"] and signs[0].distance_m == pytest.approx(truth_sign.distance_m, rel=0.1)

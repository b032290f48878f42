import math

import numpy as np
import pytest

from kartpilot.core.config import merge_config
from kartpilot.core.errors import ConfigError
from kartpilot.sim.track import (
    CenterlineSpec,
    Segment,
    TrackSpec,
    build_track,
    bundled_tracks,
    load_track,
    project_onto,
    scenery_boxes,
)


def test_bundled_tracks_are_the_documented_ones():
    assert {"utrack", "sdc-assen", "straight20"} <= set(bundled_tracks())


def test_utrack_is_a_400m_oval_with_cones_every_metre_on_both_sides():
    track = load_track("utrack")
    expected = 2 * 84.39 + 2 * math.pi * 37.11  # lane-1 centre line
    assert track.route.length_m == pytest.approx(expected, abs=0.1)
    assert track.closed
    left = [c for c in track.cones if c.side == "left"]
    right = [c for c in track.cones if c.side == "right"]
    assert len(left) == pytest.approx(track.route.length_m, abs=2)
    gaps = np.hypot(*np.diff(np.array([c.xy_m for c in right]), axis=0).T)
    assert np.median(gaps) == pytest.approx(1.0, abs=0.02)
    # cones stand on the lane's boundaries, 1.22 m apart
    p = project_onto(track.route, np.array(left[5].xy_m))
    assert p.offset_m == pytest.approx(0.61, abs=0.01)


def test_sdc_assen_has_a_crossing_a_split_and_lines_with_gaps_there():
    track = load_track("sdc-assen")
    assert 900 < track.route.length_m < 1100
    assert len(track.branches) == 1 and len(track.curbs) == 4 and track.barriers
    # the route crosses itself: two samples far apart along s are within a metre of each other
    xy, s = track.route.xy_m, track.route.s_m
    near_origin = s[np.hypot(*xy.T) < 0.5]
    assert near_origin.max() - near_origin.min() > 400
    # at the crossing the route's lines are left out, elsewhere they are painted
    crossing = int(np.argmin(np.hypot(*xy.T) + 1e9 * (s < 400)))  # the second pass over the origin
    assert not track.marked("left", crossing) and not track.marked("right", crossing)
    assert track.marked("left", track.start_index + 100)
    # turns both ways
    assert track.route.curvature_1pm.max() > 0.02 and track.route.curvature_1pm.min() < -0.02
    widths = 2 * track.route.half_width_m
    assert widths.min() == pytest.approx(4.0, abs=0.05) and widths.max() == pytest.approx(6.0, abs=0.05)


def test_projection_window_keeps_progress_on_the_right_pass_of_a_crossing():
    track = load_track("sdc-assen")
    route = track.route
    i_late = int(np.flatnonzero(np.abs(route.s_m - 500.1) < 0.03)[0])  # the second pass over the crossing
    point = route.xy_m[i_late]
    assert abs(project_onto(route, point, hint=i_late - 10).s_m - route.s_m[i_late]) < 0.1
    assert abs(project_onto(route, point, hint=5).s_m - route.s_m[5]) < 1.0  # the first pass


def test_segments_that_do_not_close_are_rejected():
    spec = TrackSpec(centerline=CenterlineSpec(closed=True, segments=(Segment(straight_m=10.0),
                                                                      Segment(radius_m=5.0, angle_deg=90.0))))
    with pytest.raises(ConfigError, match="closed"):
        build_track(spec)


def test_a_centre_line_of_repeated_points_is_refused_not_a_traceback():
    """A track of zero length (every control point the same) ended in scipy's 'Invalid inputs'."""
    for points in (((0.0, 0.0),) * 4, ((0.0, 0.0), (10.0, 0.0), (10.0, 0.0), (10.0, 10.0))):
        with pytest.raises(ConfigError, match=r"points_m\[\d\] repeats the point before it"):
            build_track(TrackSpec(centerline=CenterlineSpec(closed=False, points_m=points)))
    square = ((0.0, 0.0), (20.0, 0.0), (20.0, 20.0), (0.0, 20.0))
    again = build_track(TrackSpec(centerline=CenterlineSpec(closed=True, points_m=(*square, square[0]))))
    assert again.route.length_m == pytest.approx(
        build_track(TrackSpec(centerline=CenterlineSpec(closed=True, points_m=square))).route.length_m)


def test_a_typo_in_a_track_file_names_the_key():
    with pytest.raises(ConfigError, match=r"track\.left\.cone_gap"):
        merge_config(TrackSpec(), {"left": {"cone_gap": 2.0}}, "track")
    with pytest.raises(ConfigError, match=r"track.centerline.segments\[0\].radius"):
        merge_config(TrackSpec(), {"centerline": {"segments": [{"radius": 3}]}}, "track")


def test_unknown_track_name_lists_the_bundled_ones():
    with pytest.raises(ConfigError, match="utrack"):
        load_track("monza")


def test_track_file_from_a_path(tmp_path):
    path = tmp_path / "oval.yaml"
    path.write_text("name: oval\ncenterline:\n  segments:\n    - {radius_m: 10, angle_deg: 360}\nwidth_m: 2\n")
    track = load_track(path)
    assert track.route.length_m == pytest.approx(2 * math.pi * 10, abs=0.05)
    assert track.route.curvature_1pm.mean() == pytest.approx(0.1, abs=1e-3)


def test_a_track_is_built_once_and_no_user_can_change_it_for_the_next(tmp_path):
    first = load_track("sdc-assen")
    assert load_track("sdc-assen") is first  # the same description: the track built before
    for array in (first.route.xy_m, first.route.half_width_m, first.lines[0], first.route_marked_left,
                  first.curbs[0][0], first.barriers[0] if first.barriers else first.lines[-1]):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 0
    path = tmp_path / "short.yaml"
    path.write_text("name: short\ncenterline: {closed: false, segments: [{straight_m: 30}]}\n")
    short = load_track(path)
    path.write_text("name: short\ncenterline: {closed: false, segments: [{straight_m: 40}]}\n")
    assert load_track(path).route.length_m > short.route.length_m + 9  # a file changed: built again


def test_scenery_stands_beside_the_road_never_on_it():
    track = load_track("sdc-assen")
    boxes = scenery_boxes(track, 15.0, seed=3)
    assert len(boxes) > 0.5 * track.route.length_m / 15.0
    assert not len(scenery_boxes(track, 0.0, seed=3))
    gaps = []
    for x, y, yaw, width, depth, _ in boxes:
        c, s = np.cos(yaw), np.sin(yaw)
        corners = np.array([[x + dx * c - dy * s, y + dx * s + dy * c]
                            for dx in (-width / 2, width / 2) for dy in (-depth / 2, depth / 2)])
        centre_line_gap = np.min(np.linalg.norm(track.route.xy_m[None] - corners[:, None], axis=2))
        gaps.append(centre_line_gap - track.route.half_width_m.max())
    assert min(gaps) > track.spec.barrier_offset_m  # behind the tyre wall


def test_lelystad_is_the_venue_lane_with_an_s_bend_road_marks_dashes_and_barriers():
    track = load_track("lelystad")
    assert track.closed and track.spec.sky == "overcast"
    widths = 2 * track.route.half_width_m
    assert np.allclose(widths, 3.0)
    # an S-bend of 10 m radius each way
    curvature = track.route.curvature_1pm
    assert curvature.min() == pytest.approx(-0.1, abs=0.01) and curvature.max() >= 0.099
    # a stop line (one bar across the lane) and a zebra (stripes), all on the road
    assert len(track.road_marks) == 1 + 3
    for polygon in track.road_marks:
        centre = polygon.mean(axis=0)
        assert abs(project_onto(track.route, centre).offset_m) < 1.5
    # the barriers stand beside the lane, outside its lines
    for footprint in track.barrier_blocks:
        p = project_onto(track.route, footprint.mean(axis=0))
        assert abs(p.offset_m) > 1.5 + 0.5
    # the dashed stretch leaves gaps in the left line only; the boundary still counts there
    i = track.route.index_at(176.0 + 4.5)  # in the first gap
    left_points = np.vstack([line for line in track.lines])
    gap_point = track.route.boundary("left")[i]
    assert np.min(np.hypot(*(left_points - gap_point).T)) > 0.5
    assert track.marked("left", i)


def test_dashes_road_marks_and_barriers_are_checked():
    with pytest.raises(ConfigError, match="dash_m"):
        merge_config(TrackSpec(), {"dashed": [{"side": "left", "from_s_m": 0, "to_s_m": 10, "gap_m": 0}]}, "track")
    with pytest.raises(ConfigError, match="stripe_m"):
        merge_config(TrackSpec(), {"road_marks": [{"kind": "zebra", "stripe_m": -1}]}, "track")
    with pytest.raises(ConfigError, match="height_m"):
        merge_config(TrackSpec(), {"barrier_blocks": [{"height_m": 0}]}, "track")

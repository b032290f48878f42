"""The camera's pitch measured from the lane's boundaries: lanes on flat ground seen through a mount pitched off the
rig's, fitted as the paint finder fits them, read back; and what must not count (a bend, a junction, a frame that
disagrees with the others)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from tests.conftest import data_path

from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import invert_pose, pitched_mount, transform_points
from kartpilot.core.vehicle import get_vehicle
from kartpilot.perception.horizon import HorizonConfig, HorizonEstimator, bend_deg, pitch_off_deg
from kartpilot.perception.lanes import LaneLine, LaneObservation, detect_lanes
from kartpilot.perception.obstacles import horizon_row
from kartpilot.perception.paint import LaneCurve, fit_curve
from kartpilot.runtime.lane_policy import LANE_PRESETS, LanePolicy

RIG = get_vehicle("sdc-kart").camera("center")
HORIZON_ROW = horizon_row(RIG)


def _curve(points_body: np.ndarray, pitch_deg: float) -> LaneCurve | None:
    """A boundary on the ground (body-frame points) as the camera, mounted ``pitch_deg`` further down than the rig
    says, sees it, fitted with the rig's horizon as the paint finder fits it."""
    camera = RIG.on_body(pitched_mount(RIG.pose_body_cam_array, pitch_deg))
    cam = transform_points(invert_pose(camera.pose_body_cam_array), points_body)
    seen = cam[:, 2] > 0.5
    pixels = camera.project(cam[seen])
    inside = (pixels[:, 0] >= 0) & (pixels[:, 0] < RIG.width_px) & (pixels[:, 1] < RIG.height_px) & (
        pixels[:, 1] > HORIZON_ROW + 5)
    xs, ys = pixels[inside, 0], pixels[inside, 1]
    coef = fit_curve(xs, ys, HORIZON_ROW)
    if coef is None:
        return None
    return LaneCurve(*coef, horizon_y=HORIZON_ROW, y_far=float(ys.min()), y_near=float(ys.max()), support=1.0)


def _lane(pitch_deg: float, radius_m: float = math.inf, offset_m: float = 0.0, yaw_deg: float = 0.0,
          half_width_m: float = 1.5) -> LaneObservation:
    """A lane of two boundaries ``half_width_m`` either side of a centre line that is straight or bends with
    ``radius_m`` (left: positive), the kart ``offset_m`` left of it and turned ``yaw_deg`` to it."""
    s = np.linspace(1.0, 30.0, 300)
    curves = []
    for side in (1.0, -1.0):
        if math.isinf(radius_m):
            x, y = s, np.full_like(s, side * half_width_m)
        else:
            r = radius_m - side * half_width_m
            x, y = r * np.sin(s / radius_m), radius_m - r * np.cos(s / radius_m)
        y = y - offset_m
        c, sn = math.cos(math.radians(-yaw_deg)), math.sin(math.radians(-yaw_deg))
        body = np.column_stack([c * x - sn * y + 1.0, sn * x + c * y, np.zeros_like(x)])
        curves.append(_curve(body, pitch_deg))
    left, right = curves
    line = LaneLine(0.0, 0.0, 0.0, 0.0)
    return LaneObservation(RIG.width_px, RIG.height_px, line, line, "detected", "detected", None, 1.0,
                           left_curve=left, right_curve=right)


@pytest.mark.parametrize("pitch_deg", [-1.5, -0.5, 0.7, 1.5])
def test_a_straight_lane_gives_the_pitch_the_mount_is_off_by(pitch_deg):
    estimator = HorizonEstimator(RIG)
    for k in range(20):  # the kart weaving a little in its lane
        camera = estimator.update(_lane(pitch_deg, offset_m=0.3 * math.sin(k), yaw_deg=2.0 * math.cos(k)))
    print(f"mount off by {pitch_deg:+.2f} deg: measured {estimator.pitch_deg:+.3f}")
    assert estimator.pitch_deg == pytest.approx(pitch_deg, abs=0.05)
    # the camera it gives is the one mounted: a point on the ground lands where the pitched camera sees it
    truth = RIG.on_body(pitched_mount(RIG.pose_body_cam_array, pitch_deg))
    point = np.array([[8.0, -1.0, 0.0]])
    assert np.allclose(camera.project(transform_points(invert_pose(camera.pose_body_cam_array), point)),
                       truth.project(transform_points(invert_pose(truth.pose_body_cam_array), point)), atol=1.0)


def test_a_gentle_bend_reads_the_same_pitch():
    """The boundaries' tangents at one row are parallel on the ground in a bend too: a 60 m radius either way."""
    for radius in (60.0, -60.0):
        estimator = HorizonEstimator(RIG)
        for _ in range(20):
            estimator.update(_lane(0.8, radius_m=radius))
        assert estimator.pitch_deg == pytest.approx(0.8, abs=0.1), radius


def test_a_tight_bend_or_a_junction_does_not_count():
    """A 12 m radius turns the boundaries' images further than the gate: no frame is kept, the rig's mount stays."""
    tight = _lane(1.0, radius_m=12.0)
    assert max(bend_deg(tight.left_curve), bend_deg(tight.right_curve)) > HorizonConfig().max_bend_deg
    estimator = HorizonEstimator(RIG)
    for _ in range(30):
        camera = estimator.update(tight)
    assert len(estimator.frames) == 0 and estimator.pitch_deg == 0.0 and camera is RIG


def test_frames_that_disagree_leave_the_mount_as_it_was():
    """Half the frames say 1.5 deg, half -1.0: their middle half spreads wider than the gate, nothing is used; one
    frame off the rest does not move a measured pitch."""
    estimator = HorizonEstimator(RIG)
    for k in range(30):
        estimator.update(_lane(1.5 if k % 2 else -1.0))
    assert estimator.pitch_deg == 0.0 and estimator.camera is RIG
    steady = HorizonEstimator(RIG)
    for _ in range(20):
        steady.update(_lane(0.5))
    measured = steady.pitch_deg
    steady.update(_lane(2.5))
    assert steady.pitch_deg == pytest.approx(measured, abs=0.02)


def test_no_lane_and_a_switched_off_estimator_keep_the_rig():
    estimator = HorizonEstimator(RIG, HorizonConfig(enabled=False))
    for _ in range(20):
        assert estimator.update(_lane(1.0)) is RIG
    assert HorizonEstimator(RIG).update(None) is RIG


def test_above_the_drawn_horizon_the_view_is_lower():
    column = RIG.cx_px
    assert pitch_off_deg(RIG, (column, HORIZON_ROW)) == pytest.approx(0.0, abs=1e-6)
    assert pitch_off_deg(RIG, (column, HORIZON_ROW - 10)) > 0 > pitch_off_deg(RIG, (column, HORIZON_ROW + 10))


@pytest.mark.parametrize(("key", "value"), [("ahead_m", 0.0), ("min_frames", 0), ("max_spread_deg", -1.0),
                                            ("max_bend_deg", 120.0), ("max_pitch_deg", math.nan)])
def test_a_bad_setting_names_its_key(key, value):
    with pytest.raises(ConfigError, match=f"horizon.{key}"):
        HorizonConfig(**{key: value})


def test_on_the_real_venue_clip_only_frames_that_agree_count():
    """The real kart's centre camera at the venue (119 frames in bends and at a junction): through the gates, the
    frames kept read one pitch near the team's mount (the paint finder's curves at a junction, let through, read
    -0.8 to +1.5 deg over the same clip), and whatever is used stays near it."""
    lanes = LanePolicy({"center": RIG}, LANE_PRESETS["kart"]).config.lanes
    estimator = HorizonEstimator(RIG)
    paths = sorted(data_path("rdw-kart", "lelystad-2024", "frames").glob("*.jpg"))
    for path in paths:
        estimator.update(detect_lanes(cv2.imread(str(path)), lanes))
    kept = np.array(estimator.frames)
    print(f"{len(kept)} of {len(paths)} real frames kept: {np.round(kept, 2).tolist()} deg")
    assert len(kept) >= 1 and np.ptp(kept) < 0.2 and np.all(np.abs(kept) < 0.5)
    assert abs(estimator.pitch_deg) < 0.5


def test_a_kart_standing_still_counts_one_view_once():
    """At a start line the same view comes over and over: it would agree with itself whatever it read. A frame
    counts once the kart has moved ``spacing_m`` since the last one that did."""
    estimator = HorizonEstimator(RIG)
    for _ in range(40):
        estimator.update(_lane(1.0), moved_m=0.0)
    assert len(estimator.frames) <= 1 and estimator.camera is RIG
    for _ in range(30):  # at 1.5 m/s and 15 frames a second: every third frame counts
        estimator.update(_lane(1.0), moved_m=0.1)
    assert 9 <= len(estimator.frames) <= 11

"""Acceptance figures on real data (skipped with a reason when ../shared/data is absent). VO's drift on every real
clip with truth, and the city drive's stereo-against-monocular distance, are held by the real-accuracy guard
(tests/odometry/test_real_vo_guard.py) to their recorded figures."""

import numpy as np

from kartpilot.odometry.run import run_vo
from kartpilot.odometry.stereo_vo import StereoVO
from kartpilot.sensors.euroc import EurocSource
from tests.conftest import data_path


def test_euroc_static_platform_stays_within_5_cm() -> None:
    source = EurocSource(data_path("euroc-v101-static"))
    run = run_vo(source.frame_sets(), StereoVO(source.rig), source.name)
    excursion = float(np.linalg.norm(run.trajectory.positions, axis=1).max())
    print(f"\nEuRoC V1_01 static: largest distance from the start {excursion * 100:.2f} cm over {len(source)} frames")
    assert excursion < 0.05


def test_the_real_sdc_kart_s_centre_camera_sees_both_boundaries_at_the_venue(tmp_path) -> None:
    """``kartpilot lanes FRAMES --preset kart`` on the real kart's 119 venue frames (848x480): both boundaries in
    at least 95 % of the frames, and at least 90 % of the hand-made truth points (tests/data, frames 0, 40, 80
    and 118) within 25 px of the reported curve at their rows. The frames are the ones the paint finder was
    developed on: a check that it keeps working, not a held-out figure."""
    import csv
    import json
    from pathlib import Path

    from kartpilot.cli.main import main
    from kartpilot.perception.paint import LaneCurve

    frames = data_path("rdw-kart", "lelystad-2024", "frames")
    out = tmp_path / "lanes.csv"
    assert main(["lanes", str(frames), "--preset", "kart", "--out", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    both = sum(r["left_source"] == r["right_source"] == "detected" for r in rows)
    truth = json.loads((Path(__file__).parent / "data" / "rdw_lelystad_lane_truth.json").read_text())["frames"]
    by_file = {r["file"]: r for r in rows}
    errors = []
    for name, sides in truth.items():
        row = by_file[name]
        for side, points in sides.items():
            if not row[f"{side}_a"]:
                errors += [np.inf] * len(points)
                continue
            curve = LaneCurve(float(row[f"{side}_a"]), float(row[f"{side}_b"]), float(row[f"{side}_c"]),
                              float(row["horizon_y"]), 0.0, 0.0, 0.0)
            errors += [abs(float(curve.x_at(y)) - x) for y, x in points]
    within = float(np.mean(np.asarray(errors) < 25))
    print(f"\nreal SDC kart, Lelystad 2024: both boundaries in {both} of {len(rows)} frames; "
          f"{100 * within:.0f} % of {len(errors)} truth points within 25 px (median {np.median(errors):.1f} px)")
    assert both >= 0.95 * len(rows)
    assert within >= 0.9


def test_the_kart_s_own_body_is_not_a_boundary_in_its_side_cameras() -> None:
    """On the Hanze kart's side cameras (hanze-calibration, 1920x1080), with the body masks drawn on them
    (tests/data/hanze_body_masks.yaml): no boundary the paint finder reports runs over the kart's body, and a
    side camera's search band (placed from the camera's ground calibration, ahead of a camera turned forward)
    lies in the image."""
    from dataclasses import replace
    from pathlib import Path

    import cv2
    import yaml

    from kartpilot.calibration.board import BoardConfig, find_board
    from kartpilot.calibration.ground import calibrate_ground
    from kartpilot.perception.lanes import detect_lanes
    from kartpilot.runtime.lane_policy import LANE_PRESETS, side_search_band

    folder = data_path("rdw-kart", "hanze-calibration")
    masks = yaml.safe_load((Path(__file__).parent / "data" / "hanze_body_masks.yaml").read_text())
    board = BoardConfig(kind="charuco", columns=10, rows=8, square_m=0.115, marker_m=0.086,
                        dictionary="DICT_4X4_100")
    images = {n: cv2.imread(str(folder / f"{n}.jpg")) for n in ("left", "center", "right")}
    mounts = calibrate_ground({n: find_board(im, board, n) for n, im in images.items()},
                              {n: (1920, 1080) for n in images})
    preset = LANE_PRESETS["kart"]
    for side in ("left", "right"):
        camera = replace(mounts[side].camera, body_mask=tuple(tuple(map(tuple, p)) for p in masks[side]))
        mask = camera.body_mask_image()
        assert mask is not None
        observation = detect_lanes(images[side], preset.lanes, body_mask=mask)
        for curve in (observation.left_curve, observation.right_curve):
            if curve is None:
                continue
            rows = np.arange(curve.y_far, curve.y_near, 4.0)
            xs = np.clip(np.asarray(curve.x_at(rows)).astype(int), 0, 1919)
            on_body = float(np.mean(mask[rows.astype(int), xs] > 0))
            print(f"\n{side} camera: a boundary at confidence {observation.confidence:.2f}, "
                  f"{100 * on_body:.0f} % of it on the body")
            assert on_body < 0.1
        (far, near), column = side_search_band(camera, side, preset.near_m, preset.far_m, preset.kart_half_width_m)
        assert 0 <= column < 1920 and 0 <= far < near <= 1080

"""Calibration from board images (real data when present) and rig files."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from tests.conftest import data_path

from kartpilot.calibration.board import BoardConfig, calibrate_mono, calibrate_stereo, find_board, read_views
from kartpilot.calibration.rig import Rig, load_rig, save_rig
from kartpilot.cli.main import main
from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import mount_pose
from kartpilot.core.vehicle import get_vehicle


def opencv_left_fx() -> float:
    storage = cv2.FileStorage(str(data_path("calibration", "opencv-stereo-chessboard", "left_intrinsics.yml")),
                              cv2.FILE_STORAGE_READ)
    return float(storage.getNode("camera_matrix").mat()[0, 0])


def test_stereo_calibration_of_opencvs_sample_set() -> None:
    folder = data_path("calibration", "opencv-stereo-chessboard")
    board = BoardConfig(columns=9, rows=6, square_m=0.025)
    left, _, size = read_views(sorted(folder.glob("left*.jpg")), board)
    right, _, _ = read_views(sorted(folder.glob("right*.jpg")), board)
    stereo = calibrate_stereo(left, right, size)
    reference = opencv_left_fx()
    rows = list(stereo.row_error_px.values())
    print(f"left fx {stereo.left.camera.fx_px:.2f} px (OpenCV's {reference:.2f}), stereo RMS {stereo.rms_px:.3f} px, "
          f"baseline {stereo.baseline_m:.4f} m, rectified rows differ by {np.median(rows):.3f} px (median)")
    assert abs(stereo.left.camera.fx_px / reference - 1.0) < 0.01
    assert stereo.rms_px < 0.5
    assert np.median(rows) < 0.3 and len(stereo.pairs) == 13
    assert stereo.pose_right_left[0, 3] < 0  # the right camera is to the right


def test_mono_calibration_skips_cropped_boards_with_a_message(capsys, tmp_path) -> None:
    folder = data_path("calibration", "udacity-mono-chessboard")
    out = tmp_path / "cam.yaml"
    assert main(["calibrate", "mono", *map(str, sorted(folder.glob("*.jpg"))), "--board", "9x6",
                 "--square", "0.025", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    cropped = [s for s in summary["skipped"] if "whole board is not visible" in s]
    print(f"udacity: {len(summary['used'])} used, {len(summary['skipped'])} skipped, RMS {summary['rms_px']:.3f} px")
    assert len(cropped) == 3
    assert summary["rms_px"] < 1.5
    camera = summary["cameras"]["center"]
    assert set(camera) >= {"fx", "fy", "cx", "cy", "distortion"} and camera["distortion"][0] < 0  # barrel
    rig = load_rig(out)
    assert rig.camera("center").fx_px == pytest.approx(camera["fx"], rel=1e-4)


def test_a_charuco_board_is_found_and_calibrates_a_rendered_camera() -> None:
    board = BoardConfig(kind="charuco", columns=7, rows=5, square_m=0.04)
    flat = board.charuco_board().generateImage((1400, 1000), marginSize=40)
    K = np.array([[800.0, 0, 639.5], [0, 800.0, 359.5], [0, 0, 1]])
    views = []
    # the board (0.28 x 0.20 m, 5 px/mm) seen from a few poses by an ideal camera, warped by its homography
    for k, (rx, ry, tz) in enumerate([(0.0, 0.0, 0.6), (0.3, 0.0, 0.7), (0.0, 0.35, 0.6), (-0.25, 0.2, 0.8),
                                      (0.2, -0.3, 0.65)]):
        R, _ = cv2.Rodrigues(np.array([rx, ry, 0.0]))
        t = np.array([-0.14, -0.10, tz])
        board_to_px = np.array([[0.0002, 0, -40 * 0.0002], [0, 0.0002, -40 * 0.0002], [0, 0, 1.0]])
        H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ board_to_px
        image = cv2.warpPerspective(flat, H, (1280, 720), borderValue=255)
        view = find_board(image, board, f"view{k}")
        assert view is not None and len(view.ids) >= 20
        views.append(view)
    result = calibrate_mono(views, (1280, 720))
    print(f"ChArUco: fx {result.camera.fx_px:.1f} px (true 800), RMS {result.rms_px:.3f} px")
    assert result.camera.fx_px == pytest.approx(800.0, rel=0.02)


def test_rig_files_round_trip_and_name_what_is_wrong(tmp_path) -> None:
    kart = get_vehicle("rc-kart")
    rig = Rig(kart.camera_map, kart.stereo_pair)
    loaded = load_rig(save_rig(rig, tmp_path / "rig.yaml"))
    assert loaded.stereo_pair == ("left", "right")
    assert np.allclose(loaded.camera("left").pose_body_cam_array, kart.camera("left").pose_body_cam_array)
    assert np.allclose(mount_pose(0.4, 0.07, 0.19), kart.camera("left").pose_body_cam_array)
    bad = tmp_path / "bad.yaml"
    bad.write_text("cameras:\n  left: {width_px: 640, height_px: 480, fx_px: 500, fy_px: 500, cx_px: 320, "
                   "cy_px: 240, focal: 3}\n")
    with pytest.raises(CalibrationError, match=r"cameras.left: unknown key.*focal"):
        load_rig(bad)
    bad.write_text("cameras:\n  left: {width_px: 640, height_px: 480, fx_px: 500, fy_px: 500, cx_px: 320, "
                   "cy_px: 240, mount: {x_m: 1, yaw: 3}}\n")
    with pytest.raises(CalibrationError, match=r"mount: unknown key.*yaw"):
        load_rig(bad)
    bad.write_text("cameras:\n  left: {width_px: 640, height_px: 480, fx_px: 500, fy_px: 500, cx_px: 320, "
                   "cy_px: 240}\nstereo_pair: [left, right]\n")
    with pytest.raises(CalibrationError, match="stereo_pair must name two of the cameras"):
        load_rig(bad)
    with pytest.raises(CalibrationError, match="no such rig file"):
        load_rig(tmp_path / "missing.yaml")


def test_calibrate_without_usable_images_says_so(tmp_path, capsys) -> None:
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    assert main(["calibrate", "mono", str(blank), "--out", str(tmp_path / "c.yaml")]) == 1
    assert "only 0 images show the whole board" in capsys.readouterr().err
    assert main(["calibrate", "mono", str(blank), "--board", "nine", "--out", str(tmp_path / "c.yaml")]) == 1
    assert "expected COLUMNSxROWS" in capsys.readouterr().err


def _projected_views(poses: list[tuple[float, float, float, float]]) -> list:
    """A 9x6 board (25 mm squares) seen by an ideal 800 px camera from (rx, ry, tx, tz) poses, exactly."""
    from kartpilot.calibration.board import BoardView

    grid = np.array([[c * 0.025, r * 0.025, 0.0] for r in range(6) for c in range(9)])
    K = np.array([[800.0, 0, 639.5], [0, 800.0, 359.5], [0, 0, 1]])
    views = []
    for k, (rx, ry, tx, tz) in enumerate(poses):
        pixels, _ = cv2.projectPoints(grid, np.array([rx, ry, 0.0]), np.array([tx, -0.06, tz]), K, None)
        views.append(BoardView(f"view{k}.png", pixels.reshape(-1, 2), grid, np.arange(len(grid))))
    return views


def test_a_calibration_from_copies_of_one_view_or_one_tilt_is_refused() -> None:
    """The issue's case: copies of one view gave fx 776 px where the camera has 538, with an RMS of 0.16 px.
    Copies are named; views that all hold the board parallel to each other do not fix the focal length."""
    one = _projected_views([(0.3, 0.2, -0.1, 0.7)])[0]
    copies = [one, *(type(one)(f"copy{k}.png", one.pixels + 0.1, one.points_m, one.ids) for k in range(4))]
    with pytest.raises(CalibrationError, match=r"4 of the 5 board views are copies of another \(copy0.png of "):
        calibrate_mono(copies, (1280, 720))
    flat = _projected_views([(0.0, 0.0, tx, tz) for tx, tz in ((-0.2, 0.6), (0.0, 0.7), (0.1, 0.8), (-0.1, 0.9))])
    with pytest.raises(CalibrationError, match="held at one angle"):
        calibrate_mono(flat, (1280, 720))
    tilted = _projected_views([(0.0, 0.0, -0.1, 0.6), (0.4, 0.0, -0.1, 0.7), (0.0, 0.45, -0.1, 0.7),
                               (-0.35, 0.3, -0.1, 0.8)])
    assert calibrate_mono(tilted, (1280, 720)).camera.fx_px == pytest.approx(800.0, rel=0.01)


@pytest.mark.parametrize(("lidar", "message"), [
    ({"mount": {"x_m": 1.4, "y_m": 0.0}}, r"lidar\.mount: missing z_m"),
    ({"mount": {"x_m": 1.4, "y_m": 0.0, "z_m": 0.3, "pitch_deg": 2.0}}, r"lidar\.mount: unknown key\(s\) pitch_deg"),
    ({"mount": {"x_m": 1.4, "y_m": 0.0, "z_m": -0.3}}, r"lidar\.mount: a LiDAR mount"),
    ({"mount": {"x_m": "nose", "y_m": 0.0, "z_m": 0.3}}, r"lidar\.mount"),
    ({"mount": {"x_m": 1.4, "y_m": 0.0, "z_m": 0.3}, "device": "/dev/ttyUSB0"}, r"lidar\.device must be a mapping"),
    ({"device": {"port": "/dev/ttyUSB0"}}, r"lidar: missing mount"),
])
def test_a_rig_s_lidar_section_names_what_is_wrong(tmp_path, lidar, message) -> None:
    import yaml

    camera = {"width_px": 640, "height_px": 480, "fx_px": 500, "fy_px": 500, "cx_px": 319.5, "cy_px": 239.5}
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"cameras": {"center": camera}, "lidar": lidar}))
    with pytest.raises(CalibrationError, match=message):
        load_rig(path)


def test_a_rig_s_lidar_round_trips_with_its_turn_in_degrees(tmp_path) -> None:
    import math

    from kartpilot.core.types import LidarMount

    camera = get_vehicle("sdc-kart").camera("center")
    rig = Rig({"center": camera}, lidar=LidarMount(1.45, 0.02, 0.3, math.radians(180.0)),
              lidar_device={"port": "/dev/rplidar", "baudrate": 256000})
    text = save_rig(rig, tmp_path / "rig.yaml").read_text()
    assert "yaw_deg: 180.0" in text
    back = load_rig(tmp_path / "rig.yaml")
    assert back.lidar is not None and back.lidar.yaw_rad == pytest.approx(math.pi) and back.lidar_device == {
        "port": "/dev/rplidar", "baudrate": 256000}

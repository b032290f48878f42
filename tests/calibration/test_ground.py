"""Ground calibration: a known mount recovered from a rendered board, and the real SDC kart's cameras."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from tests.calibration.rendered import board_on_ground, render_board

from kartpilot.calibration.board import BoardConfig, find_board, measure_marker
from kartpilot.calibration.ground import (
    BirdseyeView,
    calibrate_ground,
    ground_agreement,
    ground_coverage,
    ground_points,
    mount_angles,
    stitch_birdseye,
)
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import CalibrationError
from kartpilot.core.geometry import mount_pose

BOARD = BoardConfig(kind="charuco", columns=10, rows=8, square_m=0.115, marker_m=0.086, dictionary="DICT_4X4_100")
HANZE = Path(__file__).resolve().parents[3] / "shared" / "data" / "rdw-kart" / "hanze-calibration"


@pytest.mark.parametrize("estimate_focal", [False, True])
def test_a_known_mount_is_recovered_from_a_rendered_board(estimate_focal: bool) -> None:
    truth = {"center": mount_pose(0.0, 0.0, 0.56, 0.0, 6.8, 0.0),
             "left": mount_pose(0.02, 0.09, 0.52, 27.0, 24.0, -3.0)}
    cameras = {name: PinholeCamera(1000.0, 1000.0, 959.5, 539.5, 1920, 1080).on_body(pose)
               for name, pose in truth.items()}
    board = board_on_ground(1.0, 0.1, 35.0)
    views = {name: find_board(render_board(camera, board, BOARD), BOARD, name) for name, camera in cameras.items()}
    assert all(v is not None and len(v.ids) >= 20 for v in views.values())
    known = None if estimate_focal else {n: PinholeCamera(1000.0, 1000.0, 959.5, 539.5, 1920, 1080) for n in truth}
    mounts = calibrate_ground(views, {n: (1920, 1080) for n in truth}, known)  # type: ignore[arg-type]
    for name, pose in truth.items():
        got = mounts[name]
        height, pitch, roll, yaw = mount_angles(pose)
        print(f"{name}: height {got.height_m:.4f} m (truth {height}), pitch {got.pitch_down_deg:.3f} ({pitch:.1f}), "
              f"roll {got.roll_deg:.3f} ({roll:.1f}), yaw {got.yaw_deg:.3f} ({yaw:.1f}), fx {got.camera.fx_px:.1f}")
        assert got.height_m == pytest.approx(height, abs=0.01)
        assert got.pitch_down_deg == pytest.approx(pitch, abs=0.2)
        assert got.roll_deg == pytest.approx(roll, abs=0.2)
        assert got.yaw_deg == pytest.approx(yaw, abs=0.2)
        assert np.allclose(got.camera.pose_body_cam_array[:3, 3], pose[:3, 3], atol=0.01)


def test_a_camera_that_does_not_see_the_reference_s_board_is_refused() -> None:
    camera = PinholeCamera(1000.0, 1000.0, 959.5, 539.5, 1920, 1080).on_body(mount_pose(0, 0, 0.56, 0, 6.8))
    view = find_board(render_board(camera, board_on_ground(1.0, 0.0, 0.0), BOARD), BOARD, "left")
    assert view is not None
    with pytest.raises(CalibrationError, match="reference camera 'center' has no view"):
        calibrate_ground({"left": view}, {"left": (1920, 1080)})


def test_mount_angles_inverts_mount_pose() -> None:
    pose = mount_pose(0.3, -0.2, 0.6, -25.0, 22.0, 7.0)
    assert np.allclose(mount_angles(pose), (0.6, 22.0, 7.0, -25.0))


@pytest.mark.skipif(not HANZE.is_dir(), reason="the Hanze kart's calibration images are not in ../shared/data")
def test_the_real_kart_s_three_cameras_measure_the_board_s_squares_in_the_birdseye_view() -> None:
    """The 2024 kart's three 1920x1080 cameras, one board on the ground: each camera's bird's-eye view, made
    through its recovered pose, shows squares of 0.115 m (the board found again in the warped view)."""
    images = {n: cv2.imread(str(HANZE / f"{n}.jpg")) for n in ("left", "center", "right")}
    # the markers' side as the detector places their corners (83.5 mm; the team's board says 86), as the CLI does
    board = replace(BOARD, marker_m=measure_marker(list(images.values()), BOARD), marker_corners=True)
    views = {n: find_board(im, board, n) for n, im in images.items()}
    mounts = calibrate_ground(views, {n: (1920, 1080) for n in images})  # type: ignore[arg-type]
    view = BirdseyeView((0.0, 2.0), (-1.2, 1.2), 400.0)
    for name, mount in mounts.items():
        # the markers' own corners are placed less precisely than the inner ones: 1.6 to 2.0 px RMS over all the
        # points, 1.1 to 1.4 over the inner corners alone
        assert 0.4 < mount.height_m < 0.7 and mount.reprojection_px < 2.5
        warped = stitch_birdseye({name: images[name]}, {name: mount.camera}, view)
        found = find_board(warped, BOARD, name)
        assert found is not None
        found = found.chessboard()  # the squares' sides from the inner corners
        ground = (np.column_stack([found.pixels, np.ones(len(found.pixels))]) @ view.ground_from_pixels().T)[:, :2]
        at = {int(i): p for i, p in zip(found.ids, ground, strict=True)}
        inner = BOARD.columns - 1
        sides = [np.linalg.norm(at[i] - at[j]) for i in at for j in (i + 1, i + inner)
                 if j in at and (j != i + 1 or (i + 1) % inner)]
        square = float(np.mean(sides))
        print(f"{name}: squares {square * 1000:.1f} mm in the bird's-eye view ({len(found.ids)} corners)")
        assert square == pytest.approx(0.115, rel=0.02)
    # the side cameras' ground agrees with the centre camera's where both see the board
    for agreement in ground_agreement(views, {n: m.camera for n, m in mounts.items()}):  # type: ignore[arg-type]
        print(f"{agreement.first} and {agreement.second}: the same {agreement.points} points "
              f"{agreement.median_m * 100:.1f} cm apart on the ground (median), {agreement.max_m * 100:.1f} at most")
        assert agreement.points >= 4 and agreement.max_m < 0.03


def test_ground_coverage_paints_a_polygon_where_the_mount_sees_it():
    """A 1 m square 6 to 7 m ahead and 0.5 m either side: the pixels it covers are those whose ground point lies in
    it (within the view's 2 cm grain), and nothing else is covered."""
    from kartpilot.core.vehicle import get_vehicle

    camera = get_vehicle("sdc-kart").camera("center")
    cover = ground_coverage(camera, [np.array([[6.0, 0.5], [7.0, 0.5], [7.0, -0.5], [6.0, -0.5]])])
    assert cover.shape == (camera.height_px, camera.width_px) and cover.max() == pytest.approx(1.0)
    rows, cols = np.nonzero(cover > 0.5)
    ground = ground_points(camera, np.column_stack([cols, rows]).astype(np.float64))
    assert ground[:, 0].min() > 5.95 and ground[:, 0].max() < 7.05 and np.abs(ground[:, 1]).max() < 0.55
    assert cover[: camera.height_px // 3].max() == 0.0  # the sky and the far ground hold none of it

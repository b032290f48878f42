import cv2
import numpy as np
import pytest

from kartpilot.core.camera import StereoRig
from kartpilot.perception.stereo import (
    BlockMatchConfig,
    StereoFilterConfig,
    compute_disparity,
    refine_disparity_zncc,
    stereo_filter_mask,
    stereo_match_margin,
    triangulate_rectified,
)
from kartpilot.sim.synthetic_stereo import make_texture


def _project(rig: StereoRig, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    left = rig.camera.project(points)
    right = rig.camera.project(points - [rig.baseline_m, 0.0, 0.0])
    return left, right


def test_triangulation_is_exact(rig: StereoRig, scene_points: np.ndarray) -> None:
    left, right = _project(rig, scene_points)
    np.testing.assert_allclose(triangulate_rectified(rig, left, right), scene_points, rtol=1e-9)


def test_filters_remove_planted_outliers(rig: StereoRig, scene_points: np.ndarray) -> None:
    left, right = _project(rig, scene_points)
    right = right.copy()
    right[:20, 1] += 5.0  # off the epipolar line
    right[20:40, 0] = left[20:40, 0] + 3.0  # negative disparity
    far = rig.camera.fx_px * rig.baseline_m / 80.0  # a point at 80 m
    right[40:60, 0] = left[40:60, 0] - far
    epipolar_ok, depth_ok = stereo_filter_mask(rig, left, right, StereoFilterConfig())
    assert not epipolar_ok[:40].any()
    assert epipolar_ok[40:].all()
    assert not depth_ok[:60].any()
    in_range = (scene_points[60:, 2] >= 1.0) & (scene_points[60:, 2] <= 45.0)
    np.testing.assert_array_equal(depth_ok[60:], in_range)


def test_zncc_subpixel_disparity_is_gain_invariant() -> None:
    texture = make_texture(400, np.random.default_rng(5)).astype(np.float32)
    true_disparity = 7.3
    shift = np.float32([[1, 0, -true_disparity], [0, 1, 0]])
    left = texture.astype(np.uint8)
    # right camera: content shifted by the disparity, with a different gain and offset
    right = np.clip(cv2.warpAffine(texture, shift, (400, 400), flags=cv2.INTER_CUBIC) * 0.8 + 20, 0, 255)
    right = right.astype(np.uint8)
    rng = np.random.default_rng(6)
    points = rng.uniform(40, 360, (200, 2)).astype(np.float32)
    _, disparity, valid = refine_disparity_zncc(left, right, points, np.full(200, 7.0, np.float32))
    assert valid.mean() > 0.8
    assert abs(float(np.median(disparity[valid])) - true_disparity) < 0.1


def _area_sampled_pair(disparity_eighths: int) -> tuple[np.ndarray, np.ndarray]:
    """A textured scene seen by two cameras whose pixels integrate light over their area, the right one
    shifted by ``disparity_eighths / 8`` px exactly, with another gain and offset."""
    scale = 8
    rng = np.random.default_rng(5)
    fine = cv2.resize(rng.uniform(0, 255, (100, 140)).astype(np.float32), (240 * scale, 200 * scale),
                      interpolation=cv2.INTER_CUBIC)
    fine = cv2.GaussianBlur(fine, (0, 0), 0.5 * scale)

    def camera(first_column: int, gain: float, offset: float) -> np.ndarray:
        window = fine[:, first_column:first_column + 200 * scale]
        image = cv2.resize(window, (200, 200), interpolation=cv2.INTER_AREA) * gain + offset
        return np.clip(image, 0, 255).astype(np.uint8)

    return camera(0, 1.0, 0.0), camera(disparity_eighths, 0.8, 20.0)


def test_zncc_subpixel_disparity_has_no_bias_over_the_fraction() -> None:
    """A parabola through the integer scores pulls toward whole pixels (about 0.02 px here at a quarter
    pixel); the interpolated correlation's peak does not."""
    points = np.random.default_rng(6).uniform(30, 170, (300, 2)).astype(np.float32)
    points[:, 0] += 20.0
    points[:, 0] = np.minimum(points[:, 0], 185.0)
    for eighths in range(20 * 8, 21 * 8 + 1):
        left, right = _area_sampled_pair(eighths)
        _, disparity, valid = refine_disparity_zncc(left, right, points, np.full(len(points), 20.4, np.float32))
        assert valid.mean() > 0.9
        error = disparity[valid] - eighths / 8
        print(f"disparity {eighths / 8:.3f} px: mean error {error.mean():+.4f} px, std {error.std():.4f} px")
        assert abs(float(error.mean())) < 0.008
        assert float(error.std()) < 0.02


def test_stereo_match_margin_flags_repeated_structure() -> None:
    """A patch repeated every 12 px along the row (a row of cones, a fence) has no margin over its copies;
    unique texture has a clear one."""
    rng = np.random.default_rng(3)
    unique = rng.uniform(0, 255, (60, 300))
    tile = rng.uniform(0, 255, (60, 12))
    repeated = np.tile(tile, (1, 25))
    scene = np.vstack([unique, repeated]).astype(np.float32)
    scene = cv2.GaussianBlur(scene, (0, 0), 0.8)
    left = np.clip(scene[:, :-20], 0, 255).astype(np.uint8)
    right = np.clip(scene[:, 20:], 0, 255).astype(np.uint8)  # disparity 20 px everywhere
    columns = np.arange(120, 260, 10, dtype=np.float32)
    points = np.vstack([np.column_stack([columns, np.full_like(columns, 30)]),
                        np.column_stack([columns, np.full_like(columns, 90)])])
    margins = stereo_match_margin(left, right, points, np.full(len(points), 20.0), 2.0, 100.0)
    unique_margins, repeated_margins = margins[:len(columns)], margins[len(columns):]
    print(f"margins: unique texture {np.round(unique_margins, 2)}, repeated {np.round(repeated_margins, 2)}")
    assert (unique_margins > 0.3).all()
    assert (repeated_margins < 0.05).all()


@pytest.mark.parametrize("config", [BlockMatchConfig(method="bm", block_size=11), BlockMatchConfig(method="sgbm"),
                                    BlockMatchConfig(method="sgbm", wls=True)])
def test_block_matchers_recover_a_constant_disparity(config: BlockMatchConfig) -> None:
    texture = make_texture(512, np.random.default_rng(8))
    left = np.ascontiguousarray(texture[:300, 40:460])
    right = np.ascontiguousarray(texture[:300, 60:480])  # disparity 20 px everywhere
    disparity = compute_disparity(left, right, config)
    centre = disparity[50:250, 180:380]
    assert np.nanmedian(centre) == pytest.approx(20.0, abs=0.5)

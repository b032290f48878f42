import numpy as np
import pytest

from kartpilot.core.errors import ConfigError, PerceptionError
from kartpilot.perception.features import FeatureConfig, bucket_keypoints, create_detector, detect_features
from kartpilot.perception.matching import MatchConfig, match_descriptors, match_in_band
from kartpilot.sim.synthetic_stereo import make_texture


def test_bucketing_spreads_keypoints_over_cells() -> None:
    rng = np.random.default_rng(0)
    # 1000 strong points crowded in one corner, 100 weak ones spread everywhere
    crowded = rng.uniform(0, 50, (1000, 2)).astype(np.float32)
    spread = rng.uniform(0, 400, (100, 2)).astype(np.float32)
    points = np.vstack([crowded, spread])
    responses = np.r_[np.full(1000, 10.0), np.full(100, 1.0)].astype(np.float32)
    kept = bucket_keypoints(points, responses, (400, 400), 4, 4, 160)
    assert len(kept) <= 160
    cells = {(int(p[0] // 100), int(p[1] // 100)) for p in points[kept]}
    assert len(cells) >= 14  # without bucketing all 160 would sit in one cell
    assert (kept < 1000).sum() <= 10


@pytest.mark.parametrize("name", ["orb", "sift", "akaze"])
def test_every_registered_detector_finds_features(name: str) -> None:
    image = make_texture(256, np.random.default_rng(1))
    config = FeatureConfig(detector=name, max_features=300)
    detector, binary = create_detector(config)
    features = detect_features(image, detector, binary, config)
    assert 50 <= len(features) <= 300
    assert features.descriptors.shape[0] == len(features)


def test_unknown_detector_and_bad_input() -> None:
    with pytest.raises(ConfigError, match="unknown detector"):
        create_detector(FeatureConfig(detector="surf"))  # type: ignore[arg-type]
    detector, binary = create_detector(FeatureConfig())
    with pytest.raises(PerceptionError, match="grayscale"):
        detect_features(np.zeros((10, 10, 3), np.uint8), detector, binary, FeatureConfig())


def test_black_image_gives_no_features() -> None:
    config = FeatureConfig()
    detector, binary = create_detector(config)
    assert len(detect_features(np.zeros((120, 160), np.uint8), detector, binary, config)) == 0


def _shifted_pair(shift_px: int) -> tuple[np.ndarray, np.ndarray]:
    texture = make_texture(512, np.random.default_rng(2))
    left = texture[100:340, 100:420]
    right = texture[100:340, 100 + shift_px:420 + shift_px]
    return np.ascontiguousarray(left), np.ascontiguousarray(right)


def test_band_matching_finds_the_true_disparity() -> None:
    left, right = _shifted_pair(12)  # right image content = left shifted: disparity 12 px
    config = FeatureConfig(max_features=500)
    detector, binary = create_detector(config)
    features_left = detect_features(left, detector, binary, config)
    features_right = detect_features(right, detector, binary, config)
    matches = match_in_band(features_left.points_px, features_left.descriptors, features_right.points_px,
                            features_right.descriptors, binary, 2.0, 1.0, 40.0, 0.8)
    disparity = features_left.points_px[matches.index_a, 0] - features_right.points_px[matches.index_b, 0]
    assert len(matches) > 100
    assert np.mean(np.abs(disparity - 12.0) < 1.0) > 0.95
    assert len(set(matches.index_b.tolist())) == len(matches)  # each right keypoint used once


@pytest.mark.parametrize("matcher", ["bf", "flann"])
def test_ratio_matching_on_identical_images(matcher: str) -> None:
    image = make_texture(256, np.random.default_rng(4))
    config = FeatureConfig(max_features=300)
    detector, binary = create_detector(config)
    features = detect_features(image, detector, binary, config)
    matches = match_descriptors(features.descriptors, features.descriptors, binary,
                                MatchConfig(matcher=matcher, cross_check=True))
    assert len(matches) > 0.5 * len(features)
    assert np.mean(matches.index_a == matches.index_b) > 0.95

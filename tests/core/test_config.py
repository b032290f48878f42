from dataclasses import dataclass, field
from typing import Literal

import pytest

from kartpilot.core.config import config_to_dict, load_yaml_mapping, merge_config
from kartpilot.core.errors import ConfigError
from kartpilot.odometry.stereo_vo import StereoVOConfig
from kartpilot.runtime.config import StackConfig, load_stack_config


@dataclass(frozen=True)
class Inner:
    size_px: int = 5
    mode: Literal["a", "b"] = "a"


@dataclass(frozen=True)
class Outer:
    gain: float = 1.0
    inner: Inner = field(default_factory=Inner)
    window: tuple[int, int] = (3, 3)
    label: str | None = None


def test_merge_nested_and_coerce_int_to_float() -> None:
    merged = merge_config(Outer(), {"gain": 2, "inner": {"mode": "b"}, "window": [5, 7]})
    assert merged == Outer(gain=2.0, inner=Inner(mode="b"), window=(5, 7))
    assert isinstance(merged.gain, float)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"gian": 1.0}, "unknown config key 'gian'"),
        ({"inner": {"size": 3}}, "unknown config key 'inner.size'"),
        ({"inner": {"size_px": 2.5}}, "'inner.size_px' must be int"),
        ({"inner": {"size_px": True}}, "'inner.size_px' must be int"),
        ({"gain": "fast"}, "'gain' must be float"),
        ({"inner": {"mode": "c"}}, "'inner.mode' must be one of"),
        ({"window": [1]}, "'window' needs 2 values"),
        ({"inner": 3}, "'inner' must be a mapping"),
    ],
)
def test_bad_keys_and_types_name_the_key(overrides: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        merge_config(Outer(), overrides)


def test_optional_accepts_none_and_value() -> None:
    assert merge_config(Outer(), {"label": None}).label is None
    assert merge_config(Outer(), {"label": "x"}).label == "x"


def test_component_validation_is_reported_as_config_error() -> None:
    with pytest.raises(ConfigError, match="ratio"):
        merge_config(StereoVOConfig(), {"matching": {"ratio": 1.5}})


def test_stack_yaml_round_trip(tmp_path) -> None:
    path = tmp_path / "vo.yaml"
    path.write_text("stereo_vo:\n  features: {detector: sift, max_features: 900}\n  stereo: {max_depth_m: 30}\n")
    config = load_stack_config(path)
    assert config.stereo_vo.features.detector == "sift"
    assert config.stereo_vo.features.max_features == 900
    assert config.stereo_vo.stereo.max_depth_m == 30.0
    assert config_to_dict(config.stereo_vo)["features"]["detector"] == "sift"


def test_one_lane_config_with_named_presets(tmp_path) -> None:
    """kartpilot lanes, replay and the drives read the same lane_policy.lanes; a dash camera is a preset of it,
    and the YAML goes over the preset."""
    from kartpilot.perception.lanes import LaneConfig
    from kartpilot.runtime.lane_policy import LANE_PRESETS

    assert load_stack_config(None).lane_policy.lanes == LANE_PRESETS["kart-sim"].lanes != LaneConfig()
    assert load_stack_config(None, "kart").lane_policy.lanes.method == "paint"
    assert load_stack_config(None, "dashcam").lane_policy.lanes == LaneConfig()
    path = tmp_path / "lanes.yaml"
    path.write_text("lane_policy:\n  lanes: {paint: dark}\n")
    dark = load_stack_config(path, "dashcam").lane_policy.lanes
    assert dark.paint == "dark" and dark.roi_top_width == LaneConfig().roi_top_width
    tape = load_stack_config(None, "tape").lane_policy
    assert tape.boundaries == "tape" and tape.follow == LANE_PRESETS["kart-sim"].follow
    with pytest.raises(ConfigError, match="unknown lane preset 'paint'"):
        load_stack_config(None, "paint")
    path.write_text("lane_detection: {paint: dark}\n")  # the old second section is gone: a clear error
    with pytest.raises(ConfigError, match="lane_detection"):
        load_stack_config(path)


@pytest.mark.parametrize(("mapping", "key"), [
    ({"drive": {"mono": {"wheel_sigma_mps": float("nan")}}}, "wheel_sigma_mps"),
    ({"drive": {"mono": {"place_every_m": float("nan")}}}, "place_every_m"),
    ({"lane_policy": {"speed_mps": float("nan")}}, "speed_mps"),
    ({"sim": {"effects": {"lens_distortion": [0.1, 0.2]}}}, "sim.effects.lens_distortion"),
    ({"sim": {"effects": {"lens_distortion": [float("inf"), 0.0, 0.0, 0.0]}}}, "sim.effects.lens_distortion"),
])
def test_a_nan_or_a_malformed_value_in_the_new_fields_is_refused(mapping, key) -> None:
    with pytest.raises(ConfigError, match=key):
        merge_config(StackConfig(), mapping)


def test_stack_yaml_typo_is_an_error(tmp_path) -> None:
    path = tmp_path / "vo.yaml"
    path.write_text("stereo_vo:\n  featurse: {detector: orb}\n")
    with pytest.raises(ConfigError, match=r"stereo_vo\.featurse"):
        load_stack_config(path)


def test_missing_and_invalid_yaml(tmp_path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_yaml_mapping(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_yaml_mapping(bad)
    listing = tmp_path / "list.yaml"
    listing.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_yaml_mapping(listing)


def test_a_mapping_key_takes_a_mapping_and_checks_each_value_by_name() -> None:
    """A dict field (the simulated LiDAR's dropout per surface) merged from YAML: a mapping of numbers; a value that
    is not one is named with its key. (A dict field was refused outright, even its own default: 'must be dict, got
    dict', which broke every study whose cells carry the simulator's settings.)"""
    from kartpilot.sim.lidar import LidarConfig

    merged = merge_config(LidarConfig(), {"dropout": {"person": 0.3, "car": 0}}, "lidar")
    assert merged.dropout == {"person": 0.3, "car": 0.0} and isinstance(merged.dropout["car"], float)
    assert merge_config(LidarConfig(), config_to_dict(LidarConfig()), "lidar") == LidarConfig()
    with pytest.raises(ConfigError, match=r"lidar\.dropout\.person"):
        merge_config(LidarConfig(), {"dropout": {"person": "half"}}, "lidar")
    with pytest.raises(ConfigError, match=r"lidar\.dropout' must be"):
        merge_config(LidarConfig(), {"dropout": [0.1]}, "lidar")

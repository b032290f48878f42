"""The stack's configuration: one section per component, one YAML file over the defaults.

Example ``vo.yaml``::

    stereo_vo:
      features: {detector: sift, max_features: 2000}
      stereo: {max_depth_m: 30}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from kartpilot.core.config import load_yaml_mapping, merge_config
from kartpilot.odometry.stereo_vo import StereoVOConfig

__all__ = ["StackConfig", "load_stack_config"]


@dataclass(frozen=True)
class StackConfig:
    stereo_vo: StereoVOConfig = field(default_factory=StereoVOConfig)


def load_stack_config(path: str | Path | None) -> StackConfig:
    """Defaults, with the YAML file at ``path`` merged over them when given."""
    if path is None:
        return StackConfig()
    return merge_config(StackConfig(), load_yaml_mapping(path))

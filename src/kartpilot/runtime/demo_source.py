"""The default input of the stereo VO benchmark (``kartpilot demo`` now drives the simulator)."""

from __future__ import annotations

from pathlib import Path

from kartpilot.sensors.base import StereoSource
from kartpilot.sensors.kitti import KittiOdometrySource
from kartpilot.sim.synthetic_stereo import SyntheticStereoSource

__all__ = ["default_stereo_source"]


def default_stereo_source(data_dir: str | Path) -> tuple[StereoSource, str]:
    """KITTI odometry sequence 06 under ``data_dir`` when present, else the synthetic sequence.

    Returns the source and, when it fell back, the reason (empty otherwise).
    """
    kitti_root = Path(data_dir) / "kitti-odometry"
    if (kitti_root / "sequences" / "06").is_dir():
        return KittiOdometrySource(kitti_root, "06"), ""
    return SyntheticStereoSource(), f"no KITTI data under {kitti_root}: using the built-in synthetic stereo sequence"

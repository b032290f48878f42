"""Shared fixtures: where the real data lives, and synthetic scenes with known geometry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kartpilot.core.camera import PinholeCamera, StereoRig

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def data_path(*parts: str) -> Path:
    """A path under ../shared/data, or skip the test with the reason."""
    path = DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not present: {path} (see ../shared/data/README.md)")
    return path


@pytest.fixture
def rig() -> StereoRig:
    """A small-kart-like rectified rig: 960x540, f 743 px, 14 cm baseline."""
    return StereoRig(PinholeCamera(743.0, 743.0, 479.5, 269.5, 960, 540), 0.14)


@pytest.fixture
def scene_points() -> np.ndarray:
    """300 points spread 2 to 30 m in front of the camera."""
    rng = np.random.default_rng(7)
    depth = rng.uniform(2.0, 30.0, 300)
    x = rng.uniform(-0.5, 0.5, 300) * depth
    y = rng.uniform(-0.25, 0.3, 300) * depth
    return np.stack([x, y, depth], axis=1)

"""Figures: estimated and true paths seen from above, and the error over distance."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from kartpilot.core.trajectory import Trajectory

__all__ = ["plot_trajectories"]


def plot_trajectories(reference: Trajectory | None, estimate: Trajectory, path: str | Path, title: str = "") -> None:
    """Top view (x right, z forward of the first camera) and, with a reference, error over distance."""
    columns = 2 if reference is not None else 1
    figure, axes = plt.subplots(1, columns, figsize=(6 * columns, 5), squeeze=False)
    top = axes[0, 0]
    if reference is not None:
        top.plot(reference.positions[:, 0], reference.positions[:, 2], "k-", label="ground truth")
    top.plot(estimate.positions[:, 0], estimate.positions[:, 2], "r-", label="estimate")
    top.set_xlabel("x (m)")
    top.set_ylabel("z (m)")
    top.set_aspect("equal", adjustable="datalim")
    top.grid(True, alpha=0.3)
    top.legend()
    top.set_title(title or "trajectory (top view)")
    if reference is not None:
        count = min(len(reference), len(estimate))
        error = np.linalg.norm(reference.positions[:count] - estimate.positions[:count], axis=1)
        distance = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(reference.positions[:count], axis=0), axis=1))]
        side = axes[0, 1]
        side.plot(distance, error, "b-")
        side.set_xlabel("distance travelled (m)")
        side.set_ylabel("position error (m)")
        side.grid(True, alpha=0.3)
        side.set_title("position error over distance")
    figure.tight_layout()
    figure.savefig(str(path), dpi=110)
    plt.close(figure)

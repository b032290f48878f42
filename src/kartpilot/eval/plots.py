"""Figures: estimated and true paths seen from above, the error over distance, path following."""

from __future__ import annotations

import io
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from kartpilot.core.files import write_bytes_atomic
from kartpilot.core.trajectory import Trajectory

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["plot_path_following", "plot_steering", "plot_trajectories"]


def pyplot() -> ModuleType:
    """matplotlib's pyplot on the file-only Agg backend, imported when a figure is drawn: at import it would cost
    every command a third of a second (``kartpilot`` starts without it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_trajectories(reference: Trajectory | None, estimate: Trajectory, path: str | Path, title: str = "") -> None:
    """Top view (x right, z forward of the first camera) and, with a reference, error over distance."""
    columns = 2 if reference is not None else 1
    plt = pyplot()
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
    _save(figure, path)
    plt.close(figure)


def plot_path_following(taught_xy: np.ndarray, reference_xy: np.ndarray, driven_xy: np.ndarray,
                        estimated_xy: np.ndarray, distance_m: np.ndarray, path: str | Path, title: str = "") -> None:
    """Top view of a repeat drive: the taught path (truth), the reference (VO), the driven path (truth)
    and the pipeline's own estimate of it; beside it, ``distance_m``, each driven point's distance from
    the taught path."""
    plt = pyplot()
    figure, axes = plt.subplots(1, 2, figsize=(12, 5), squeeze=False)
    top = axes[0, 0]
    top.plot(taught_xy[:, 0], taught_xy[:, 1], "k-", lw=2.5, alpha=0.4, label="taught path (truth)")
    top.plot(reference_xy[:, 0], reference_xy[:, 1], "b--", lw=1, label="reference (VO)")
    top.plot(driven_xy[:, 0], driven_xy[:, 1], "r-", lw=1, label="driven (truth)")
    top.plot(estimated_xy[:, 0], estimated_xy[:, 1], "g:", lw=1, label="driven (pipeline's estimate)")
    top.set_xlabel("x (m, forward at the start)")
    top.set_ylabel("y (m, left at the start)")
    span = np.ptp(taught_xy, axis=0)
    if max(span) < 8 * max(min(span), 0.5):
        top.set_aspect("equal", adjustable="datalim")
    else:  # a long straight: stretch the cross-track axis so a deviation shows
        top.set_ylabel("y (m, left at the start; stretched)")
    top.grid(True, alpha=0.3)
    top.legend(fontsize=8)
    top.set_title(title or "path versus reference")
    side = axes[0, 1]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(driven_xy, axis=0), axis=1))])
    side.plot(s, distance_m, "r-")
    side.set_xlabel("distance driven (m)")
    side.set_ylabel("distance from the taught path (m)")
    side.grid(True, alpha=0.3)
    side.set_title("tracking error (truth)")
    figure.tight_layout()
    _save(figure, path)
    plt.close(figure)


def plot_steering(t_s: np.ndarray, steer_rad: np.ndarray, cross_track_m: np.ndarray, path: str | Path,
                  title: str = "") -> None:
    """Steering command and the controller's cross-track error over time."""
    plt = pyplot()
    figure, axes = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    axes[0].plot(t_s, np.degrees(steer_rad), "b-", lw=1)
    axes[0].set_ylabel("steer (deg, + left)")
    axes[0].grid(True, alpha=0.3)
    axes[0].set_title(title or "steering over time")
    axes[1].plot(t_s, cross_track_m, "r-", lw=1)
    axes[1].set_ylabel("cross-track error (m)")
    axes[1].set_xlabel("time (s)")
    axes[1].grid(True, alpha=0.3)
    figure.tight_layout()
    _save(figure, path)
    plt.close(figure)


def _save(figure: Figure, path: str | Path) -> None:
    """The figure as an image file, written whole or not at all; the format from the file's suffix."""
    buffer = io.BytesIO()
    figure.savefig(buffer, dpi=110, format=Path(path).suffix.lstrip(".").lower() or "png")
    write_bytes_atomic(path, buffer.getvalue())

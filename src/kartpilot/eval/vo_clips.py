"""Stereo VO scored on real clips with ground truth: the clips kartpilot judges VO by, in one place.

Simulated bends once made the keyframe VO look six times better while a real curve got worse (docs/stereo-vo.md):
a change to VO counts when it holds on these. Each clip is a real stereo recording with its truth in
``../shared/data`` (README there), taken whole or every second or third frame (the same road driven two or three
times faster: larger steps between frames, as a curve's turn or a faster kart makes them):

* ``kitti-06``: KITTI odometry 06, frames 0 to 50, a car on a nearly straight road, 60 m; its rig on the car
  (the left camera level, 1.65 m up: Geiger et al. 2013), so that what holds for a ground vehicle can apply;
* ``euroc-mh01``: EuRoC MH_01, 110 frames of a stereo rig carried by hand over a pallet, 3.85 m and 170 degrees
  of summed turn (not a ground vehicle: its rig has no mount).

:func:`score_stereo` runs stereo VO with a configuration over a clip and scores it against the truth;
``benchmarks/vo_ablation.py`` and the real-accuracy guard (``tests/odometry/test_real_vo_guard.py``) use them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from kartpilot.core.camera import StereoRig
from kartpilot.core.errors import DataError
from kartpilot.core.geometry import mount_pose
from kartpilot.eval.trajectory_metrics import evaluate_trajectory
from kartpilot.odometry.mono_vo import GroundConfig, MonoVO, MonoVOConfig
from kartpilot.odometry.run import VORun, run_vo
from kartpilot.odometry.stereo_vo import StereoVO, StereoVOConfig
from kartpilot.sensors.base import StereoSource, read_ahead
from kartpilot.sensors.euroc import EurocSource
from kartpilot.sensors.kitti import KittiOdometrySource

__all__ = ["CLIPS", "GUARD_MARGINS", "RealClip", "guard_failures", "guard_figures", "real_clips", "score_mono_kitti",
           "score_stereo", "score_stereo_source", "stereo_over_mono_city"]


@dataclass(frozen=True)
class RealClip:
    """A real stereo clip with ground truth: its name, how it is opened under the data folder, and the stride
    (every ``stride``-th frame)."""

    name: str
    folder: str
    open: Callable[[Path], StereoSource]
    stride: int = 1
    note: str = ""

    @property
    def label(self) -> str:
        return self.name if self.stride == 1 else f"{self.name}, every {self.stride}{_ORDINAL[self.stride]} frame"


_ORDINAL = {2: "nd", 3: "rd"}


class KittiOnItsCar(KittiOdometrySource):
    """A KITTI sequence whose rig's left camera is mounted as on KITTI's car: level, 1.65 m above the road. Only
    for stereo VO (monocular VO takes a mount for a kart's: its arc motion from the rear axle)."""

    @property
    def rig(self) -> StereoRig:
        rig = super().rig
        return replace(rig, camera=rig.camera.on_body(mount_pose(z_m=1.65)))


CLIPS = (
    RealClip("kitti-06", "kitti-odometry", lambda p: KittiOnItsCar(p, "06"), 1, "a car, 60 m nearly straight"),
    RealClip("kitti-06", "kitti-odometry", lambda p: KittiOnItsCar(p, "06"), 2, "twice the step"),
    RealClip("kitti-06", "kitti-odometry", lambda p: KittiOnItsCar(p, "06"), 3, "three times the step"),
    RealClip("euroc-mh01", "euroc-mh01-moving", EurocSource, 1, "hand-held, 3.85 m, 170 deg of turn"),
    RealClip("euroc-mh01", "euroc-mh01-moving", EurocSource, 2, "up to 10 deg a step"),
)
"""Every real clip with truth, as the ablation and the guard take them."""


def real_clips(data: Path) -> list[RealClip]:
    """The clips of :data:`CLIPS` whose data is under ``data`` (``../shared/data``)."""
    return [clip for clip in CLIPS if (data / clip.folder).is_dir()]


def score_stereo(clip: RealClip, data: Path, config: StereoVOConfig | None = None) -> dict[str, Any]:
    """Stereo VO with ``config`` over ``clip`` (its data under ``data``), against its truth."""
    return {"clip": clip.label, **score_stereo_source(clip.open(data / clip.folder), config, clip.stride)}


def score_stereo_source(source: StereoSource, config: StereoVOConfig | None = None, stride: int = 1
                        ) -> dict[str, Any]:
    """Stereo VO with ``config`` over every ``stride``-th frame of ``source``, against its truth (:func:`_scored`),
    and whether the attitude prior applied (the rig has a mount)."""
    vo = StereoVO(source.rig, config)
    run = run_vo(read_ahead(source.frame_sets(stride=stride)), vo, source.name)
    return {**_scored(run, source), "attitude_prior": vo.attitude_prior}


def _scored(run: VORun, truth_source: StereoSource) -> dict[str, Any]:
    """A run against its source's truth: end drift (% of the distance), end rotation, ATE after alignment, bridged
    frames and frames per second."""
    truth = truth_source.ground_truth()
    if truth is None:
        raise DataError(f"{truth_source.name} has no ground truth to score VO against")
    metrics = evaluate_trajectory(truth, run.trajectory)
    return {"frames": len(run.trajectory), "distance_m": metrics.path_length_m,
            "end_drift_percent": metrics.end_drift_percent, "end_rotation_deg": metrics.end_rotation_deg,
            "ate_rmse_m": metrics.ate_rmse_m, "bridged_frames": run.bridged_frames,
            "frames_per_second": run.frames_per_second}


def _mono_run(source: StereoSource, height_m: float = 1.65, stride: int = 1) -> VORun:
    """Monocular VO on the left camera (no mount: a car's, not a kart's arc), metres from the ground plane at
    ``height_m``, as ``kartpilot odometry kitti --mono --camera-height 1.65`` runs it."""
    vo = MonoVO(source.rig.camera, MonoVOConfig(ground=GroundConfig(camera_height_m=height_m)))
    return run_vo(read_ahead(source.frame_sets(stride=stride)), vo, source.name)


def score_mono_kitti(data: Path, stride: int = 1) -> dict[str, Any]:
    """Monocular VO on KITTI 06 (its left camera 1.65 m above the road), every ``stride``-th frame, against its
    truth."""
    source = KittiOdometrySource(data / "kitti-odometry", "06")
    label = "kitti-06" if stride == 1 else f"kitti-06, every {stride}{_ORDINAL[stride]} frame"
    return {"clip": f"{label} (monocular)", **_scored(_mono_run(source, stride=stride), source)}


def stereo_over_mono_city(data: Path) -> float:
    """The KITTI raw city drive (no poses): the distance stereo VO drives (scale from the baseline) over the one
    monocular VO drives (scale from the 1.65 m camera height); each scale is independent of the other, so the
    ratio's distance from 1 bounds both errors."""
    source = KittiOdometrySource(data / "kitti-raw-city", "91")
    stereo = run_vo(source.frame_sets(), StereoVO(source.rig), source.name).trajectory.path_length_m
    return float(stereo / _mono_run(source).trajectory.path_length_m)


def guard_figures(data: Path) -> dict[str, dict[str, float]]:
    """What the real-accuracy guard holds VO to: per real clip with truth, stereo VO's end drift (%), ATE (m) and
    bridged frames with the defaults; monocular VO's on KITTI 06, whole and every 2nd frame; and how far the city
    drive's stereo-over-mono distance is from 1. Clips whose data is missing are left out."""
    out: dict[str, dict[str, float]] = {}
    for clip in real_clips(data):
        row = score_stereo(clip, data)
        out[f"{clip.label} (stereo)"] = {key: float(row[key]) for key in ("end_drift_percent", "ate_rmse_m",
                                                                            "bridged_frames")}
    if (data / "kitti-odometry").is_dir():
        for stride in (1, 2):
            row = score_mono_kitti(data, stride)
            out[row["clip"]] = {key: float(row[key]) for key in ("end_drift_percent", "ate_rmse_m", "bridged_frames")}
    if (data / "kitti-raw-city").is_dir():
        out["kitti-raw-city (stereo over mono distance)"] = {"off_one": abs(stereo_over_mono_city(data) - 1.0)}
    return out


GUARD_MARGINS = {"end_drift_percent": (0.15, 0.15), "ate_rmse_m": (0.15, 0.01), "bridged_frames": (0.0, 1.0),
                 "off_one": (0.0, 0.01)}
"""How much worse than its recorded figure a measure may come out before the guard fails: (a share of the figure,
a floor), whichever is larger. Runs on one machine give the same figures to the last digit; the margin takes in
another CPU's or OpenCV build's arithmetic."""


def guard_failures(measured: dict[str, dict[str, float]], recorded: dict[str, dict[str, float]]) -> list[str]:
    """Each measure of ``measured`` (:func:`guard_figures`) worse than its ``recorded`` figure by more than
    :data:`GUARD_MARGINS`, and each clip with no recorded figure, as a line saying which and by how much."""
    out = []
    for clip, figures in measured.items():
        if clip not in recorded:
            out.append(f"{clip}: no recorded figure (record it on purpose with benchmarks/real_vo_figures.py)")
            continue
        for key, value in figures.items():
            share, floor = GUARD_MARGINS[key]
            figure = recorded[clip][key]
            if not value <= figure + max(floor, share * figure):  # NaN fails too
                out.append(f"{clip}: {key} {value:.4f}, recorded {figure:.4f} (allowed up to "
                           f"{figure + max(floor, share * figure):.4f})")
    return out

"""Trajectory metrics, computed through evo's API.

- ATE: RMSE of the position error after an SE(3) Umeyama alignment (Sturm et al.,
  "A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012); on a straight
  path, where that alignment is degenerate, after aligning the first poses.
- RPE over a path distance (1 m, 10 m): translation error in % of the distance and
  rotation error in deg/m, over all pose pairs that far apart along the ground
  truth (Geiger et al., KITTI, CVPR 2012, use 100 to 800 m on long sequences;
  short sequences need shorter segments).
- End-point drift: distance between the estimated and true final positions, in %
  of the ground-truth path length, with both trajectories starting at the same pose;
  and its rotation: the angle between the estimated and true final orientations (degrees,
  and degrees per metre of the path), the heading error that bends a trajectory in a turn.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass

import numpy as np
from evo.core import filters, metrics, sync
from evo.core.geometry import GeometryException
from evo.core.trajectory import PoseTrajectory3D

from kartpilot.core.errors import EvaluationError
from kartpilot.core.trajectory import Trajectory

__all__ = ["RpeResult", "TrajectoryMetrics", "evaluate_trajectory", "to_evo"]


@dataclass(frozen=True)
class RpeResult:
    delta_m: float
    pairs: int
    translation_percent: float
    rotation_deg_per_m: float


@dataclass(frozen=True)
class TrajectoryMetrics:
    """Metrics of one estimated trajectory against its ground truth."""

    poses: int
    path_length_m: float
    ate_rmse_m: float
    end_drift_m: float
    end_drift_percent: float
    rpe: tuple[RpeResult, ...]
    end_rotation_deg: float = float("nan")

    @property
    def end_rotation_deg_per_m(self) -> float:
        return self.end_rotation_deg / self.path_length_m if self.path_length_m > 0 else float("nan")

    def as_dict(self) -> dict[str, object]:
        return asdict(self)

    def table(self) -> str:
        """A plain-text table for the terminal."""
        lines = [
            f"{'poses':<28}{self.poses:>12d}",
            f"{'path length (m)':<28}{self.path_length_m:>12.2f}",
            f"{'ATE RMSE (m)':<28}{self.ate_rmse_m:>12.3f}",
            f"{'end-point drift (m)':<28}{self.end_drift_m:>12.3f}",
            f"{'end-point drift (%)':<28}{self.end_drift_percent:>12.3f}",
            f"{'end rotation (deg)':<28}{self.end_rotation_deg:>12.3f}",
            f"{'end rotation (deg/m)':<28}{self.end_rotation_deg_per_m:>12.4f}",
        ]
        for rpe in self.rpe:
            label = f"RPE {rpe.delta_m:g} m"
            if rpe.pairs == 0:
                lines.append(f"{label + ' (no pairs)':<28}{'-':>12}")
                continue
            lines.append(f"{label + ' trans (%)':<28}{rpe.translation_percent:>12.3f}")
            lines.append(f"{label + ' rot (deg/m)':<28}{rpe.rotation_deg_per_m:>12.4f}")
        return "\n".join(lines)


def to_evo(trajectory: Trajectory) -> PoseTrajectory3D:
    return PoseTrajectory3D(poses_se3=list(trajectory.poses), timestamps=trajectory.stamps_s.copy())


def _associate(reference: Trajectory, estimate: Trajectory) -> tuple[PoseTrajectory3D, PoseTrajectory3D]:
    ref, est = to_evo(reference), to_evo(estimate)
    if len(reference) == len(estimate) and np.allclose(reference.stamps_s, estimate.stamps_s, atol=1e-3):
        return ref, est
    try:
        ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    except sync.SyncException as exc:
        raise EvaluationError(f"cannot associate the trajectories by timestamp: {exc}") from exc
    return ref, est


def evaluate_trajectory(reference: Trajectory, estimate: Trajectory,
                        rpe_deltas_m: tuple[float, ...] = (1.0, 10.0)) -> TrajectoryMetrics:
    """Compare an estimate with its ground truth (matching timestamps).

    The estimate is first moved so that its first pose coincides with the reference's (odometry starts
    from its own origin; ground truth may be in a world frame), then end-point drift is measured, then
    ATE after a rigid alignment.

    Raises:
        EvaluationError: when fewer than two poses can be associated.
    """
    ref, est = _associate(reference, estimate)
    if ref.num_poses < 2:
        raise EvaluationError("fewer than two poses in common between estimate and ground truth")
    est = copy.deepcopy(est)
    est.align_origin(ref)
    path_length = float(ref.path_length)
    end_drift = float(np.linalg.norm(est.positions_xyz[-1] - ref.positions_xyz[-1]))
    turn = ref.poses_se3[-1][:3, :3].T @ est.poses_se3[-1][:3, :3]
    end_rotation = float(np.degrees(np.arccos(np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0))))
    aligned = copy.deepcopy(est)
    try:
        aligned.align(ref, correct_scale=False)
    except GeometryException:
        # a straight-line path leaves the rotation about it undetermined: align the first poses instead
        aligned.align_origin(ref)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    rpes = []
    for delta in rpe_deltas_m:
        rpes.append(_rpe(ref, est, delta))
    return TrajectoryMetrics(
        poses=int(ref.num_poses), path_length_m=path_length,
        ate_rmse_m=float(ape.get_statistic(metrics.StatisticsType.rmse)),
        end_drift_m=end_drift,
        end_drift_percent=100.0 * end_drift / path_length if path_length > 0 else float("nan"),
        rpe=tuple(rpes), end_rotation_deg=end_rotation)


def _rpe(ref: PoseTrajectory3D, est: PoseTrajectory3D, delta_m: float) -> RpeResult:
    results = []
    for relation in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
        rpe = metrics.RPE(relation, delta=delta_m, delta_unit=metrics.Unit.meters, rel_delta_tol=0.2,
                          all_pairs=True, pairs_from_reference=True)
        try:
            rpe.process_data((ref, est))
        except (metrics.MetricsException, filters.FilterException):
            return RpeResult(delta_m, 0, float("nan"), float("nan"))
        results.append((len(rpe.error), float(np.mean(rpe.error))))
    (pairs, trans_m), (_, rot_deg) = results
    return RpeResult(delta_m, pairs, 100.0 * trans_m / delta_m, rot_deg / delta_m)

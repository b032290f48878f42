import numpy as np
import pytest

from kartpilot.core.errors import DataError
from kartpilot.core.geometry import pose_from_rotvec
from kartpilot.core.trajectory import (
    Trajectory,
    guess_format,
    read_kitti_poses,
    read_trajectory,
    read_tum,
    write_kitti_poses,
    write_tum,
)


@pytest.fixture
def trajectory() -> Trajectory:
    rng = np.random.default_rng(3)
    poses = [pose_from_rotvec(rng.normal(0, 0.3, 3), rng.normal(0, 5, 3)) for _ in range(20)]
    return Trajectory.from_poses(poses, np.arange(20) * 0.1 + 1e9)


def test_kitti_round_trip(tmp_path, trajectory: Trajectory) -> None:
    path = tmp_path / "traj.txt"
    write_kitti_poses(path, trajectory)
    back = read_kitti_poses(path)
    np.testing.assert_allclose(back.poses, trajectory.poses, atol=1e-8)
    assert guess_format(path) == "kitti"


def test_tum_round_trip(tmp_path, trajectory: Trajectory) -> None:
    path = tmp_path / "traj.tum"
    write_tum(path, trajectory)
    back = read_tum(path)
    np.testing.assert_allclose(back.poses, trajectory.poses, atol=1e-8)
    np.testing.assert_allclose(back.stamps_s, trajectory.stamps_s, atol=1e-6)
    assert guess_format(path) == "tum"
    assert len(read_trajectory(path)) == 20


def test_bad_trajectory_files(tmp_path) -> None:
    with pytest.raises(DataError, match="not found"):
        read_kitti_poses(tmp_path / "none.txt")
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing\n")
    with pytest.raises(DataError, match="no poses"):
        read_kitti_poses(empty)
    short = tmp_path / "short.txt"
    short.write_text("1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(DataError, match=r"short.txt:1: expected 12 numbers"):
        read_kitti_poses(short)
    text = tmp_path / "text.txt"
    text.write_text("1 0 0 0 0 1 0 0 0 0 1 x\n")
    with pytest.raises(DataError, match="not a number"):
        read_kitti_poses(text)

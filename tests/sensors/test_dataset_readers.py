import shutil

import numpy as np
import pytest
from tests.conftest import data_path

from kartpilot.core.errors import CalibrationError, DataError
from kartpilot.sensors.base import read_gray
from kartpilot.sensors.euroc import EurocSource
from kartpilot.sensors.kitti import KittiOdometrySource


def _fake_kitti(root, frames: int = 3, calib: str | None = None):
    sequence = root / "sequences" / "00"
    for camera in ("image_0", "image_1"):
        (sequence / camera).mkdir(parents=True)
        for index in range(frames):
            import cv2

            cv2.imwrite(str(sequence / camera / f"{index:06d}.png"), np.full((40, 60), 128, np.uint8))
    if calib is None:
        calib = ("P0: 50 0 30 0 0 50 20 0 0 0 1 0\n"
                 "P1: 50 0 30 -25 0 50 20 0 0 0 1 0\n")
    (sequence / "calib.txt").write_text(calib)
    (sequence / "times.txt").write_text("\n".join(f"{i * 0.1:.1f}" for i in range(frames)) + "\n")
    return root


def test_fake_kitti_layout_reads(tmp_path) -> None:
    source = KittiOdometrySource(_fake_kitti(tmp_path), 0)
    assert len(source) == 3
    assert source.rig.baseline_m == pytest.approx(0.5)
    frame = source.frame(2)
    assert frame.stamp_ns == 200_000_000 and frame.left.shape == (40, 60)
    assert source.ground_truth() is None


def test_kitti_errors_are_clear(tmp_path) -> None:
    with pytest.raises(DataError, match="KITTI root not found"):
        KittiOdometrySource(tmp_path / "missing", "06")
    root = _fake_kitti(tmp_path / "a")
    with pytest.raises(DataError, match="sequence 07 not found"):
        KittiOdometrySource(root, "07")
    no_p1 = _fake_kitti(tmp_path / "b", calib="P0: 50 0 30 0 0 50 20 0 0 0 1 0\n")
    with pytest.raises(CalibrationError, match="no P1"):
        KittiOdometrySource(no_p1, 0)
    empty = _fake_kitti(tmp_path / "c", frames=0)
    with pytest.raises(DataError, match="no frames"):
        KittiOdometrySource(empty, 0)


def test_corrupt_image_is_a_data_error(tmp_path) -> None:
    path = tmp_path / "broken.png"
    path.write_bytes(b"\x89PNG not really")
    with pytest.raises(DataError, match="cannot read image"):
        read_gray(path)
    with pytest.raises(DataError, match="not found"):
        read_gray(tmp_path / "absent.png")
    (tmp_path / "empty.jpg").write_bytes(b"")  # OpenCV 4.14 asserts on an empty buffer: it was a traceback
    with pytest.raises(DataError, match="empty"):
        read_gray(tmp_path / "empty.jpg")


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_a_cut_off_image_is_a_data_error_not_a_half_grey_frame(tmp_path, suffix) -> None:
    """OpenCV decodes a JPEG or PNG cut off half-way (its lower part grey) with only a warning; kartpilot
    refuses it, in a folder given to ``kartpilot lanes`` too."""
    import cv2

    from kartpilot.cli.main import main

    image = (np.random.default_rng(0).random((120, 160, 3)) * 255).astype(np.uint8)
    whole = tmp_path / f"whole{suffix}"
    cv2.imwrite(str(whole), image)
    assert read_gray(whole).shape == (120, 160)
    folder = tmp_path / "frames"
    folder.mkdir()
    data = whole.read_bytes()
    (folder / f"cut{suffix}").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="cut off"):
        read_gray(folder / f"cut{suffix}")
    out = tmp_path / "lanes.csv"
    assert main(["lanes", str(folder), "--out", str(out)]) == 1
    assert not out.exists()


def test_real_kitti_06() -> None:
    root = data_path("kitti-odometry")
    source = KittiOdometrySource(root, "06")
    assert len(source) == 51
    assert source.rig.baseline_m == pytest.approx(0.5372, abs=1e-3)
    truth = source.ground_truth()
    assert truth is not None and len(truth) == 51
    assert 55 < truth.path_length_m < 65


def test_real_euroc_pairs_by_timestamp_and_rectifies() -> None:
    source = EurocSource(data_path("euroc-v101-static"))
    assert len(source) == 95  # cam1/data.csv lists 4 rows without files
    assert 0.10 < source.rig.baseline_m < 0.12
    frame = source.frame(0)
    assert frame.left.shape == (480, 752)


def test_euroc_missing_calibration(tmp_path) -> None:
    root = data_path("euroc-v101-static")
    copy = tmp_path / "euroc"
    shutil.copytree(root / "mav0" / "cam0", copy / "mav0" / "cam0")
    (copy / "mav0" / "cam1").mkdir(parents=True)
    with pytest.raises(CalibrationError, match="not found"):
        EurocSource(copy)


def test_real_euroc_ground_truth_is_the_rectified_left_camera_s() -> None:
    """MH_01's truth through cam0's T_BS and the rectification: one pose per frame at its stamp, from the first
    frame's camera, over the clip's 3.85 m of path and 23.1 deg of net turn (its SOURCE.txt's figures)."""
    source = EurocSource(data_path("euroc-mh01-moving"))
    truth = source.ground_truth()
    assert truth is not None and len(truth) == len(source) == 110
    assert np.allclose(truth.poses[0], np.eye(4))
    assert [truth.stamps_s[i] for i in (0, 109)] == [source.frame(i).stamp_ns * 1e-9 for i in (0, 109)]
    assert truth.path_length_m == pytest.approx(3.85, abs=0.03)
    net = truth.poses[-1][:3, :3]
    assert np.degrees(np.arccos((np.trace(net) - 1) / 2)) == pytest.approx(23.1, abs=0.3)


def test_euroc_without_ground_truth_has_none_and_a_broken_one_is_named(tmp_path) -> None:
    assert EurocSource(data_path("euroc-v101-static")).ground_truth() is None
    root = data_path("euroc-mh01-moving")
    copy = tmp_path / "euroc"
    for camera in ("cam0", "cam1"):
        (copy / "mav0" / camera).mkdir(parents=True)
        shutil.copy(root / "mav0" / camera / "sensor.yaml", copy / "mav0" / camera / "sensor.yaml")
        (copy / "mav0" / camera / "data.csv").write_text((root / "mav0" / camera / "data.csv").read_text())
        shutil.copytree(root / "mav0" / camera / "data", copy / "mav0" / camera / "data")
    truth = copy / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    truth.parent.mkdir(parents=True)
    truth.write_text("#timestamp, ...\n1403636584663560000,4.6,-1.7,0.9,2.0,0,0,0,0,0,0,0,0,0,0,0,0\n")
    with pytest.raises(DataError, match=r"data\.csv.*quaternion of length 2"):
        EurocSource(copy).ground_truth()
    row = ",4.6,-1.7,0.9,1,0,0,0,0,0,0,0,0,0,0,0,0\n"
    truth.write_text(f"#timestamp, ...\n1{row}2{row}")
    with pytest.raises(DataError, match="fewer than two of the frames' stamps"):
        EurocSource(copy).ground_truth()


def test_read_ahead_keeps_the_order_raises_where_reading_stopped_and_stops_with_its_caller() -> None:
    import threading

    from kartpilot.sensors.base import read_ahead

    assert list(read_ahead(iter(range(50)), depth=3)) == list(range(50))

    def broken():
        yield from (0, 1)
        raise DataError("frame 2: cut off")

    got = []
    with pytest.raises(DataError, match="frame 2"):
        for item in read_ahead(broken()):
            got.append(item)
    assert got == [0, 1]
    read = []

    def endless():
        k = 0
        while True:
            read.append(k)
            yield k
            k += 1

    stream = read_ahead(endless(), depth=2)
    assert [next(stream) for _ in range(3)] == [0, 1, 2]
    stream.close()  # the caller stops: the thread stops too, a few items ahead at most
    assert not any(t.name == "read-ahead" and t.is_alive() for t in threading.enumerate())
    assert len(read) <= 3 + 2 + 1
    with pytest.raises(ValueError, match="depth"):
        next(read_ahead(iter(()), depth=0))

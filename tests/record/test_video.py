"""H.264 videos: readable back frame for frame, small, and never left half-written."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from kartpilot.core.errors import RecordingError
from kartpilot.record.video import VideoFile


def _frame(k: int, size_wh: tuple[int, int]) -> np.ndarray:
    image = np.zeros((size_wh[1], size_wh[0], 3), np.uint8)
    cv2.rectangle(image, (10 + 4 * k, 20), (60 + 4 * k, 70), (40, 200, 250), -1)
    cv2.putText(image, f"{k}", (100, 100), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2)
    return image


def test_a_video_reads_back_with_every_frame_and_its_size(tmp_path: Path) -> None:
    path = tmp_path / "drive.mp4"
    with VideoFile(path, 30.0, (321, 179)) as video:  # odd sizes are padded for the codec
        for k in range(45):
            video.write(_frame(k, (321, 179)))
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, image = capture.read()
        if not ok:
            break
        frames.append(image)
    assert len(frames) == 45
    assert frames[0].shape[:2] in ((179, 321), (180, 322))
    # H.264 is lossy: the picture is there, close to what was written
    assert np.abs(frames[10][:179, :321].astype(int) - _frame(10, (321, 179)).astype(int)).mean() < 6
    assert not list(tmp_path.glob(".*partial*"))


def test_a_video_that_got_no_frame_leaves_no_file_and_a_wrong_size_is_refused(tmp_path: Path) -> None:
    VideoFile(tmp_path / "empty.mp4", 30.0, (64, 48)).close()
    assert list(tmp_path.iterdir()) == []
    with VideoFile(tmp_path / "sized.mp4", 30.0, (64, 48)) as video, \
            pytest.raises(RecordingError, match="64x48"):
        video.write(np.zeros((50, 64, 3), np.uint8))

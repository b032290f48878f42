"""Whether two frames belong to one drive: a folder of photos taken at different places is not one drive, so
nothing that smooths from frame to frame (a follower's steer, a held boundary) may carry from one to the next.

Consecutive frames of a drive, even at speed, show nearly the same scene at thumbnail size; two photos of
different places do not. The measure is the mean absolute difference of two 32x18 grey thumbnails, each
normalised to zero mean and unit spread (so exposure changes do not count). Measured on the real data
(docs/real-kart.md): consecutive frames of the SDC kart's camera at about 14 frames/s differ by 0.018 to 0.073;
the venue's separate scenes by 0.18 to 0.30, and unrelated road photos by 0.27 to 1.2. A cut is more than
``CUT_THRESHOLD``, twice the largest step seen within a drive.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.core.types import FrameSet, Image

__all__ = ["CUT_THRESHOLD", "is_cut", "thumbnail", "with_scene_starts"]

CUT_THRESHOLD = 0.15


def thumbnail(image: Image) -> NDArray[np.float64]:
    """A 32x18 grey thumbnail with zero mean and unit spread."""
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    small = cv2.resize(gray, (32, 18), interpolation=cv2.INTER_AREA).astype(np.float64)
    return (small - small.mean()) / (small.std() + 1.0)


def is_cut(previous: NDArray[np.float64] | None, current: NDArray[np.float64], threshold: float = CUT_THRESHOLD
           ) -> bool:
    """Whether ``current`` starts a new scene after ``previous`` (thumbnails; True when there is none before)."""
    return previous is None or float(np.mean(np.abs(previous - current))) > threshold


def with_scene_starts(frames: Iterable[FrameSet], independent: bool = False, camera: str = "center"
                      ) -> Iterator[tuple[FrameSet, bool]]:
    """Each frame set with whether it starts a new scene (``independent``: every one does), judged on
    ``camera``'s image: where state smoothed over frames must start afresh."""
    previous = None
    for frame_set in frames:
        current = thumbnail(frame_set.images[camera])
        yield frame_set, independent or is_cut(previous, current)
        previous = current

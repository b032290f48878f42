"""The one interface of kartpilot's visual odometry, stereo or monocular.

Both take a :class:`~kartpilot.core.types.FrameSet` and read the cameras they were built for (stereo VO the
rectified left and right, monocular VO one camera), so a localiser, the runner and fault injection treat
them alike.
"""

from __future__ import annotations

from typing import Literal, Protocol

import cv2

from kartpilot.core.errors import PerceptionError
from kartpilot.core.geometry import Array
from kartpilot.core.types import FrameSet, Image

__all__ = ["VOStep", "VisualOdometry", "grey_images"]


class VOStep(Protocol):
    """What every VO reports for one frame set."""

    @property
    def index(self) -> int: ...

    @property
    def stamp_ns(self) -> int: ...

    @property
    def pose_world_cam(self) -> Array:
        """4x4 pose of the VO's (left) camera in the world frame, the camera at the first frame."""

    @property
    def status(self) -> Literal["init", "ok", "bridged"]: ...

    @property
    def reason(self) -> str: ...

    @property
    def inliers(self) -> int:
        """The correspondences the motion rests on (0 where the frame was bridged)."""


class VisualOdometry(Protocol):
    """Stereo and monocular VO alike: ``process`` one frame set, get the step's pose."""

    @property
    def cameras(self) -> tuple[str, ...]:
        """The names of the cameras it reads in each frame set."""

    @property
    def scale_source(self) -> str:
        """Where the metres come from, in words."""

    @property
    def timing_ms(self) -> dict[str, float]:
        """Milliseconds per stage, summed over every frame so far."""

    def process(self, frames: FrameSet) -> VOStep: ...

    def close(self) -> None: ...


def grey_images(frames: FrameSet, cameras: tuple[str, ...]) -> list[Image]:
    """The named cameras' images in 8-bit grey; a camera missing from the set raises PerceptionError."""
    images = []
    for name in cameras:
        image = frames.images.get(name)
        if image is None:
            raise PerceptionError(f"frame {frames.index}: the {name} camera delivered nothing")
        images.append(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image)
    return images

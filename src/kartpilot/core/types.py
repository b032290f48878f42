"""Frozen messages exchanged between stages. Field names carry their units."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from numpy.typing import NDArray

__all__ = ["Image", "StereoFrame"]

Image = NDArray[Any]
"""An 8-bit image (grayscale HxW or BGR HxWx3), as OpenCV returns it."""


@dataclass(frozen=True)
class StereoFrame:
    """A synchronised, rectified stereo pair.

    Attributes:
        index: position of the frame in its source (0-based).
        stamp_ns: capture time in nanoseconds (monotonic within a source).
        left, right: 8-bit grayscale images of equal size, rectified.
    """

    index: int
    stamp_ns: int
    left: Image
    right: Image

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9

"""A frame's colour planes, converted once, and the colour masks the event's detectors build from them.

The detectors ask the same questions of a frame's pixels: is it red (a lamp, a sign's ring, a barrier), green (a
lamp, grass), pale (a barrier's white)? Each asks them of the frame's HSV, and several of its grey.
:func:`~kartpilot.perception.detect.detect_classical` converts the frame once (:class:`ColourPlanes`) and hands
the planes to each detector; a detector called alone converts its own. A colour mask is mostly empty: its
blobs are labelled in the box that holds them (:func:`mask_components`), not over the whole frame.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from kartpilot.core.types import Image

__all__ = ["ColourPlanes", "grass", "green_mask", "mask_components", "red_mask"]


class ColourPlanes(NamedTuple):
    """One frame's HSV (OpenCV's 8-bit: hue 0 to 179; None for a grey frame) and its grey."""

    hsv: Image | None
    gray: Image

    @classmethod
    def of(cls, image: Image) -> ColourPlanes:
        if image.ndim != 3:
            return cls(None, image)
        return cls(cv2.cvtColor(image, cv2.COLOR_BGR2HSV), cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))


def red_mask(hsv: Image, s_min: int, v_min: int, hue_max: int = 10) -> Image:
    """255 where an HSV pixel is red (OpenCV's hue, 0 to 180: up to ``hue_max``, 20 degrees by default, or from
    165) and at least this saturated and bright, else 0."""
    return cv2.bitwise_or(cv2.inRange(hsv, (0, s_min, v_min), (hue_max, 255, 255)),
                          cv2.inRange(hsv, (165, s_min, v_min), (255, 255, 255)))


def green_mask(hsv: Image, s_min: int, v_min: int) -> Image:
    """255 where an HSV pixel is green (hue 40 to 100) and at least this saturated and bright, else 0."""
    return cv2.inRange(hsv, (40, s_min, v_min), (100, 255, 255))


def grass(hsv: Image) -> np.ndarray:
    """Green, saturated HSV pixels (hue 30 to 90, saturation from 50): grass, not road or paint. Boolean."""
    return cv2.inRange(hsv, (30, 50, 0), (90, 255, 255)) > 0


def mask_components(mask: Image) -> tuple[int, Image, np.ndarray, tuple[int, int]]:
    """The 8-connected components of a mask's set pixels, labelled within the box that holds them all: (their
    count with the background's, the labels of that box, each one's (x, y, width, height, area) in the box, the
    box's top-left (x, y) in the mask). A colour mask's box is mostly a small part of the frame, where labelling
    the whole frame costs a millisecond. The box starts on an even row and column: the block-based algorithm
    (BBDT, OpenCV's fastest with statistics here) then meets the pixels in the same 2x2 blocks and order as over
    the whole mask, and numbers the components alike."""
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0 or h == 0:
        return 1, np.zeros((0, 0), np.int32), np.zeros((1, 5), np.int32), (0, 0)
    x0, y0 = x - x % 2, y - y % 2
    count, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(
        np.ascontiguousarray(mask[y0:y + h, x0:x + w]), 8, cv2.CV_32S, cv2.CCL_BBDT)
    return count, labels, stats, (x0, y0)

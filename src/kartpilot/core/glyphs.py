"""Text drawn in an outline (TrueType) font, as a mask: for the digits a speed sign's reader compares with and the
renderer paints on its signs.

OpenCV draws only its Hershey stroke fonts; a road sign's digits are a filled sans-serif. The TrueType fonts come
from matplotlib's own data (DejaVu Sans, shipped in every matplotlib wheel), so nothing is downloaded and every
machine draws the same pixels. The outline is taken with ``matplotlib.textpath.TextPath`` and filled with OpenCV
(even-odd, so a 0's counter stays open).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from kartpilot.core.errors import ConfigError

__all__ = ["FONTS", "text_mask"]

FONTS = {"dejavu-sans": "DejaVuSans.ttf", "dejavu-sans-bold": "DejaVuSans-Bold.ttf"}
"""The outline fonts by name: files in matplotlib's ``mpl-data/fonts/ttf``."""


@lru_cache(maxsize=64)
def text_mask(text: str, font: str, height_px: int, squeeze: float = 1.0) -> np.ndarray:
    """``text`` in ``font`` (a key of :data:`FONTS`), its ink ``height_px`` tall and ``squeeze`` times its natural
    width: a uint8 mask (255 ink, 0 not; anti-aliased at the edges) cut to the ink, read-only."""
    if font not in FONTS:
        raise ConfigError(f"unknown font {font!r}: one of {', '.join(FONTS)}")
    if not text.strip() or height_px < 4 or not 0.2 <= squeeze <= 2.0:
        raise ConfigError("text_mask needs some text, a height of 4 px or more and a squeeze in [0.2, 2]")
    import matplotlib
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextPath

    path = TextPath((0, 0), text, size=100, prop=FontProperties(fname=Path(matplotlib.get_data_path()) / "fonts"
                                                                / "ttf" / FONTS[font]))
    polygons = [np.asarray(p, np.float64) for p in path.to_polygons()]
    polygons = [p for p in polygons if len(p) >= 3]
    points = np.concatenate(polygons)
    (x0, y0), (x1, y1) = points.min(axis=0), points.max(axis=0)
    scale = (height_px - 1) / (y1 - y0)
    width = int(np.ceil((x1 - x0) * scale * squeeze)) + 1
    ink = np.zeros((height_px, width), np.uint8)
    sub = 16  # OpenCV's fixed point: 4 fractional bits
    for polygon in polygons:  # even-odd: each outline flips what it covers (a counter inside a 0 is cut out)
        xy = np.stack([(polygon[:, 0] - x0) * scale * squeeze, (y1 - polygon[:, 1]) * scale], axis=1)
        layer = np.zeros_like(ink)
        cv2.fillPoly(layer, [np.round(xy * sub).astype(np.int32)], 255, cv2.LINE_AA, shift=4)
        ink = cv2.absdiff(ink, layer)
    ink.setflags(write=False)
    return ink

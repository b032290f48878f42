"""The one door for image files: every image kartpilot reads from a file comes through :func:`read_image`.

It names the file in every error, tells a folder from a missing file, refuses an image whose header says it is
larger than :data:`MAX_IMAGE_PIXELS` before a byte of it is decoded (a 50,000 x 50,000 PNG of a few kilobytes
would otherwise take 7.5 GB), finds a JPEG or PNG cut off in its writing (OpenCV decodes those with their lower
part grey, in silence), decodes from the file's bytes whatever its extension says (a PNG named ``.jpg`` is read as
the PNG it is) and whatever its name's encoding, and refuses an image too small to be a camera's view.
"""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np

from kartpilot.core.errors import DataError
from kartpilot.core.files import check_readable
from kartpilot.core.types import Image

__all__ = ["MAX_IMAGE_PIXELS", "MIN_IMAGE_PX", "decode_image", "image_size_from_header", "read_gray", "read_image"]

MIN_IMAGE_PX = 32
"""The smallest side an image may have (a Donkey Car's camera gives 160x120): below it no pipeline has a region of
interest to look at, and OpenCV's resizing and HOG fail inside (one crashed the process)."""

MAX_IMAGE_PIXELS = 50_000_000
"""The most pixels an image file may hold: a 50-megapixel still (8688 x 5792) is the largest a team's camera
makes; a kart's cameras give 0.4 to 2 megapixels. Decoded as BGR, the bound is 150 MB."""


def read_gray(path: str | Path) -> Image:
    """Read an image as 8-bit grayscale (see :func:`read_image`)."""
    return read_image(path, cv2.IMREAD_GRAYSCALE)


def read_image(path: str | Path, flags: int = cv2.IMREAD_COLOR) -> Image:
    """Read an image (BGR by default; OpenCV's ``flags``); a missing, corrupt, cut-off, empty, oversized (its header
    over :data:`MAX_IMAGE_PIXELS`) or tiny (under :data:`MIN_IMAGE_PX` a side) file, or a folder, raises
    DataError naming it."""
    path = Path(path)
    check_readable(path, what="image file")
    try:
        data = np.fromfile(path, np.uint8)  # from its bytes: OpenCV's own reader fails on a name not valid UTF-8
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc.strerror or exc}") from None
    if data.size == 0:  # OpenCV asserts on an empty buffer rather than returning None
        raise DataError(f"the image {path} is empty (0 bytes)")
    _check_complete(path, data)
    image = decode_image(data, str(path), flags)
    if min(image.shape[:2]) < MIN_IMAGE_PX:
        raise DataError(f"the image {path} is {image.shape[1]}x{image.shape[0]} px: too small for a camera's view "
                        f"(at least {MIN_IMAGE_PX} px a side)")
    return image


def decode_image(data: np.ndarray, source: str, flags: int = cv2.IMREAD_COLOR) -> Image:
    """An image from its encoded bytes (a file's, a bag message's): over :data:`MAX_IMAGE_PIXELS` by its header,
    or not an image, raises DataError naming ``source``."""
    size = image_size_from_header(data[:65536].tobytes())
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise DataError(f"the image {source} is {size[0]}x{size[1]} px by its header: more than the "
                        f"{MAX_IMAGE_PIXELS / 1e6:.0f} megapixels kartpilot reads")
    image = cv2.imdecode(data, flags) if data.size else None
    if image is None or image.size == 0:
        raise DataError(f"cannot read image (corrupt or not an image): {source}")
    return image


def image_size_from_header(head: bytes) -> tuple[int, int] | None:
    """(width, height) from the first bytes of a PNG, JPEG, BMP or GIF; None for another format or a header cut
    short (the decoder then has the last word, within the file's own size)."""
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24:
        width, height = struct.unpack(">II", head[16:24])
        return int(width), int(height)
    if head[:2] == b"BM" and len(head) >= 26:
        width, height = struct.unpack("<ii", head[18:26])
        return abs(int(width)), abs(int(height))
    if head[:6] in (b"GIF87a", b"GIF89a") and len(head) >= 10:
        width, height = struct.unpack("<HH", head[6:10])
        return int(width), int(height)
    if head[:2] == b"\xff\xd8":
        k = 2
        while k + 9 < len(head):
            if head[k] != 0xFF:
                return None
            marker = head[k + 1]
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
                k += 2
                continue
            length = struct.unpack(">H", head[k + 2:k + 4])[0]
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # a start of frame
                height, width = struct.unpack(">HH", head[k + 5:k + 9])
                return int(width), int(height)
            k += 2 + length
    return None


def _check_complete(path: Path, data: np.ndarray) -> None:
    """A JPEG must end with its end-of-image marker, a PNG with its IEND chunk (a few padding bytes allowed)."""
    head, tail = data[:8].tobytes(), data[-64:].tobytes()
    if head[:3] == b"\xff\xd8\xff" and b"\xff\xd9" not in tail.rstrip(b"\x00\r\n ")[-4:]:
        raise DataError(f"the JPEG {path} is cut off: it has no end-of-image marker")
    if head == b"\x89PNG\r\n\x1a\n" and b"IEND" not in tail[-16:]:
        raise DataError(f"the PNG {path} is cut off: it has no IEND chunk")

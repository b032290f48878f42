"""The suite's own helpers, where a test's claim rests on them."""

import cv2
import numpy as np

from tests.conftest import png_grey


def test_png_grey_is_the_grey_a_recording_s_png_reads_back_as_on_every_colour():
    levels = np.arange(256, dtype=np.uint8)
    red, green, blue = np.meshgrid(levels, levels, levels, indexing="ij")
    image = np.stack([blue, green, red], axis=-1).reshape(4096, 4096, 3)  # every 24-bit colour once
    ok, png = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    assert ok
    read_back = cv2.imdecode(png, cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(png_grey(image), read_back)
    assert not np.array_equal(png_grey(image), cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))  # why it is not cvtColor

"""Text in an outline font, from matplotlib's bundled DejaVu Sans: the digits a speed sign shows."""

import numpy as np
import pytest

from kartpilot.core.errors import ConfigError
from kartpilot.core.glyphs import text_mask


def test_digits_are_filled_their_counters_open_and_their_size_as_asked():
    zero = text_mask("0", "dejavu-sans-bold", 60)
    assert zero.shape[0] == 60 and zero.dtype == np.uint8
    h, w = zero.shape
    assert zero[h // 2, w // 2] == 0  # the counter inside the 0 is open (even-odd fill)
    assert zero[h // 2, :w // 4].max() == 255 and zero[h // 2, 3 * w // 4:].max() == 255  # its two sides are ink
    assert zero[0].max() > 0 and zero[-1].max() > 0 and zero[:, 0].max() > 0  # cut to the ink
    narrow = text_mask("20", "dejavu-sans", 60, squeeze=0.85)
    assert narrow.shape[1] == pytest.approx(0.85 * text_mask("20", "dejavu-sans", 60).shape[1], abs=2)
    assert text_mask("20", "dejavu-sans-bold", 60).mean() > text_mask("20", "dejavu-sans", 60).mean()  # heavier
    with pytest.raises(ValueError):
        zero[0, 0] = 1  # cached: read-only


def test_an_unknown_font_or_no_text_is_an_error_naming_it():
    with pytest.raises(ConfigError, match="comic"):
        text_mask("20", "comic-sans", 40)
    with pytest.raises(ConfigError, match="text"):
        text_mask(" ", "dejavu-sans", 40)

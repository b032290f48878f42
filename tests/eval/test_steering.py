"""The agreement of a follower's steer with a human's pulsed joystick steering."""

import math

import numpy as np
import pytest

from kartpilot.core.errors import EvaluationError
from kartpilot.eval.steering import smoothed_steer, steer_agreement


def _pulsed_human(rate_hz: float, seconds: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A smooth intended steer, and the joystick's version: held in short pulses, 0 two thirds of the time."""
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    intended = 0.8 * np.sin(2 * np.pi * t / 6.0)
    pulses = (np.arange(len(t)) // 2) % 3 == 0  # two frames on, four off
    return intended, np.where(pulses, np.clip(3 * intended, -1, 1), 0.0) + rng.normal(0, 0.02, len(t))


def test_a_follower_that_steers_as_the_human_means_agrees_although_the_joystick_pulses():
    rng = np.random.default_rng(1)
    intended, joystick = _pulsed_human(20.0, 60.0, rng)
    follower = 0.3 * intended + rng.normal(0, 0.02, len(intended))  # another scale, in radians
    raw = float(np.corrcoef(follower, joystick)[0, 1])
    report = steer_agreement(follower, joystick, 20.0)
    assert report.correlation > 0.9 > raw + 0.05  # the smoothing is what makes the comparison fair
    assert report.sign_agreement > 0.97 and report.turning_frames > 0.3 * report.frames
    # a follower steering the other way is found out, one steering at random gets chance
    assert steer_agreement(-follower, joystick, 20.0).sign_agreement < 0.03
    noise = steer_agreement(rng.normal(0, 1, len(follower)), joystick, 20.0)
    assert abs(noise.correlation) < 0.1 and 0.4 < noise.sign_agreement < 0.6


def test_smoothing_is_a_centred_average_over_the_window():
    steer = np.zeros(41)
    steer[20] = 1.0
    out = smoothed_steer(steer, 20.0, 0.25)  # 5 samples
    assert out[18:23] == pytest.approx([0.2] * 5) and out.sum() == pytest.approx(1.0)
    assert np.array_equal(smoothed_steer(steer, 20.0, 0.0), steer)


def test_bad_input_is_refused_by_name():
    with pytest.raises(EvaluationError, match="one steer per frame"):
        steer_agreement(np.zeros(3), np.zeros(4), 20.0)
    with pytest.raises(EvaluationError, match="finite"):
        steer_agreement(np.array([0.0, math.nan]), np.zeros(2), 20.0)
    with pytest.raises(EvaluationError, match="positive rate"):
        smoothed_steer(np.zeros(3), 0.0)
    assert math.isnan(steer_agreement(np.zeros(5), np.zeros(5), 20.0).correlation)


def test_lanes_on_a_tub_compares_with_the_smoothed_human_at_the_tub_s_rate(tmp_path, capsys):
    import json

    import cv2
    from tests.sensors.test_donkeycar import write_tub

    from kartpilot.cli.main import main

    angles = [0.9 if (i // 2) % 3 == 0 else 0.0 for i in range(40)]  # pulses to the right, 20 Hz
    lines = [json.dumps({"_index": i, "_timestamp_ms": 1000 + 50 * i, "cam/image_array": f"{i}.jpg",
                         "user/angle": a}) for i, a in enumerate(angles)]
    write_tub(tmp_path / "tub", lines)
    for i in range(40):
        cv2.imwrite(str(tmp_path / "tub" / "images" / f"{i}.jpg"), np.full((120, 160, 3), 40, np.uint8))
    assert main(["lanes", str(tmp_path / "tub"), "--out", str(tmp_path / "lanes.csv")]) == 0
    printed = capsys.readouterr().out
    turning = int((np.abs(smoothed_steer(np.array(angles), 20.0)) > 0.3).sum())
    assert 0 < turning < 40 and f"over the {turning} frames where the human clearly turns" in printed

"""How well a follower's steering agrees with a human driver's, on a recording with the human's commands.

A joystick is steered in pulses: on the shared Donkey Car tubs about two thirds of the frames are exactly 0
while the car turns. So the human's steer is first smoothed over about half a second (a centred moving
average), and the follower's steer is compared with that: the correlation over every frame, and the sign
agreement over the frames where the smoothed human steer is clearly a turn (beyond ``turning``, in the
human's normalised -1..1 units). Both are independent of the two steers' scales.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from kartpilot.core.errors import EvaluationError

__all__ = ["SteerAgreement", "smoothed_steer", "steer_agreement"]


@dataclass(frozen=True)
class SteerAgreement:
    """Attributes:
        correlation: Pearson's r of the follower's steer and the human's smoothed steer, over every frame.
        sign_agreement: the share of turning frames where both steer to the same side.
        turning_frames: the frames where the smoothed human steer is beyond the threshold.
        frames: the frames compared.
    """

    correlation: float
    sign_agreement: float
    turning_frames: int
    frames: int


def smoothed_steer(steer: np.ndarray, rate_hz: float, window_s: float = 0.5) -> np.ndarray:
    """A centred moving average of ``steer`` over ``window_s`` (at least one sample)."""
    if not rate_hz > 0 or not window_s >= 0:
        raise EvaluationError(f"smoothing needs a positive rate and a window of at least 0 s, got {rate_hz}, "
                              f"{window_s}")
    size = max(1, round(window_s * rate_hz))
    return uniform_filter1d(np.asarray(steer, dtype=float), size, mode="nearest")


def steer_agreement(follower: np.ndarray, human: np.ndarray, rate_hz: float, window_s: float = 0.5,
                    turning: float = 0.3) -> SteerAgreement:
    """Compare ``follower`` with ``human`` smoothed over ``window_s``; both positive to the same side."""
    follower, human = np.asarray(follower, dtype=float), np.asarray(human, dtype=float)
    if follower.shape != human.shape or follower.ndim != 1:
        raise EvaluationError(f"one steer per frame for both, got {follower.shape} and {human.shape}")
    if not (np.isfinite(follower).all() and np.isfinite(human).all()):
        raise EvaluationError("the steers must be finite")
    reference = smoothed_steer(human, rate_hz, window_s)
    correlation = (float(np.corrcoef(follower, reference)[0, 1])
                   if len(follower) > 1 and follower.std() > 0 and reference.std() > 0 else math.nan)
    turns = np.abs(reference) > turning
    agree = float(np.mean(np.sign(follower[turns]) == np.sign(reference[turns]))) if turns.any() else math.nan
    return SteerAgreement(correlation, agree, int(turns.sum()), len(follower))

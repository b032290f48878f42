"""Steering and speed from lane boundaries: the thesis's lane follower, with what it lacked.

The thesis steered toward the boundaries' intersection (its equations 1 and 2), kept the last steer
for a few frames when no boundary was seen and then halted, used a slower throttle in turns, and let
the side cameras' off-track steer override the centre camera. It oscillated and settled off-centre.
Added here: a lateral-offset term (the lane centre against the image centre), exponential smoothing
and a rate limit on the steer, a side preference at splits (the lane suddenly widening, seen far ahead
first at speed, with the kept boundary guarded against the fork's inner line), a speed plan from what
the camera sees (slower before a bend and through a split) in place of the thesis's fixed slower throttle
in turns, a fusion rule for both side cameras at once that steers away from the nearer boundary, and the
side cameras' steer added to the centre camera's instead of replacing it (in a corner the two took turns
and the kart weaved).

``lane_follow_step`` is a pure function: state in, decision and state out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

from kartpilot.perception.lanes import LaneLine, LaneObservation, heading_deviation_rad, intersection

__all__ = ["LaneDecision", "LaneFollowConfig", "LaneFollowState", "heading_follow_step", "lane_follow_step"]


@dataclass(frozen=True)
class LaneFollowConfig:
    """Attributes:
        max_steer_rad: the kart's maximum steer (S_max in the thesis).
        heading_gain: steer per radian of heading deviation (1: the thesis).
        offset_gain: steer (rad) per unit of lateral offset, the lane centre's distance from the image
            centre at the bottom row over the lane's width there (0: the thesis).
        smoothing: weight of the previous steer in the exponential smoothing (0: none, the thesis).
        max_steer_rate_radps: how fast the commanded steer may change.
        hold_frames: frames the last steer is kept when no boundary is seen; then the kart halts.
        speed_plan: ``ahead`` (full throttle while the steer and the boundaries' meeting point, far ahead,
            stay within a quarter of ``turn_threshold_rad`` and ``bend_ahead_rad``; then it eases to
            ``throttle_turn`` as either reaches its threshold; lower at splits and when unsure) or ``steer``
            (the thesis's two fixed throttles, the lower one when the steer exceeds ``turn_threshold_rad``).
        throttle_split: the most throttle while a split lasts.
        full_confidence: below this detection confidence the throttle falls in proportion (to
            ``throttle_turn`` times itself at least); 0, the default: off. At the 30 km/h mode on sdc-assen the
            throttle's dips in an unsure corner set off a weave that touched a line (docs/lanes.md).
        split_preference: which side's boundary to follow when the lane suddenly widens (a split).
        split_width_ratio: how much wider than usual the lane must look at the region's bottom to count
            as a split.
        split_far_ratio, split_far_row: the same, at a row far ahead (a fraction of the region's height from
            its top), where a split shows first: at speed the near widening is seen too late.
        split_confirm_frames: a widening counts as a split when seen in this many frames in a row.
        split_hold_s: how long the split's rule holds after the last widening seen.
        split_gate: at a split, the kept boundary may not jump toward the other side by more than this
            fraction of the image's width at the far row (the fork's inner line is not it).
        boundary_jump: a boundary whose bottom moved more than this share of the lane's usual width since the
            last frame it was believed is a bad fit (a stop line's end, a shadow's edge, a blurred frame), not
            the road: the other boundary and the usual width stand in for it, and it neither votes for a split
            nor teaches the width. A kart moves a boundary's bottom a few per cent of the width a frame, a
            split's widening too; after ``hold_frames`` such frames in a row the new place is believed.
        side_rule: how a side camera's steer away from a boundary meets the centre camera's: ``blend`` adds it
            (``side_gain`` times the maximum steer at the nearest), so in a corner the centre's turn is eased
            rather than reversed; ``override`` replaces the centre's steer (the thesis's rule), which in a
            corner hands the steer back and forth between the two and makes the kart weave.
        side_gain: the side camera's steer at the nearest boundary, as a share of ``max_steer_rad``.
        both_sides: with both side cameras steering, ``nearer`` steers away from the nearer boundary;
            ``left_first`` always takes the left camera's steer to the right (the thesis's rule).
        missing_side: with one boundary seen, put the other a remembered lane width away (``lane_width``)
            or use the image's extreme column as the thesis did (``extreme``).
    """

    max_steer_rad: float = 0.40
    heading_gain: float = 0.6
    offset_gain: float = 0.25
    smoothing: float = 0.4
    max_steer_rate_radps: float = 1.5
    hold_frames: int = 8
    throttle_straight: float = 1.0
    throttle_turn: float = 0.6
    turn_threshold_rad: float = 0.12
    speed_plan: Literal["ahead", "steer"] = "ahead"
    bend_ahead_rad: float = 0.15
    throttle_split: float = 0.6
    full_confidence: float = 0.0
    split_preference: Literal["right", "left"] = "right"
    split_width_ratio: float = 1.45
    split_far_ratio: float = 1.45
    split_far_row: float = 0.05
    split_hold_s: float = 1.5
    split_confirm_frames: int = 3
    split_gate: float = 0.05
    boundary_jump: float = 0.3
    side_rule: Literal["blend", "override"] = "blend"
    side_gain: float = 1.0
    both_sides: Literal["nearer", "left_first"] = "nearer"
    missing_side: Literal["lane_width", "extreme"] = "lane_width"

    def __post_init__(self) -> None:
        checks = {"turn_threshold_rad": self.turn_threshold_rad > 0, "bend_ahead_rad": self.bend_ahead_rad > 0,
                  "throttle_split": 0 <= self.throttle_split <= 1, "full_confidence": 0 <= self.full_confidence <= 1,
                  "split_far_row": 0 <= self.split_far_row < 1, "split_confirm_frames": self.split_confirm_frames >= 1,
                  "split_hold_s": self.split_hold_s >= 0, "split_gate": self.split_gate >= 0,
                  "boundary_jump": self.boundary_jump > 0,
                  "side_gain": self.side_gain >= 0}
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"{bad[0]} is out of range ({getattr(self, bad[0])!r})")


@dataclass(frozen=True)
class LaneFollowState:
    """What the follower remembers: its last steer, how long it has seen nothing, the lane's usual width at
    the region's bottom, top and far row, how long a split still lasts, the boundary kept there and for how
    many frames it has not been seen, for how many frames in a row the lane has looked wider, and where each
    boundary's bottom was last believed (and for how many frames in a row one has jumped from it)."""

    steer_rad: float = 0.0
    frames_without_lane: int = 0
    lane_width_bottom_px: float = 0.0
    lane_width_top_px: float = 0.0
    lane_width_far_px: float = 0.0
    split_left_s: float = 0.0
    kept_line: LaneLine | None = None
    kept_age: int = 0
    split_votes: int = 0
    bottoms_px: tuple[float, float] = (math.nan, math.nan)
    jumps: int = 0


@dataclass(frozen=True)
class LaneDecision:
    """Steer (rad, positive left), throttle and brake, and which rule produced them."""

    steer_rad: float
    throttle: float
    brake: float
    reason: Literal["centre", "split", "side-left", "side-right", "hold", "halt", "path"]


def lane_follow_step(config: LaneFollowConfig, state: LaneFollowState, centre: LaneObservation | None,
                     away_from_left: float = 0.0, away_from_right: float = 0.0, dt_s: float = 1 / 30
                     ) -> tuple[LaneDecision, LaneFollowState]:
    """One control step.

    Args:
        centre: the centre camera's observation (None when the camera delivered nothing).
        away_from_left, away_from_right: the side cameras' steers away from a boundary, 0 to 1.
    """
    side: Literal["side-left", "side-right"] | None = None
    side_steer = 0.0
    if away_from_left > 0 or away_from_right > 0:
        if away_from_left > 0 and away_from_right > 0:
            use_left = config.both_sides == "left_first" or away_from_left >= away_from_right
        else:
            use_left = away_from_left > 0
        side = "side-left" if use_left else "side-right"
        side_steer = -away_from_left if use_left else away_from_right
        if config.side_rule == "override" or centre is None or not centre.any_detected:
            steer = _rate_limited(config, state, side_steer * config.max_steer_rad, dt_s)
            return LaneDecision(steer, config.throttle_turn, 0.0, side), replace(
                state, steer_rad=steer, frames_without_lane=0)
        side_steer *= config.side_gain * config.max_steer_rad

    if centre is None or not centre.any_detected:
        return _nothing_seen(config, state)

    width_b, width_t, width_f = state.lane_width_bottom_px, state.lane_width_top_px, state.lane_width_far_px
    split_left_s, kept, kept_age, votes = state.split_left_s, state.kept_line, state.kept_age, 0
    reason: Literal["centre", "split"] = "centre"
    left, right, target = centre.left, centre.right, centre.intersection_px
    far_row = left.y_top + config.split_far_row * (left.y_bottom - left.y_top)
    preferred = config.split_preference
    virtual = False
    jumped_side, bottoms, jumps = _jumped(config, state, centre, width_b)
    if jumped_side:  # one boundary leapt: a bad fit; the other and the usual width stand in for it
        left, right = _keep_one_side("left" if jumped_side == "right" else "right", left, right, width_b, width_t)
        target, virtual = _aim(centre, left, right), True
    elif centre.both_detected:
        now_b, now_t = right.x_bottom - left.x_bottom, right.x_top - left.x_top
        now_f = right.x_at(far_row) - left.x_at(far_row)
        if (width_b > 0 and now_b > config.split_width_ratio * width_b) or (
                width_f > 0 and now_f > config.split_far_ratio * width_f):
            votes = state.split_votes + 1  # the lane widens: near, or far ahead first at speed
            if votes >= config.split_confirm_frames:
                split_left_s = config.split_hold_s
        elif split_left_s <= 0 and _plausible(now_b, width_b) and _plausible(now_f, width_f):
            width_b = now_b if width_b <= 0 else 0.9 * width_b + 0.1 * now_b
            width_t = now_t if width_t <= 0 else 0.9 * width_t + 0.1 * now_t
            width_f = now_f if width_f <= 0 else 0.9 * width_f + 0.1 * now_f
    if split_left_s > 0 and width_b > 0:
        # keep the preferred side's boundary, as long as it does not jump toward the other side (the fork's
        # inner line, taken for it); without it, the last one that was kept
        reason = "split"
        line = right if preferred == "right" else left
        source = centre.right_source if preferred == "right" else centre.left_source
        gate = config.split_gate * centre.width_px
        jumped = kept is not None and (line.x_at(far_row) < kept.x_at(far_row) - gate if preferred == "right"
                                       else line.x_at(far_row) > kept.x_at(far_row) + gate)
        if source == "detected" and not jumped:
            kept, kept_age = line, 0
        else:
            kept_age += 1
        if kept is not None and kept_age <= config.hold_frames:
            left, right = _keep_one_side(preferred, kept if preferred == "left" else left,
                                         kept if preferred == "right" else right, width_b, width_t)
            target, virtual = _aim(centre, left, right), True
    elif not centre.both_detected and config.missing_side == "lane_width" and width_b > 0 and not jumped_side:
        seen = "right" if centre.right_source == "detected" else "left"
        left, right = _keep_one_side(seen, left, right, width_b, width_t)
        target, virtual = _aim(centre, left, right), True
    if split_left_s <= 0:
        kept, kept_age = None, 0
    deviation = heading_deviation_rad(centre, target)  # positive: the lane goes right
    steer_right = config.heading_gain * deviation
    if centre.both_detected or virtual:
        lane_centre = (left.x_bottom + right.x_bottom) / 2
        lane_width = max(right.x_bottom - left.x_bottom, 1.0)
        steer_right += config.offset_gain * (lane_centre - (centre.width_px - 1) / 2) / lane_width
    ahead = _bend_ahead(centre, deviation)
    if side is None:
        steer = _smoothed(config, state, -steer_right, dt_s)
        throttle = _throttle(config, steer, ahead, centre.confidence, reason == "split")
    else:  # the side camera's steer away eases the centre's, and the kart slows as in a turn
        steer = _smoothed(config, state, side_steer - steer_right, dt_s)
        throttle = min(config.throttle_turn, _throttle(config, steer, ahead, centre.confidence, reason == "split"))
    return LaneDecision(steer, throttle, 0.0, side or reason), LaneFollowState(
        steer, 0, width_b, width_t, width_f, max(0.0, split_left_s - dt_s), kept, kept_age, votes, bottoms, jumps)


def _jumped(config: LaneFollowConfig, state: LaneFollowState, centre: LaneObservation, width_b: float
            ) -> tuple[str, tuple[float, float], int]:
    """Which detected boundary, if one, leapt since it was last believed (``boundary_jump``), the boundaries'
    bottoms to believe from now on, and how many frames in a row one has leapt."""
    now = (centre.left.x_bottom if centre.left_source == "detected" else math.nan,
           centre.right.x_bottom if centre.right_source == "detected" else math.nan)
    if width_b <= 0 or state.jumps >= config.hold_frames:
        return "", now, 0
    leap = config.boundary_jump * width_b
    moved = [abs(a - b) > leap for a, b in zip(now, state.bottoms_px, strict=True)]  # NaN: not a leap
    if moved[0] != moved[1] and centre.both_detected:
        side = "left" if moved[0] else "right"
        kept = (state.bottoms_px[0], now[1]) if side == "left" else (now[0], state.bottoms_px[1])
        return side, kept, state.jumps + 1
    believed = [n if math.isfinite(n) else b for n, b in zip(now, state.bottoms_px, strict=True)]
    return "", (believed[0], believed[1]), 0


def _plausible(now_px: float, usual_px: float) -> bool:
    """A width worth remembering: positive, and near the usual one. A bad fit would drag the memory; and a
    lane that widens gradually (a split's ramp) must not be learnt as the usual width before it counts."""
    return now_px > 0 and (usual_px <= 0 or 0.8 < now_px / usual_px < 1.2)


def heading_follow_step(config: LaneFollowConfig, state: LaneFollowState, deviation_rad: float | None,
                        dt_s: float = 1 / 30) -> tuple[LaneDecision, LaneFollowState]:
    """One control step toward a target bearing (positive to the right) found by other means than two lines,
    such as a taped track's centre (:func:`kartpilot.perception.tape.detect_tape_track`): the heading term
    alone, with the same smoothing, rate limit, turn throttle and hold-then-halt as :func:`lane_follow_step`.
    ``None``: nothing was seen."""
    if deviation_rad is None or not math.isfinite(deviation_rad):
        return _nothing_seen(config, state)
    steer = _smoothed(config, state, -config.heading_gain * deviation_rad, dt_s)
    return LaneDecision(steer, _throttle(config, steer, deviation_rad), 0.0, "centre"), replace(
        state, steer_rad=steer, frames_without_lane=0)


def _rate_limited(config: LaneFollowConfig, state: LaneFollowState, target: float, dt_s: float) -> float:
    max_step = config.max_steer_rate_radps * dt_s
    target = max(-config.max_steer_rad, min(config.max_steer_rad, target))
    return state.steer_rad + max(-max_step, min(max_step, target - state.steer_rad))


def _smoothed(config: LaneFollowConfig, state: LaneFollowState, target: float, dt_s: float) -> float:
    return _rate_limited(config, state, config.smoothing * state.steer_rad + (1 - config.smoothing) * target, dt_s)


_STRAIGHT = 0.25  # below this share of turn_threshold_rad and bend_ahead_rad, the road counts as straight


def _throttle(config: LaneFollowConfig, steer: float, ahead_rad: float = 0.0, confidence: float = 1.0,
              split: bool = False) -> float:
    """The speed plan: full throttle on a straight, down to ``throttle_turn`` as the steer or the bend ahead
    grows, at most ``throttle_split`` at a split, and in proportion to the confidence below
    ``full_confidence``."""
    if config.speed_plan == "steer":
        return config.throttle_turn if abs(steer) > config.turn_threshold_rad else config.throttle_straight
    bend = max(abs(steer) / config.turn_threshold_rad, abs(ahead_rad) / config.bend_ahead_rad)
    ease = min(1.0, max(0.0, (bend - _STRAIGHT) / (1.0 - _STRAIGHT)))  # a straight's small corrections: none
    throttle = config.throttle_straight - (config.throttle_straight - config.throttle_turn) * ease
    if split:
        throttle = min(throttle, config.throttle_split)
    if confidence < config.full_confidence:
        throttle *= max(confidence / config.full_confidence, config.throttle_turn)
    return throttle


def _nothing_seen(config: LaneFollowConfig, state: LaneFollowState) -> tuple[LaneDecision, LaneFollowState]:
    """The last steer for ``hold_frames``, then a halt with full brake."""
    missing = state.frames_without_lane + 1
    if missing <= config.hold_frames:
        return LaneDecision(state.steer_rad, config.throttle_turn, 0.0, "hold"), replace(
            state, frames_without_lane=missing)
    return LaneDecision(state.steer_rad, 0.0, 1.0, "halt"), replace(state, frames_without_lane=missing)


def _bend_ahead(centre: LaneObservation, deviation_rad: float) -> float:
    """The bend the speed plan slows for: where both boundaries were found as curves, the bearing of the lane's
    centre at the farthest row both are seen (the aim lies nearer, about 4 m ahead: too late to slow for a
    tight bend at speed); else the deviation the steer follows (the thesis's far meeting point)."""
    left, right = centre.left_curve, centre.right_curve
    if left is None or right is None:
        return deviation_rad
    far = max(left.y_far, right.y_far)
    return heading_deviation_rad(centre, ((float(left.x_at(far)) + float(right.x_at(far))) / 2, far))


def _aim(centre: LaneObservation, left: LaneLine, right: LaneLine) -> tuple[float, float] | None:
    """The point to aim at between two boundaries (one of them put a lane width from the other): the lane's
    centre at the chords' top where the boundaries were found as curves (they end at the aim row), else the
    thesis's meeting point of the two lines."""
    if centre.left_curve is not None or centre.right_curve is not None:
        return (left.x_top + right.x_top) / 2, left.y_top
    return intersection(left, right)


def _keep_one_side(side: str, left: LaneLine, right: LaneLine, width_b: float, width_t: float
                   ) -> tuple[LaneLine, LaneLine]:
    """At a split, keep the preferred boundary and put the other one a usual lane width away."""
    if side == "right":
        virtual = LaneLine(right.x_bottom - width_b, right.y_bottom, right.x_top - width_t, right.y_top)
        return virtual, right
    virtual = LaneLine(left.x_bottom + width_b, left.y_bottom, left.x_top + width_t, left.y_top)
    return left, virtual

"""The Stanley steering law (Hoffmann, Tomlin, Montemerlo and Thrun, 2007), measured at the front axle."""

from __future__ import annotations

import math
from dataclasses import dataclass

from kartpilot.core.errors import ConfigError

__all__ = ["StanleyConfig", "heading_lookahead_m", "stanley_steer"]


@dataclass(frozen=True)
class StanleyConfig:
    """Attributes:
        k_heading: gain on the heading error (the thesis: 0.5).
        k_cross_track: gain on the cross-track error (the thesis: 1.2), per second.
        softening_mps: ``k_s``; keeps the cross-track term finite and calm at low speed.
        heading_lookahead_m, heading_lookahead_time_s: the path heading is taken
            ``heading_lookahead_m + heading_lookahead_time_s * speed`` ahead of the front axle's nearest
            point (the thesis's suggestion), which anticipates bends and damps a recorded path's noise.
        curvature_feedforward: add ``atan(L * curvature)`` less what the heading term gives in a steady
            bend (where the heading error is ``(L + look-ahead) * curvature``), so the kart holds a
            bend with no cross-track error; the gains then act only on deviations.
    """

    k_heading: float = 0.5
    k_cross_track: float = 1.2
    softening_mps: float = 0.5
    heading_lookahead_m: float = 0.2
    heading_lookahead_time_s: float = 0.15
    curvature_feedforward: bool = True

    def __post_init__(self) -> None:
        if (self.k_heading < 0 or self.k_cross_track < 0 or self.softening_mps <= 0 or self.heading_lookahead_m < 0
                or self.heading_lookahead_time_s < 0):
            raise ConfigError("stanley: gains and look-ahead must not be negative, softening_mps must be positive")


def heading_lookahead_m(config: StanleyConfig, speed_mps: float) -> float:
    """How far ahead of the front axle the path heading is taken at this speed."""
    return config.heading_lookahead_m + config.heading_lookahead_time_s * abs(speed_mps)


def stanley_steer(config: StanleyConfig, cross_track_m: float, heading_error_rad: float, speed_mps: float,
                  curvature_per_m: float = 0.0, wheelbase_m: float = 0.0) -> float:
    """Road-wheel angle (positive left), unclipped.

    ``delta = k_h * theta_e - atan(k_e * e / (k_s + |v|)) [+ delta_ff]`` with ``e`` the front axle's signed
    distance from the path (positive when the kart is left of it), ``theta_e`` the path heading at the
    look-ahead point minus the kart's heading, and
    ``delta_ff = atan(L * curvature) - k_h * (L + look-ahead) * curvature``.
    """
    steer = config.k_heading * heading_error_rad - math.atan(
        config.k_cross_track * cross_track_m / (config.softening_mps + abs(speed_mps)))
    if config.curvature_feedforward:
        steady_heading_error = (wheelbase_m + heading_lookahead_m(config, speed_mps)) * curvature_per_m
        steer += math.atan(wheelbase_m * curvature_per_m) - config.k_heading * steady_heading_error
    return steer

"""Pure pursuit: steer the rear axle onto a circle through a look-ahead point."""

from __future__ import annotations

import math

__all__ = ["pure_pursuit_steer"]


def pure_pursuit_steer(x_m: float, y_m: float, yaw_rad: float, target_x_m: float, target_y_m: float,
                       wheelbase_m: float) -> float:
    """Road-wheel angle (positive left) that takes the rear axle at (x, y, yaw) through the target.

    ``delta = atan(2 L sin(alpha) / l_d)``, with ``alpha`` the target's bearing from the heading and
    ``l_d`` its distance (Coulter, 1992).
    """
    dx, dy = target_x_m - x_m, target_y_m - y_m
    distance = math.hypot(dx, dy)
    if distance < 1e-6:
        return 0.0
    alpha = math.atan2(dy, dx) - yaw_rad
    return math.atan2(2.0 * wheelbase_m * math.sin(alpha), distance)

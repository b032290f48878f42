"""Built-in drivers that produce data and baselines in the simulator.

* ``centerline``: pure pursuit on the ground-truth centre line (privileged: it
  reads the simulator's true pose), optionally weaving or hugging one edge like
  the thesis's zig-zag and lane-edge data runs;
* ``commands``: replays the actuator commands of a recording.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from kartpilot.control.longitudinal import SpeedPIConfig, SpeedPIState, speed_pi
from kartpilot.control.pure_pursuit import pure_pursuit_steer
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, FrameSet
from kartpilot.sim.simulator import Simulator
from kartpilot.sim.track import SAMPLE_SPACING_M, project_onto

__all__ = ["CenterlineDriver", "CenterlineDriverConfig", "CommandsDriver"]


@dataclass(frozen=True)
class CenterlineDriverConfig:
    """Attributes:
        speed_mps: target speed.
        lookahead_m, lookahead_time_s: look-ahead distance = lookahead_m + lookahead_time_s * speed.
        edge_offset_m: drive this far left (+) or right (-) of the centre line.
        weave_amplitude_m, weave_period_m: a sinusoidal zig-zag around that line.
        trim_gain_rad_per_m_s: how fast the driver trims the steering against a steady pull (a kart that
            drags to one side, a sloped track), per metre of offset and second, as a human driver does
            (0: no trim). It learns on straights only: in bends pure pursuit cuts inside by design.
        trim_limit_rad: the trim's bound.
    """

    speed_mps: float = 1.0
    lookahead_m: float = 0.6
    lookahead_time_s: float = 0.6
    edge_offset_m: float = 0.0
    weave_amplitude_m: float = 0.0
    weave_period_m: float = 12.0
    trim_gain_rad_per_m_s: float = 0.1
    trim_limit_rad: float = 0.1
    speed_control: SpeedPIConfig = field(default_factory=SpeedPIConfig)


class CenterlineDriver:
    """Follows the route's centre line (plus offsets) from the simulator's true pose."""

    def __init__(self, sim: Simulator, config: CenterlineDriverConfig | None = None) -> None:
        self.sim = sim
        self.config = config or CenterlineDriverConfig()
        if self.config.speed_mps <= 0:
            raise ConfigError("the centerline driver's speed must be positive")
        self._speed_state = SpeedPIState()
        self._hint = sim.track.start_index
        self._trim_rad = 0.0

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        sim, cfg = self.sim, self.config
        state, route, vehicle = sim.state, sim.track.route, sim.vehicle
        here = project_onto(route, np.array([state.x_m, state.y_m]), self._hint)
        self._hint = here.index
        error = here.offset_m - self._wanted_offset(float(route.s_m[here.index]))
        straight = abs(float(route.curvature_1pm[here.index])) < 0.01  # in bends pure pursuit cuts inside
        if cfg.trim_gain_rad_per_m_s > 0 and state.vx_mps > 0.2 and straight:
            self._trim_rad -= cfg.trim_gain_rad_per_m_s * min(max(error, -0.2), 0.2) * sim.dt_s
            self._trim_rad = min(max(self._trim_rad, -cfg.trim_limit_rad), cfg.trim_limit_rad)
        lookahead = cfg.lookahead_m + cfg.lookahead_time_s * max(state.vx_mps, cfg.speed_mps)
        steps = round(lookahead / SAMPLE_SPACING_M)
        i = (here.index + steps) % len(route.s_m) if route.closed else min(here.index + steps, len(route.s_m) - 1)
        s_target = float(route.s_m[i])
        offset = self._wanted_offset(s_target)
        heading = float(route.heading_rad[i])  # one normal, not the whole route's every step
        target = route.xy_m[i] + offset * np.array([-math.sin(heading), math.cos(heading)])
        steer = pure_pursuit_steer(state.x_m, state.y_m, state.yaw_rad, float(target[0]), float(target[1]),
                                   vehicle.wheelbase_m) + self._trim_rad
        steer = max(-vehicle.max_steer_rad, min(vehicle.max_steer_rad, steer))
        throttle, brake, self._speed_state = speed_pi(cfg.speed_control, self._speed_state, cfg.speed_mps,
                                                      state.vx_mps, sim.dt_s)
        return ActuatorCommand(frames.stamp_ns, steer, throttle, brake)

    def _wanted_offset(self, s_m: float) -> float:
        """Where the driver wants to be left of the centre line at ``s_m``: the edge offset plus the weave."""
        cfg = self.config
        return cfg.edge_offset_m + cfg.weave_amplitude_m * math.sin(2 * math.pi * s_m / cfg.weave_period_m)


class CommandsDriver:
    """Replays recorded commands by time since their first stamp (zero-order hold), then stops."""

    def __init__(self, commands: Sequence[ActuatorCommand]) -> None:
        if not commands:
            raise ConfigError("there are no commands to replay")
        self._stamps = np.array([c.stamp_ns for c in commands], np.int64)
        self._stamps -= self._stamps[0]
        self._commands = list(commands)
        self._t0: int | None = None

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        if self._t0 is None:
            self._t0 = frames.stamp_ns
        elapsed = frames.stamp_ns - self._t0
        i = int(np.searchsorted(self._stamps, elapsed, side="right")) - 1
        if elapsed > self._stamps[-1] + 10**9:  # a second past the last command: stop
            return ActuatorCommand.stop(frames.stamp_ns)
        c = self._commands[max(i, 0)]
        return ActuatorCommand(frames.stamp_ns, c.steer_rad, c.throttle, c.brake)

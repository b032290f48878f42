"""The stack's configuration: one section per component, one YAML file over the defaults.

Example ``stack.yaml``::

    stereo_vo:
      features: {detector: sift, max_features: 2000}
      stereo: {max_depth_m: 30}
    sim:
      effects: {noise_sigma: 4.0, vibration_m: 0.003}
      render: {time_of_day_h: 18.5}
    centerline_driver: {weave_amplitude_m: 0.2}
    drive:
      follow: {controller: pure_pursuit, bias: {gain_rad_per_m_s: 0.0}}
      localizer: {reloc: {gain: 0.5}}
    live: {sync_tolerance_ms: 10, health: {timeout_s: 0.5}}
    can: {interface: socketcan, channel: can0, send_rate_hz: 25, rdw: {sensor_timeout_s: 0.2}}
    limits: {max_steer_rad: 0.4, max_steer_rate_radps: 3.0, max_throttle: 0.6}   # the real kart
    watchdogs: {overrun_factor: 2.0, overrun_steps: 3}
    supervisor: {require_hold: true}
    gamepad: {hold_button: 5, estop_button: 1, max_steer_rad: 0.3}   # another pad: its axis and button numbers
    places: {spacing_m: 0.5, vlad: {words: 64, pca_dims: 128, features: {detector: sift}}}
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from kartpilot.actuation.can_bus import ActuatorLimits, CanConfig
from kartpilot.core.config import load_yaml_mapping, merge_config
from kartpilot.core.errors import ConfigError
from kartpilot.odometry.mono_vo import MonoVOConfig
from kartpilot.odometry.places import PlacesConfig
from kartpilot.odometry.stereo_vo import StereoVOConfig
from kartpilot.runtime.drive import WatchdogConfig
from kartpilot.runtime.lane_policy import LANE_PRESETS, LanePolicyConfig
from kartpilot.runtime.path_policy import DriveConfig
from kartpilot.runtime.supervisor import SupervisorConfig
from kartpilot.sensors.capture import LiveConfig
from kartpilot.sensors.gamepad import GamepadMapping
from kartpilot.sim.drivers import CenterlineDriverConfig
from kartpilot.sim.simulator import SimConfig
from kartpilot.sim.track import load_track_spec

__all__ = ["StackConfig", "load_stack_config", "sim_lane_preset"]


@dataclass(frozen=True)
class StackConfig:
    stereo_vo: StereoVOConfig = field(default_factory=StereoVOConfig)
    mono_vo: MonoVOConfig = field(default_factory=MonoVOConfig)
    places: PlacesConfig = field(default_factory=PlacesConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    centerline_driver: CenterlineDriverConfig = field(default_factory=CenterlineDriverConfig)
    lane_policy: LanePolicyConfig = field(default_factory=LanePolicyConfig)
    drive: DriveConfig = field(default_factory=DriveConfig)
    live: LiveConfig = field(default_factory=LiveConfig)
    can: CanConfig = field(default_factory=CanConfig)
    limits: ActuatorLimits = field(default_factory=ActuatorLimits)
    watchdogs: WatchdogConfig = field(default_factory=WatchdogConfig)
    supervisor: SupervisorConfig = field(default_factory=SupervisorConfig)
    gamepad: GamepadMapping = field(default_factory=GamepadMapping)


def sim_lane_preset(requested: str | None, track: str) -> str:
    """The lane preset of a simulated drive: the one asked for, else the track's own (``lane_preset`` in its
    file: the real kart's ``kart`` where the track is drawn as the venue looks)."""
    return requested or load_track_spec(track).lane_preset


def load_stack_config(path: str | Path | None, lane_preset: str | None = None) -> StackConfig:
    """Defaults, with the lane pipeline's preset for the kind of track (``LANE_PRESETS``: ``kart``, the
    default, ``dashcam`` or ``tape``) and then the YAML file at ``path`` merged over them when given."""
    base = StackConfig()
    if lane_preset is not None:
        if lane_preset not in LANE_PRESETS:
            raise ConfigError(f"unknown lane preset {lane_preset!r} ({', '.join(LANE_PRESETS)})")
        base = replace(base, lane_policy=LANE_PRESETS[lane_preset])
    return base if path is None else merge_config(base, load_yaml_mapping(path))

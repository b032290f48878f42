"""The kart's one description: chassis, steering, speed modes, the protocol its actuators speak, cameras.

The simulator, the actuators, the command limits and replay all read the kart from here, so the
steering range has one source. Two karts are built in: ``sdc-kart`` (the RDW Self Driving Challenge
electric go-kart; its ECUs speak the organiser's ``rdw`` protocol) and ``rc-kart`` (the thesis's
1:8 small-scale kart with its 14 cm stereo pair, 19 cm high; our own ``kartpilot`` protocol).

Body frame: x forward, y left, z up, origin on the ground under the middle of
the rear axle (the point pure pursuit steers). Cameras use OpenCV's frame
(x right, y down, z forward) and carry their pose on the body.

The steering calibration maps the stack's road-wheel angle (``steer_rad``, positive left) to the
value the steering ECU takes and to the counts its sensor reports; ``kartpilot calibrate steering``
measures it on the kart and writes it into the rig file, which then overrides the default here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import mount_pose
from kartpilot.core.types import LidarMount

GRAVITY_MPS2 = 9.81

__all__ = ["GRAVITY_MPS2", "PROTOCOLS", "VEHICLES", "SteeringCalibration", "VehicleParams", "camera_pose_on_body",
           "get_vehicle"]

PROTOCOLS = ("rdw", "kartpilot")


@dataclass(frozen=True)
class SteeringCalibration:
    """How a road-wheel angle becomes the steering ECU's value, and how its sensor's counts become an angle.

    Linear maps, as the kart's actuator and potentiometer are: ``value = value_offset + value_sign *
    steer_rad / rad_per_value`` and ``counts = count_offset + counts_per_value * value``.

    Attributes:
        value_sign: the sign of the ECU's value for a steer to the left (-1 on the RDW kart, whose
            positive value steers right).
        rad_per_value: road-wheel radians per unit of the ECU's value.
        value_offset: the value that holds the wheels straight (a trim).
        max_value: the ECU's accepted range, symmetric (1.25 on the RDW kart).
        counts_per_value, count_offset: the steering sensor's counts for a value (its slope may be negative).
    """

    value_sign: int = -1
    rad_per_value: float = 0.32
    value_offset: float = 0.0
    max_value: float = 1.25
    counts_per_value: float = 512.0
    count_offset: float = 0.0

    def __post_init__(self) -> None:
        if self.value_sign not in (-1, 1):
            raise ConfigError(f"steering.value_sign must be -1 or 1, got {self.value_sign}")
        for name in ("rad_per_value", "max_value"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"steering.{name} must be a positive number, got {value}")
        for name in ("value_offset", "counts_per_value", "count_offset"):
            if not math.isfinite(getattr(self, name)):
                raise ConfigError(f"steering.{name} must be finite, got {getattr(self, name)}")
        if self.counts_per_value == 0:
            raise ConfigError("steering.counts_per_value must not be 0")

    def _value_unclamped(self, steer_rad: float) -> float:
        return self.value_offset + self.value_sign * steer_rad / self.rad_per_value

    def value_of(self, steer_rad: float) -> float:
        """The ECU's value for a road-wheel angle (positive left), clamped to the accepted range."""
        return min(max(self._value_unclamped(steer_rad), -self.max_value), self.max_value)

    def steer_of_value(self, value: float) -> float:
        """The road-wheel angle (positive left) a value asks for."""
        return self.value_sign * (value - self.value_offset) * self.rad_per_value

    def counts_of(self, steer_rad: float) -> float:
        """The sensor's counts at a road-wheel angle (unclamped: the wheels may be off the ECU's range)."""
        return self.count_offset + self.counts_per_value * self._value_unclamped(steer_rad)

    def steer_of_counts(self, counts: float) -> float:
        """The road-wheel angle (positive left) the sensor's counts stand for."""
        return self.steer_of_value((counts - self.count_offset) / self.counts_per_value)

    @property
    def max_steer_rad(self) -> float:
        """The largest angle to either side the ECU's range allows around the trim."""
        return (self.max_value - abs(self.value_offset)) * self.rad_per_value


@dataclass(frozen=True)
class VehicleParams:
    """One kart. Lengths in metres, angles in radians, masses in kilograms.

    Attributes:
        wheelbase_m, cg_to_rear_m: axle spacing and the centre of gravity's distance from the rear axle.
        width_m: outside width over the tyres; ``front_overhang_m``/``rear_overhang_m`` give the footprint.
        tyre_stiffness_per_rad, friction: a tyre's lateral force per unit load and slip angle, and the
            friction coefficient at which it saturates.
        max_steer_rad, steer_rate_radps, steer_lag_s: the steering servo's range, speed and response.
        top_speed_mps: top speed on a full battery; it sags by ``battery_sag`` (fraction) when empty.
        battery_endurance_s: seconds at full throttle from full to empty.
        kinematic_below_mps, dynamic_above_mps: below the first, the kinematic single-track model;
            above the second, the dynamic one with tyre slip; blended in between.
        speed_modes_mps: the speed modes the kart offers (the SDC kart's 5/15/30/60 km/h).
        cameras: (name, camera) pairs; ``stereo_pair`` names the left and right camera when there is one.
        protocol: what its actuators speak on CAN: ``rdw`` (the RDW kart's ECUs) or ``kartpilot`` (our DBC).
        steering: the steering calibration (``rdw``); a rig file's ``steering`` section overrides it.
        lidar: the planar LiDAR's mount, where the kart has one (the 2026 SDC kart); a rig file's ``lidar``
            section overrides it.
    """

    name: str
    wheelbase_m: float
    cg_to_rear_m: float
    width_m: float
    front_overhang_m: float
    rear_overhang_m: float
    mass_kg: float
    yaw_inertia_kgm2: float
    tyre_stiffness_per_rad: float
    friction: float
    max_steer_rad: float
    steer_rate_radps: float
    steer_lag_s: float
    top_speed_mps: float
    max_accel_mps2: float
    max_brake_mps2: float
    rolling_decel_mps2: float
    battery_sag: float
    battery_endurance_s: float
    min_speed_mps: float
    kinematic_below_mps: float
    dynamic_above_mps: float
    speed_modes_mps: tuple[float, ...]
    cameras: tuple[tuple[str, PinholeCamera], ...]
    stereo_pair: tuple[str, str] | None = None
    protocol: Literal["rdw", "kartpilot"] = "kartpilot"
    steering: SteeringCalibration = field(default_factory=SteeringCalibration)
    lidar: LidarMount | None = None

    def __post_init__(self) -> None:
        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"vehicle {self.name!r}: protocol must be one of {', '.join(PROTOCOLS)}")
        positive = ("wheelbase_m", "width_m", "mass_kg", "yaw_inertia_kgm2", "tyre_stiffness_per_rad", "friction",
                    "max_steer_rad", "steer_rate_radps", "top_speed_mps", "max_accel_mps2", "max_brake_mps2",
                    "battery_endurance_s")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"vehicle {self.name!r}: {name} must be a positive number, got {value}")
        at_least_zero = ("cg_to_rear_m", "front_overhang_m", "rear_overhang_m", "steer_lag_s", "rolling_decel_mps2",
                         "battery_sag", "min_speed_mps", "kinematic_below_mps", "dynamic_above_mps")
        for name in at_least_zero:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"vehicle {self.name!r}: {name} must be zero or more, got {value}")
        if not self.cg_to_rear_m <= self.wheelbase_m:
            raise ConfigError(f"vehicle {self.name!r}: its centre of gravity ({self.cg_to_rear_m} m from the rear "
                              f"axle) lies beyond the front axle ({self.wheelbase_m} m)")
        if not self.max_steer_rad < math.pi / 2:
            raise ConfigError(f"vehicle {self.name!r}: max_steer_rad {self.max_steer_rad} must be under 90 degrees")
        if not (self.battery_sag < 1 and self.kinematic_below_mps <= self.dynamic_above_mps):
            raise ConfigError(f"vehicle {self.name!r}: battery_sag under 1, and kinematic_below_mps at most "
                              "dynamic_above_mps")
        if self.protocol == "rdw" and self.steering.max_steer_rad < self.max_steer_rad - 1e-9:
            reach = self.steering.max_steer_rad
            raise ConfigError(f"vehicle {self.name!r}: its steering calibration reaches {reach:.3f} rad, less than its "
                              f"{self.max_steer_rad:.3f} rad range")

    @property
    def cg_to_front_m(self) -> float:
        return self.wheelbase_m - self.cg_to_rear_m

    def dynamic_share(self, speed_mps: float) -> float:
        """How much of the dynamic single-track model (tyres that slip) the kart's motion follows at this speed:
        none below ``kinematic_below_mps``, all above ``dynamic_above_mps``, linearly between."""
        span = self.dynamic_above_mps - self.kinematic_below_mps
        return min(max((speed_mps - self.kinematic_below_mps) / max(span, 1e-9), 0.0), 1.0)

    def rear_slip_rad(self, speed_mps: float, yaw_rate_radps: float) -> float:
        """The angle between the rear axle's velocity and the heading in a steady turn (negative: outward, for a
        left turn's positive yaw rate). The rear tyres carry the rear axle's share of the lateral acceleration
        ``v * yaw_rate``, and that share is also theirs of the weight, so with linear tyres the slip angle is the
        lateral acceleration over ``g * tyre_stiffness_per_rad`` whatever the mass's distribution (the
        simulator's single-track model in a steady turn). A kart's rear axle does not move along its heading in
        a bend: 0.3 degrees at 4 m/s in sdc-assen's bends, half the turn of a 10 Hz frame."""
        lateral = speed_mps * yaw_rate_radps
        return -self.dynamic_share(speed_mps) * lateral / (GRAVITY_MPS2 * self.tyre_stiffness_per_rad)

    @property
    def camera_map(self) -> dict[str, PinholeCamera]:
        return dict(self.cameras)

    def camera(self, name: str) -> PinholeCamera:
        cams = self.camera_map
        if name not in cams:
            raise ConfigError(f"vehicle {self.name!r} has no camera {name!r} (it has {', '.join(cams)})")
        return cams[name]

    def stereo_rig(self) -> StereoRig:
        """The rectified stereo rig (the simulated pair is ideal: parallel, same intrinsics)."""
        if self.stereo_pair is None:
            raise ConfigError(f"vehicle {self.name!r} has no stereo pair")
        left, right = (self.camera(n) for n in self.stereo_pair)
        baseline = float(np.linalg.norm(left.pose_body_cam_array[:3, 3] - right.pose_body_cam_array[:3, 3]))
        return StereoRig(left, baseline)

    def tyre_points_body(self) -> np.ndarray:
        """Outer edges of the four tyres' contact patches in the body frame (4x2)."""
        half = self.width_m / 2
        return np.array([[self.wheelbase_m, half], [self.wheelbase_m, -half], [0.0, half], [0.0, -half]])

    def footprint_body(self) -> tuple[float, float, float, float]:
        """The footprint rectangle (x_min, x_max, y_min, y_max) in the body frame."""
        half = self.width_m / 2
        return -self.rear_overhang_m, self.wheelbase_m + self.front_overhang_m, -half, half


def camera_pose_on_body(x_m: float, y_m: float, z_m: float, yaw_deg: float = 0.0,
                        pitch_down_deg: float = 0.0) -> tuple[tuple[float, ...], ...]:
    """The 4x4 pose of an OpenCV camera on the body, looking forward then yawed left and pitched down."""
    pose = mount_pose(x_m, y_m, z_m, yaw_deg, pitch_down_deg)
    return tuple(tuple(float(v) for v in row) for row in pose)


def _camera(f_px: float, w: int, h: int, pose: tuple[tuple[float, ...], ...]) -> PinholeCamera:
    return PinholeCamera(f_px, f_px, (w - 1) / 2, (h - 1) / 2, w, h, (), pose)


RC_KART = VehicleParams(
    name="rc-kart",
    wheelbase_m=0.35, cg_to_rear_m=0.16, width_m=0.40, front_overhang_m=0.10, rear_overhang_m=0.08,
    mass_kg=4.5, yaw_inertia_kgm2=0.16, tyre_stiffness_per_rad=5.0, friction=0.9,
    max_steer_rad=0.45, steer_rate_radps=4.0, steer_lag_s=0.05,
    top_speed_mps=6.4, max_accel_mps2=3.0, max_brake_mps2=5.0, rolling_decel_mps2=0.3,
    battery_sag=0.15, battery_endurance_s=1200.0, min_speed_mps=0.62,
    kinematic_below_mps=1.0, dynamic_above_mps=2.0, speed_modes_mps=(0.62, 1.0, 2.0, 4.0),
    cameras=(
        ("left", _camera(743.0, 960, 540, camera_pose_on_body(0.40, 0.07, 0.19))),
        ("right", _camera(743.0, 960, 540, camera_pose_on_body(0.40, -0.07, 0.19))),
        ("center", _camera(743.0, 960, 540, camera_pose_on_body(0.40, 0.0, 0.19))),
    ),
    stereo_pair=("left", "right"),
)

SDC_KART = VehicleParams(
    name="sdc-kart",
    wheelbase_m=1.05, cg_to_rear_m=0.45, width_m=1.20, front_overhang_m=0.45, rear_overhang_m=0.30,
    mass_kg=170.0, yaw_inertia_kgm2=60.0, tyre_stiffness_per_rad=8.0, friction=1.0,
    max_steer_rad=0.40, steer_rate_radps=1.2, steer_lag_s=0.10,
    top_speed_mps=16.7, max_accel_mps2=2.5, max_brake_mps2=6.0, rolling_decel_mps2=0.25,
    battery_sag=0.10, battery_endurance_s=2400.0, min_speed_mps=1.0,
    kinematic_below_mps=2.0, dynamic_above_mps=4.0, speed_modes_mps=(5 / 3.6, 15 / 3.6, 30 / 3.6, 60 / 3.6),
    cameras=(
        # the real kart's centre camera: 848x480 MJPG, 67 degrees across (the Hanze kart's 1920x1080 cameras'
        # fx of 1447 px scaled to 848 px), 0.56 m up and pitched 6.8 degrees down (its ground calibration,
        # docs/real-kart.md)
        ("center", _camera(640.0, 848, 480, camera_pose_on_body(1.20, 0.0, 0.56, pitch_down_deg=6.8))),
        ("left", _camera(400.0, 640, 480, camera_pose_on_body(0.90, 0.55, 0.60, yaw_deg=70.0, pitch_down_deg=40.0))),
        ("right", _camera(400.0, 640, 480,
                          camera_pose_on_body(0.90, -0.55, 0.60, yaw_deg=-70.0, pitch_down_deg=40.0))),
    ),
    protocol="rdw",
    # until calibrated on the kart: the ECU's full range (1.25) reaches the steering's 0.40 rad, and the
    # sensor's valid range (+-800 counts) spans the ECU's range with a margin
    steering=SteeringCalibration(value_sign=-1, rad_per_value=0.32, counts_per_value=-600.0),
)

SDC_KART_STEEP = replace(
    SDC_KART, name="sdc-kart-steep",
    # the same kart with its centre camera mounted as the thesis's was: 0.60 m up and pitched 12 degrees down, a
    # 640x480 camera of the same field of view. It sees the ground from 0.75 m ahead (the real mount: 1.1 m), which
    # the one-camera pipeline's registration on the road's top view needs (docs/mono-vo.md)
    cameras=(("center", _camera(480.0, 640, 480, camera_pose_on_body(1.20, 0.0, 0.60, pitch_down_deg=12.0))),
             *SDC_KART.cameras[1:]),
)

SDC_KART_2026 = replace(
    SDC_KART, name="sdc-kart-2026",
    # the 2026 closed-category kart (../shared/docs/sdc-event.md): the same kart and cameras, with a planar 360-degree
    # LiDAR on its nose, 5 cm behind the front of its footprint (1.50 m ahead of the rear axle), its scan plane 0.30 m
    # above the road: under a car's bumper line, above the kerbs, at a person's knees, across a barrier block
    lidar=LidarMount(x_m=1.45, y_m=0.0, z_m=0.30),
)

VEHICLES: dict[str, VehicleParams] = {v.name: v for v in (RC_KART, SDC_KART, SDC_KART_STEEP, SDC_KART_2026)}


def get_vehicle(name: str) -> VehicleParams:
    if name not in VEHICLES:
        raise ConfigError(f"unknown vehicle {name!r}; known: {', '.join(sorted(VEHICLES))}")
    return VEHICLES[name]

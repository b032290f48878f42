"""The two karts as typed data: chassis, actuators and cameras.

Body frame: x forward, y left, z up, origin on the ground under the middle of
the rear axle (the point pure pursuit steers). Cameras use OpenCV's frame
(x right, y down, z forward) and carry their pose on the body.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kartpilot.calibration.rig import mount_pose
from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.errors import ConfigError

__all__ = ["VEHICLES", "VehicleParams", "camera_pose_on_body", "get_vehicle"]


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

    @property
    def cg_to_front_m(self) -> float:
        return self.wheelbase_m - self.cg_to_rear_m

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
        ("center", _camera(480.0, 640, 480, camera_pose_on_body(1.20, 0.0, 0.60, pitch_down_deg=12.0))),
        ("left", _camera(400.0, 640, 480, camera_pose_on_body(0.90, 0.55, 0.60, yaw_deg=70.0, pitch_down_deg=40.0))),
        ("right", _camera(400.0, 640, 480,
                          camera_pose_on_body(0.90, -0.55, 0.60, yaw_deg=-70.0, pitch_down_deg=40.0))),
    ),
)

VEHICLES: dict[str, VehicleParams] = {v.name: v for v in (RC_KART, SDC_KART)}


def get_vehicle(name: str) -> VehicleParams:
    if name not in VEHICLES:
        raise ConfigError(f"unknown vehicle {name!r}; known: {', '.join(sorted(VEHICLES))}")
    return VEHICLES[name]

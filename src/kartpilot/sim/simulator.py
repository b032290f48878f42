"""The closed-loop simulator: a frame source and a command sink like the real kart.

Each :meth:`Simulator.read` renders the kart's cameras at the current state;
each :meth:`Simulator.send` applies a command and advances the physics by one
camera period, then lets the referee judge. Time is simulated, so a run is the
same however fast the machine is, and everything random (sensor noise,
vibration, dropped frames) comes from the run's seed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from kartpilot.calibration.lens import lens_distortion
from kartpilot.core.camera import DISTORTION_COUNTS, PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.geometry import Array, arc_2d, compose_2d
from kartpilot.core.trajectory import Trajectory
from kartpilot.core.types import ActuatorCommand, FrameSet, Image, LaserScan, LidarMount
from kartpilot.core.vehicle import GRAVITY_MPS2, VehicleParams, get_vehicle
from kartpilot.perception.objects import Detection
from kartpilot.sim.camera_effects import (
    add_shot_noise,
    apply_gain,
    auto_exposure_gain,
    jpeg_roundtrip,
    mean_level,
    moving_exposure,
    shift_rows,
)
from kartpilot.sim.dynamics import Disturbances, VehicleState, step_vehicle
from kartpilot.sim.lidar import LidarConfig, simulate_scan
from kartpilot.sim.referee import Referee, RefereeConfig, RunResult
from kartpilot.sim.render import RenderConfig, Renderer
from kartpilot.sim.track import Prop, Track, load_track, project_onto

__all__ = ["CameraEffectsConfig", "DisturbanceConfig", "SimConfig", "Simulator", "body_pose", "camera_poses_on_route",
           "mount_off", "perfect_camera", "real_camera"]


@dataclass(frozen=True)
class CameraEffectsConfig:
    """What a real camera adds to a perfect rendering. The defaults are the kart presets' real cameras
    (:func:`real_camera`); :func:`perfect_camera` is the renderer's pinhole with its read noise alone.

    Attributes:
        exposure_gain: brightness factor after rendering (above 1 over-exposes, below 1 under-exposes).
        noise_sigma: standard deviation of the sensor noise in grey levels (0 = none).
        motion_blur_subframes: renderings averaged over the exposure (1 = no motion blur).
        exposure_time_s: the exposure that motion blur spans.
        drop_probability: chance that a camera delivers no frame at a step.
        vibration_m, vibration_pitch_deg, vibration_hz: vertical shake of the cameras (amplitudes reached
            at 1 m/s and above; the small kart shook).
        lens_distortion: OpenCV distortion coefficients (k1, k2, p1, p2[, k3]) every camera's lens has: the
            cameras' calibration carries them and the images are bent by them (empty: pinhole cameras).
        light_change_at_s, light_change_gain: from this time on (0: never) the light changes by this factor,
            at once, as when the kart drives out of a building's shadow (the thesis's runs met such changes).
        shot_noise: a real sensor's noise grows with the light it counts (photon shot noise): its variance is
            ``noise_sigma**2 + shot_noise * level`` in grey levels (0: the same noise in the dark and the sun).
        jpeg_quality: each frame compressed and decompressed as JPEG at this quality, as a USB camera's MJPG
            stream delivers it (the SDC kart's cameras: MJPG at 848x480); 0: none.
        rolling_shutter_s: the time the sensor takes to read its rows, top to bottom (0: a global shutter). The
            middle row is read at the frame's stamp; a turning kart's verticals lean, the near road stretches.
        exposure_blur_samples: motion blur over ``exposure_time_s`` from the one rendering, warped to this many
            instants of the exposure and averaged (0: none; cheaper than ``motion_blur_subframes``, which renders
            each instant, and exact on the road: see :mod:`kartpilot.sim.camera_effects`).
        auto_exposure_s: the auto-exposure's time constant: the gain follows the light the camera meters toward
            ``auto_exposure_level`` with this lag, so the same road is not the same grey in every frame and a step
            in the light takes a few frames to settle (0: a fixed exposure).
        auto_exposure_level: the mean grey level the auto-exposure aims for.
        rectification_residual_px: the vertical offset a calibrated stereo pair keeps after rectification: the
            first camera's image moves down by half of it, the others' up by half, each resampled as
            rectification resamples (0: perfectly rectified and never resampled).
        mount_pitch_deg, mount_roll_deg, mount_height_m: every camera sits this far off from where the rig says
            (knocked on the way to the start): pitched down (+), rolled with its right side down (+), higher (+).
            The images come from where the cameras are; the stack, the recording's calibration and the
            referee keep the rig's mount; the ground truth is where they are.
    """

    exposure_gain: float = 1.0
    noise_sigma: float = 2.0
    motion_blur_subframes: int = 1
    exposure_time_s: float = 0.008
    drop_probability: float = 0.0
    vibration_m: float = 0.0
    vibration_pitch_deg: float = 0.0
    vibration_hz: float = 11.0
    lens_distortion: tuple[float, ...] = ()
    light_change_at_s: float = 0.0
    light_change_gain: float = 1.0
    shot_noise: float = 0.3
    jpeg_quality: int = 85
    rolling_shutter_s: float = 0.02
    exposure_blur_samples: int = 3
    auto_exposure_s: float = 0.3
    auto_exposure_level: float = 110.0
    rectification_residual_px: float = 0.2
    mount_pitch_deg: float = 0.0
    mount_roll_deg: float = 0.0
    mount_height_m: float = 0.0

    def __post_init__(self) -> None:
        for key, most in (("mount_pitch_deg", 10.0), ("mount_roll_deg", 10.0), ("mount_height_m", 0.2)):
            value = getattr(self, key)
            if not (math.isfinite(value) and abs(value) <= most):
                raise ConfigError(f"sim.effects.{key} must be within +-{most:g}, got {value}")
        for key in ("rolling_shutter_s", "auto_exposure_s", "exposure_time_s"):
            value = getattr(self, key)
            if not (math.isfinite(value) and 0 <= value <= 1):
                raise ConfigError(f"sim.effects.{key} must be 0 to 1 s, got {value}")
        if not 0 <= self.exposure_blur_samples <= 16 or self.exposure_blur_samples == 1:
            raise ConfigError(f"sim.effects.exposure_blur_samples must be 0 (none) or 2 to 16, "
                              f"got {self.exposure_blur_samples}")
        if not (math.isfinite(self.auto_exposure_level) and 10 <= self.auto_exposure_level <= 245):
            raise ConfigError(f"sim.effects.auto_exposure_level must be 10 to 245, got {self.auto_exposure_level}")
        if not (math.isfinite(self.rectification_residual_px) and abs(self.rectification_residual_px) <= 5):
            raise ConfigError("sim.effects.rectification_residual_px must be within +-5 px, got "
                              f"{self.rectification_residual_px}")
        if not (math.isfinite(self.shot_noise) and self.shot_noise >= 0):
            raise ConfigError(f"sim.effects.shot_noise must be a finite number >= 0, got {self.shot_noise}")
        if not 0 <= self.jpeg_quality <= 100:
            raise ConfigError(f"sim.effects.jpeg_quality must be 0 (none) or 1 to 100, got {self.jpeg_quality}")
        if not (self.light_change_at_s >= 0 and self.light_change_gain > 0 and self.exposure_gain > 0):
            raise ConfigError("sim.effects.light_change_at_s must not be negative; the gains must be positive")
        if len(self.lens_distortion) not in DISTORTION_COUNTS or not all(map(math.isfinite, self.lens_distortion)):
            raise ConfigError("sim.effects.lens_distortion needs 4, 5, 8, 12 or 14 finite OpenCV coefficients "
                              f"(or none), got {list(self.lens_distortion)}")


@dataclass(frozen=True)
class DisturbanceConfig:
    """Attributes:
        steer_bias_rad: constant offset of the steering (positive pulls left).
        cross_slope: apply the track's cross-slope as a lateral pull.
    """

    steer_bias_rad: float = 0.0
    cross_slope: bool = True


@dataclass(frozen=True)
class SimConfig:
    """One simulated run. ``cameras`` empty means every camera of the vehicle; ``speed_mode_mps`` caps the
    kart's top speed like the SDC kart's speed modes (0: the vehicle's own top speed)."""

    track: str = "utrack"
    vehicle: str = "rc-kart"
    seed: int = 1
    camera_rate_hz: float = 30.0
    cameras: tuple[str, ...] = ()
    render_images: bool = True
    show_cones: bool = True
    max_time_s: float = 0.0
    speed_mode_mps: float = 0.0
    render: RenderConfig = field(default_factory=RenderConfig)
    effects: CameraEffectsConfig = field(default_factory=CameraEffectsConfig)
    disturbances: DisturbanceConfig = field(default_factory=DisturbanceConfig)
    referee: RefereeConfig = field(default_factory=RefereeConfig)
    props: tuple[Prop, ...] = ()
    """A scenario's objects, added to the track's own (``track.props``)."""
    lidar: LidarConfig = field(default_factory=LidarConfig)
    """The planar LiDAR's sensor, scanned where the vehicle has one (its mount: ``VehicleParams.lidar``); its
    sweeps ride on the frame sets (``FrameSet.scans["lidar"]``)."""


def real_camera(vehicle: str) -> CameraEffectsConfig:
    """What the named vehicle's real cameras add to a rendering, as far as we know them: the effects a simulated
    result must survive before it says anything about the kart (the default of every kart preset).

    Measured: the stereo pair's rectification residual (0.21 px on KITTI 06, 0.16 px on EuRoC MH_01, by
    ``benchmarks/honest_camera.py``). Typical of the cameras' kind, not measured on them: a USB camera's MJPG
    quality, a rolling shutter read over two thirds of a 30 Hz frame, 8 ms exposures outdoors, an auto-exposure
    that settles in about a second, photon shot noise."""
    get_vehicle(vehicle)  # an unknown name is the usual error
    return CameraEffectsConfig()


def perfect_camera() -> CameraEffectsConfig:
    """The renderer's perfect pinhole with only its read noise (2 grey levels): every row at one instant, no blur,
    a fixed exposure, no compression, a perfectly rectified pair (``--perfect-camera``; what the simulator's
    figures were measured through before the real camera became the default)."""
    return CameraEffectsConfig(exposure_time_s=0.01, shot_noise=0.0, jpeg_quality=0, rolling_shutter_s=0.0,
                               exposure_blur_samples=0, auto_exposure_s=0.0, rectification_residual_px=0.0)


def mount_off(pose_body_cam: Array, effects: CameraEffectsConfig) -> Array:
    """Where a camera the rig puts at ``pose_body_cam`` is, off by ``effects``' mount pitch, roll (about the body's
    axes, at the camera) and height."""
    pitch, roll = math.radians(effects.mount_pitch_deg), math.radians(effects.mount_roll_deg)
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    about_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # + pitch: the optical axis down
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])  # + roll: the right side down
    pose = np.array(pose_body_cam, dtype=float)
    pose[:3, :3] = about_y @ about_x @ pose[:3, :3]
    pose[2, 3] += effects.mount_height_m
    return pose


def body_pose(state: VehicleState) -> Array:
    """The 4x4 world pose of the body frame (rear axle centre on the ground)."""
    pose = np.eye(4)
    c, s = math.cos(state.yaw_rad), math.sin(state.yaw_rad)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:2, 3] = state.x_m, state.y_m
    return pose


def camera_poses_on_route(track: Track, cameras: Mapping[str, PinholeCamera], sample: int) -> dict[str, Array]:
    """Each camera's 4x4 world pose with the kart's rear axle on the route's centre line ``sample`` route samples
    after the start (wrapping round the lap), heading along it: a rendering's poses without a drive."""
    route = track.route
    i = (track.start_index + sample) % len(route.s_m)
    body = body_pose(VehicleState(x_m=float(route.xy_m[i, 0]), y_m=float(route.xy_m[i, 1]),
                                  yaw_rad=float(route.heading_rad[i])))
    return {name: body @ cam.pose_body_cam_array for name, cam in cameras.items()}


def check_drivable(track: Track, vehicle: VehicleParams) -> None:
    """Refuse a track with a bend tighter than the kart's tightest turn (its rear axle's radius at full lock,
    ``wheelbase / tan(max_steer)``): no driver could follow it, and the drive would end as a failure of the stack
    rather than of the file."""
    tightest_m = vehicle.wheelbase_m / math.tan(vehicle.max_steer_rad)
    curvature = np.abs(track.route.curvature_1pm)  # the route (a split's branch is the wrong way anyway)
    k = int(np.argmax(curvature))
    if curvature[k] * tightest_m > 1.0:
        raise ConfigError(f"track {track.name!r}: a bend of {1.0 / curvature[k]:.2f} m radius at "
                          f"{track.route.s_m[k]:.0f} m along the route is tighter than the {vehicle.name}'s tightest "
                          f"turn ({tightest_m:.2f} m at full lock)")


class Simulator:
    """A track, a kart, its cameras and the referee, stepped at the camera rate."""

    def __init__(self, config: SimConfig | None = None, track: Track | None = None,
                 vehicle: VehicleParams | None = None) -> None:
        self.config = config = config or SimConfig()
        if config.camera_rate_hz <= 0:
            raise ConfigError("sim.camera_rate_hz must be positive")
        self.track = track or load_track(config.track)
        if config.props:
            self.track = replace(self.track, spec=replace(self.track.spec, props=self.track.spec.props + config.props))
        self.vehicle = vehicle or get_vehicle(config.vehicle)
        check_drivable(self.track, self.vehicle)
        if config.speed_mode_mps > 0:
            self.vehicle = replace(self.vehicle, top_speed_mps=min(self.vehicle.top_speed_mps, config.speed_mode_mps))
        names = config.cameras or tuple(name for name, _ in self.vehicle.cameras)
        lens = tuple(config.effects.lens_distortion)
        self.cameras = {name: replace(self.vehicle.camera(name), distortion=lens) for name in names}
        self._mounts = {name: mount_off(cam.pose_body_cam_array, config.effects) for name, cam in self.cameras.items()}
        self._lenses = {name: remap for name, cam in self.cameras.items()
                        if (remap := lens_distortion(cam)) is not None} if config.render_images else {}
        self.dt_s = 1.0 / config.camera_rate_hz
        x, y, yaw = self.track.start_pose()
        self.state = VehicleState(x_m=x, y_m=y, yaw_rad=yaw)
        self.step_index = 0
        self.referee = Referee(self.track, self.vehicle, config.referee, cones=config.show_cones)
        self._rng = np.random.default_rng(config.seed)
        self._vibration_phase = self._rng.uniform(0, 2 * np.pi, 2)
        # the read noise alone from a bank of its own; with shot noise, both from one unit normal draw
        self._noise_bank = self._make_noise_bank() if (config.effects.noise_sigma > 0 and not config.effects.shot_noise
                                                       and config.render_images) else []
        self._unit_bank = self._make_unit_bank() if config.effects.shot_noise > 0 and config.render_images else []
        self._exposure_gains: dict[str, float] = {}  # each camera's auto-exposure, from the frames before
        self._renderer: Renderer | None = None
        if config.render_images:
            pinholes = {name: replace(cam, distortion=()) for name, cam in self.cameras.items()}
            self._renderer = Renderer(self.track, pinholes, config.render, show_cones=config.show_cones)
        self.camera_poses: dict[str, list[Array]] = {name: [] for name in self.cameras}
        self.stamps_ns: list[int] = []
        self.dropped_frames = 0
        self.last_command = ActuatorCommand.stop(0)
        self._lidar_rng = np.random.default_rng([config.seed, config.lidar.seed])
        self._next_scan_s = 0.0
        self.scans = 0
        max_time = config.max_time_s or self._default_time_limit()
        self._max_steps = math.ceil(max_time / self.dt_s)

    # --- interfaces ------------------------------------------------------------------------

    @property
    def time_ns(self) -> int:
        return round(self.step_index * self.dt_s * 1e9)

    @property
    def time_s(self) -> float:
        return self.step_index * self.dt_s

    @property
    def done(self) -> bool:
        return self.referee.done or self.step_index >= self._max_steps

    def read(self) -> FrameSet | None:
        """Frame source: the cameras' images now (a dropped frame leaves its camera out); None when done."""
        if self.done:
            return None
        poses = {name: self.camera_pose(name) for name in self.cameras}
        self.stamps_ns.append(self.time_ns)
        for name, pose in poses.items():
            self.camera_poses[name].append(pose)
        images: dict[str, Image] = {}
        if self._renderer is not None:
            images = self._render(poses)
            effects = self.config.effects
            for name in list(images):
                if effects.drop_probability > 0 and self._rng.random() < effects.drop_probability:
                    del images[name]
                    self.dropped_frames += 1
        return FrameSet(self.step_index, self.time_ns, images, scans=self._scans())

    @property
    def lidar_mounts(self) -> dict[str, LidarMount]:
        """The vehicle's LiDARs by the name their sweeps ride under (``lidar``; none where it has none)."""
        return {"lidar": self.vehicle.lidar} if self.vehicle.lidar is not None else {}

    def _scans(self) -> dict[str, LaserScan]:
        """The LiDAR's sweep that began since the set before (none where no sweep began: the sensor keeps its own
        rate), taken from where the kart was when it began: the body's pose now, moved back along its arc."""
        mounts = self.lidar_mounts
        if not mounts or self.time_s + 1e-9 < self._next_scan_s:
            return {}
        start_s = self._next_scan_s
        while self._next_scan_s <= self.time_s + 1e-9:
            self._next_scan_s += 1.0 / self.config.lidar.rate_hz
        state = self.state
        back = arc_2d(state.vx_mps, state.yaw_rate_radps, -(self.time_s - start_s))
        body = compose_2d((state.x_m, state.y_m, state.yaw_rad), back)
        self.scans += 1
        return {name: simulate_scan(self.track, body, state.vx_mps, state.yaw_rate_radps, start_s, self.config.lidar,
                                    mount, self._lidar_rng) for name, mount in mounts.items()}

    def send(self, command: ActuatorCommand) -> None:
        """Command sink: apply ``command`` for one camera period, then let the referee judge."""
        self.last_command = command
        self.state = step_vehicle(self.vehicle, self.state, command, self.dt_s, self._disturbances())
        self.step_index += 1
        self.referee.update(self.time_s, self.state)

    def result(self, wall_time_s: float) -> RunResult:
        return self.referee.result(wall_time_s)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- ground truth -------------------------------------------------------------------------

    def camera_pose(self, name: str, state: VehicleState | None = None) -> Array:
        """World pose of a camera, including the vibration of its mount."""
        state = state or self.state
        return body_pose(state) @ self._vibration(state) @ self._mounts[name]

    def object_truth(self, camera: str) -> list[Detection]:
        """The scenario's objects as ``camera`` sees them now, exactly: each prop (a light with its phase, a sign
        with its value, a person, the car), stop line, zebra and barrier block in front of the camera and in its
        image, with its box (its 3D box's corners projected, clipped to the image), its distance ahead and to
        the left of the kart's body frame on the ground (a car's and a barrier's to the nearest point of their
        footprint, a stop line's and a zebra's to their near edge, where the kart stops), and its state."""
        cam = self.cameras[camera]
        world_cam = self.camera_pose(camera)
        cam_world = np.linalg.inv(world_cam)
        body_world = np.linalg.inv(body_pose(self.state))
        track, t = self.track, self.time_s
        items: list[tuple[str, str, Array, Array]] = []  # label, state, corners (world), foot (world)
        for prop in track.spec.props:
            corners = track.prop_corners(prop, t)
            foot = corners[:4, :2].mean(axis=0)
            if prop.kind == "traffic_light":
                corners = corners.copy()
                corners[:4, 2] = 1.5  # the head, not the pole
            elif prop.kind == "speed_sign":
                corners = corners.copy()
                corners[:4, 2] = corners[4, 2] - 0.6  # the disc
            state = prop.light_at(t) if prop.kind == "traffic_light" else (
                str(prop.value_kmh) if prop.kind == "speed_sign" else "")
            items.append((prop.kind, state, corners, foot))
        for number, mark in enumerate(track.spec.road_marks):
            polygons = np.vstack([p for p, k in zip(track.road_marks, track.road_mark_of, strict=True) if k == number])
            paint = "crosswalk" if mark.kind == "zebra" else str(mark.kind)  # the detectors' class for a zebra
            items.append((paint, "", np.column_stack([polygons, np.zeros(len(polygons))]), polygons.mean(axis=0)))
        for block, footprint in zip(track.spec.barrier_blocks, track.barrier_blocks, strict=True):
            corners = np.vstack([np.column_stack([footprint, np.zeros(4)]),
                                 np.column_stack([footprint, np.full(4, block.height_m)])])
            items.append(("barrier", "", corners, footprint.mean(axis=0)))
        out = []
        for label, state, corners, foot in items:
            in_cam = corners @ cam_world[:3, :3].T + cam_world[:3, 3]
            if np.any(in_cam[:, 2] <= 0.2):
                continue
            px = cam.project(in_cam)
            left, top = max(float(px[:, 0].min()), 0.0), max(float(px[:, 1].min()), 0.0)
            right = min(float(px[:, 0].max()), cam.width_px - 1.0)
            bottom = min(float(px[:, 1].max()), cam.height_px - 1.0)
            if right <= left or bottom <= top:
                continue
            body = body_world[:3, :3] @ np.r_[foot, 0.0] + body_world[:3, 3]
            if label in ("car", "barrier", "stop_line", "crosswalk"):  # the face or edge the kart meets, not the middle
                base = corners[:4] if label in ("car", "barrier") else corners  # a mark's all lie on the ground
                body[0] = float(np.min(base @ body_world[:3, :3].T[:, 0] + body_world[0, 3]))
            out.append(Detection(label, (left, top, right, bottom), 1.0, state, distance_m=float(body[0]),
                                 lateral_m=float(body[1]), source="truth"))
        return out

    def ground_truth(self, camera: str) -> Trajectory:
        """The poses of ``camera`` at every frame read so far."""
        if not self.stamps_ns:
            raise ConfigError("no frames were read, so there is no ground truth yet")
        return Trajectory(np.asarray(self.stamps_ns, float) * 1e-9, np.asarray(self.camera_poses[camera]))

    # --- internals ------------------------------------------------------------------------------

    def _default_time_limit(self) -> float:
        length = self.track.route.length_m * self.config.referee.laps if self.track.closed else self.track.finish_s_m
        return 60.0 + 3.0 * length / self.vehicle.min_speed_mps

    def _disturbances(self) -> Disturbances:
        lateral = 0.0
        slope = math.radians(self.track.spec.cross_slope_deg)
        if self.config.disturbances.cross_slope and slope:
            p = project_onto(self.track.route, np.array([self.state.x_m, self.state.y_m]), self.referee.route_index)
            lateral = GRAVITY_MPS2 * math.sin(slope) * math.cos(self.state.yaw_rad - p.heading_rad)
        return Disturbances(self.config.disturbances.steer_bias_rad, lateral)

    def _vibration(self, state: VehicleState) -> Array:
        effects = self.config.effects
        out = np.eye(4)
        if effects.vibration_m <= 0 and effects.vibration_pitch_deg <= 0:
            return out
        scale = min(1.0, state.vx_mps / 1.0)
        w = 2 * math.pi * effects.vibration_hz * self.time_s
        dz = effects.vibration_m * scale * math.sin(w + self._vibration_phase[0])
        pitch = math.radians(effects.vibration_pitch_deg) * scale * math.sin(1.37 * w + self._vibration_phase[1])
        c, s = math.cos(pitch), math.sin(pitch)
        out[:3, :3] = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        out[2, 3] = dz
        return out

    def _render(self, poses: dict[str, Array]) -> dict[str, Image]:
        assert self._renderer is not None
        effects = self.config.effects
        n = max(1, effects.motion_blur_subframes)
        self._renderer.set_time(self.time_s)
        if n == 1:
            images = self._renderer.render(poses)
        else:
            sums: dict[str, np.ndarray] = {}
            for k in range(n):
                back = effects.exposure_time_s * k / (n - 1)
                past = replace(self.state, x_m=self.state.x_m - back * self.state.vx_mps * math.cos(self.state.yaw_rad),
                               y_m=self.state.y_m - back * self.state.vx_mps * math.sin(self.state.yaw_rad),
                               yaw_rad=self.state.yaw_rad - back * self.state.yaw_rate_radps)
                sub = self._renderer.render({name: self.camera_pose(name, past) for name in poses})
                for name, image in sub.items():
                    sums[name] = sums.get(name, 0) + image.astype(np.float32)
            images = {name: (total / n).astype(np.uint8) for name, total in sums.items()}
        if effects.rolling_shutter_s > 0 or effects.exposure_blur_samples:
            blur_s = effects.exposure_time_s if effects.exposure_blur_samples else 0.0
            images = {name: moving_exposure(image, self.cameras[name], self.state.vx_mps, self.state.yaw_rate_radps,
                                            effects.rolling_shutter_s, blur_s, effects.exposure_blur_samples)
                      for name, image in images.items()}
        bent = {name: self._lenses[name](image) if name in self._lenses else image for name, image in images.items()}
        exposed = {name: self._expose(name, image) for name, image in bent.items()}
        residual = effects.rectification_residual_px
        if residual:
            first = next(iter(self.cameras))
            exposed = {name: shift_rows(image, residual / 2 if name == first else -residual / 2)
                       for name, image in exposed.items()}
        return exposed

    def _expose(self, name: str, image: Image) -> Image:
        effects = self.config.effects
        out = image
        gain = effects.exposure_gain
        if 0 < effects.light_change_at_s <= self.time_s:
            gain *= effects.light_change_gain
        if effects.auto_exposure_s > 0:
            # the camera meters this frame and sets the next one's gain: a frame is exposed with what came before
            level = mean_level(image) * gain
            settled = self._exposure_gains.get(name)
            current = settled if settled is not None else auto_exposure_gain(1.0, level, effects.auto_exposure_level,
                                                                              self.dt_s, 0.0)
            self._exposure_gains[name] = auto_exposure_gain(current, level, effects.auto_exposure_level, self.dt_s,
                                                            effects.auto_exposure_s)
            gain *= current
        if gain != 1.0:
            out = apply_gain(out, gain)
        if self._noise_bank:
            bank = self._noise_bank[int(self._rng.integers(len(self._noise_bank)))]
            h, w = out.shape[:2]
            dy, dx = (int(v) for v in self._rng.integers(0, 32, 2))
            out = np.clip(out.astype(np.int16) + bank[dy:dy + h, dx:dx + w], 0, 255).astype(np.uint8)
        if self._unit_bank:
            bank = self._unit_bank[int(self._rng.integers(len(self._unit_bank)))]
            h, w = out.shape[:2]
            dy, dx = (int(v) for v in self._rng.integers(0, 32, 2))
            out = add_shot_noise(out, effects.shot_noise, bank[dy:dy + h, dx:dx + w], effects.noise_sigma)
        if effects.jpeg_quality:
            out = jpeg_roundtrip(out, effects.jpeg_quality)
        return out

    def _make_unit_bank(self) -> list[np.ndarray]:
        """A few images of unit normal noise, cropped at random offsets each frame (as the noise bank)."""
        h = max(c.height_px for c in self.cameras.values()) + 32
        w = max(c.width_px for c in self.cameras.values()) + 32
        return [self._rng.standard_normal((h, w, 3), dtype=np.float32) for _ in range(4)]

    def _make_noise_bank(self) -> list[np.ndarray]:
        """A few noise images, cropped at random offsets each frame: seeded, and cheap per frame."""
        h = max(c.height_px for c in self.cameras.values()) + 32
        w = max(c.width_px for c in self.cameras.values()) + 32
        sigma = self.config.effects.noise_sigma
        return [np.round(self._rng.normal(0, sigma, (h, w, 3))).astype(np.int16) for _ in range(4)]

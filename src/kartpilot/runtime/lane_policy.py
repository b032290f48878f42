"""The lane-following pipeline as a policy: camera images in, an actuator command out.

Centre camera: :func:`detect_lanes`; side cameras: :func:`detect_side_boundary` in a region of search
computed from each camera's calibration (the ground between ``near_m`` and ``far_m`` beside the kart,
where a boundary appears only when the kart is close to it); then :func:`lane_follow_step`. The same
policy drives the simulator, a replay or the real kart.

The follower's throttle is open loop, as in the thesis, unless ``speed_mps`` is set and the kart reports
its own speed (the RDW kart's 0x440): then the follower's throttle is a fraction of ``speed_mps`` (the
slower one in turns), held by a PI controller on the measured speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np

from kartpilot.behaviour.events import BehaviourConfig, BehaviourDecision, BehaviourState, behaviour_step
from kartpilot.control.lane_follow import (
    LaneDecision,
    LaneFollowConfig,
    LaneFollowState,
    heading_follow_step,
    lane_follow_step,
)
from kartpilot.control.longitudinal import SpeedPIConfig, SpeedPIState, speed_pi
from kartpilot.control.path_follow import PathFollowConfig, PathFollowState, path_follow_step
from kartpilot.control.stanley import StanleyConfig
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import CalibrationError, ConfigError
from kartpilot.core.geometry import invert_pose, transform_points
from kartpilot.core.types import ActuatorCommand, FrameSet, Image, LidarMount, VehicleFeedback, VehiclePose
from kartpilot.odometry.dead_reckoning import dead_reckon
from kartpilot.perception.detect import DetectorConfig, ObjectDetector
from kartpilot.perception.horizon import HorizonConfig, HorizonEstimator
from kartpilot.perception.lanes import (
    LaneConfig,
    LaneObservation,
    SideSearchConfig,
    detect_lanes,
    detect_side_boundary,
    draw_lanes,
    lane_on_ground,
)
from kartpilot.perception.objects import Detection
from kartpilot.perception.obstacles import ground_row
from kartpilot.perception.scan import LidarAgreement, LidarView, ScanConfig, lidar_view, locate_detections
from kartpilot.perception.signals import SignalConfig
from kartpilot.perception.tape import TapeConfig, TapeObservation, detect_tape_track, draw_tape_track
from kartpilot.planning.reference_path import ReferencePath
from kartpilot.sensors.health import LidarHealthConfig, LidarWatchdog

__all__ = [
    "KNOWN_GOOD_SPEED_MODE_KMH",
    "LANE_PRESETS",
    "LanePolicy",
    "LanePolicyConfig",
    "horizon_fraction",
    "lane_speed_mode_mps",
    "side_search_band",
]

# the simulator's kart camera (0.60 m, 12 degrees down, sdc-assen's wide track): the thesis's edges and straight
# lines, which the simulator's laps were measured with (docs/lanes.md)
_SIM_KART_LINES = LaneConfig(roi_top_width=1.0, min_abs_slope=0.1)
# the real SDC kart's centre camera at the venue (docs/real-kart.md): painted lines seen from 0.56 m, found as
# paint and fitted as curves; the horizon at 0.34 of the height is the ground calibration's (6.8 degrees down)
_REAL_KART_LINES = LaneConfig(method="paint", roi_top_width=1.0, min_abs_slope=0.1)

KNOWN_GOOD_SPEED_MODE_KMH = 15.0
"""The speed mode a simulated drive of the lanes pipeline on the sdc-kart uses unless one is given: the
fastest of the SDC kart's modes (5, 15, 30, 60 km/h) at which it drives whole laps of sdc-assen without a fault
with its defaults and the open-loop throttle, on the real kart's centre camera (``benchmarks/lane_race.py``,
docs/lanes.md; 30 km/h needs the speed held on the measured speed there) and of the venue track
(``benchmarks/venue_laps.py``). Simulated tracks: they say nothing yet about a real one."""


def lane_speed_mode_mps(pipeline: str, vehicle: str, requested_mps: float) -> float:
    """The speed mode a simulated drive runs at: the one requested, else (lanes on the sdc-kart)
    ``KNOWN_GOOD_SPEED_MODE_KMH``, else none (0: the kart's own top speed)."""
    if requested_mps > 0 or pipeline != "lanes" or vehicle != "sdc-kart":
        return requested_mps
    return KNOWN_GOOD_SPEED_MODE_KMH / 3.6


MANOEUVRE_FOLLOW = PathFollowConfig(stanley=StanleyConfig(k_heading=1.0, heading_lookahead_m=0.0,
                                                         heading_lookahead_time_s=0.0))
"""The manoeuvre follower's Stanley: a manoeuvre's S (parking's: 2.4 m across in 7 m, its curvature from 0 to 0.29
and back twice) is no steady bend. The teach-and-repeat follower's look-ahead heading and the feed-forward that
takes a steady bend's heading error off it turned the kart early and too little: it ended parking 6 to 10 degrees
yawed, a corner over the bay's line (sweep events 10479 and 10491, which park with this). The heading at the front
axle, no look-ahead, and twice the heading gain follow the S (``benchmarks/manoeuvre_follow.py``; docs/scenarios.md
says what it was chosen on and what judged it)."""


@dataclass(frozen=True)
class LanePolicyConfig:
    """Attributes:
        boundaries: what marks the track: ``lines`` (painted road lines, :mod:`kartpilot.perception.lanes`)
            or ``tape`` (a small-scale taped track seen through a wide-angle lens,
            :mod:`kartpilot.perception.tape`).
        lanes, tape: the two detectors' settings.
        near_m, far_m: the side cameras' region of search, as distances from the kart's side.
        kart_half_width_m: half the kart's width (where "beside the kart" starts).
        roi_far_m: the centre camera's region of interest starts at the row where the ground this far
            ahead appears (from the calibration; overrides ``lanes.roi_top``).
        speed_mps: with the kart's measured speed, the speed the follower's full throttle stands for
            (0: open-loop throttle, the thesis's).
        speed_pi: the speed controller's gains.
        events: the event's rules above lane following (:mod:`kartpilot.behaviour.events`): the objects in the
            centre camera (``detector``; people off by default, the HOG detector's cost) turn into a speed cap and
            stops before a red light's line or a crossing (``behaviour``). Needs ``speed_mps`` and the measured
            speed. The event's course is a closed one-way track: a speed sign counts on either side of the road
            (``detector.signals.sign_side: any``; on a public road, one on the left is the other direction's). A
            light counts on the right only, where the event has put it (``light_side: right``): a face before a
            tree's dark crown reads as a red lamp in its housing (the first scenario sweep's pedestrians), and
            on either side there are twice the faces.
        manoeuvre: the path follower that steers a manoeuvre the rules plan (an overtake, parking), on the pose dead
            reckoned from the measured speed and the steering (:data:`MANOEUVRE_FOLLOW`: Stanley's heading at the
            front axle, no look-ahead); ``wheelbase_m`` is the kart's (the sdc-kart's);
            the lanes steer again once the path is back within ``handover_m`` of the lane's centre. On the way back
            the dead-reckoned pose is corrected by the lane in view (:func:`lane_fix`).
        scan, lidar_health: on a kart with a LiDAR (the vehicle's or the rig's mount), its sweeps' objects and its
            watchdog: while it gives good sweeps the rules use them (the camera's detections placed by the scan,
            the bay measured, the return held, a stop before what is in the way); once it has given none for
            ``lidar_health.timeout_s``, the camera-only rules, said in the ``behaviour`` topic. So too while it
            disagrees with the camera: most of the cars, people and barriers the camera finds within
            ``lidar_reach_m`` have no return along their bearing (:class:`~kartpilot.perception.scan.LidarAgreement`).
        horizon: with the event's rules, the centre camera's pitch measured from the lane's boundaries while
            driving (:mod:`kartpilot.perception.horizon`): what the detectors find is placed with the camera as
            it is mounted, not as the rig says (the ``behaviour`` topic's ``pitch_off_deg``).
    """

    boundaries: Literal["lines", "tape"] = "lines"
    lanes: LaneConfig = field(default_factory=lambda: _SIM_KART_LINES)
    tape: TapeConfig = field(default_factory=TapeConfig)
    side: SideSearchConfig = field(default_factory=SideSearchConfig)
    follow: LaneFollowConfig = field(default_factory=LaneFollowConfig)
    near_m: float = 0.15
    far_m: float = 0.9
    kart_half_width_m: float = 0.6
    roi_far_m: float = 25.0
    speed_mps: float = 0.0
    speed_pi: SpeedPIConfig = field(default_factory=SpeedPIConfig)
    events: bool = False
    detector: DetectorConfig = field(default_factory=lambda: DetectorConfig(
        people=False, signals=SignalConfig(sign_side="any")))
    behaviour: BehaviourConfig = field(default_factory=BehaviourConfig)
    manoeuvre: PathFollowConfig = field(default_factory=lambda: MANOEUVRE_FOLLOW)
    wheelbase_m: float = 1.05
    handover_m: float = 0.5
    scan: ScanConfig = field(default_factory=ScanConfig)
    lidar_health: LidarHealthConfig = field(default_factory=LidarHealthConfig)
    lidar_reach_m: float = 10.0
    horizon: HorizonConfig = field(default_factory=HorizonConfig)

    def __post_init__(self) -> None:
        if not self.wheelbase_m > 0:
            raise ConfigError("lane_policy.wheelbase_m must be positive")
        if not self.lidar_reach_m > 0:
            raise ConfigError("lane_policy.lidar_reach_m must be positive")
        if not self.speed_mps >= 0:
            raise ConfigError("lane_policy.speed_mps must be 0 (open loop) or positive")
        if self.events and self.speed_mps <= 0:
            raise ConfigError("lane_policy.events needs lane_policy.speed_mps: the event's rules hold the speed on "
                              "the kart's measured speed")


def lane_fix(pose: VehiclePose, lane: tuple[float, float], lane_width_m: float, gate_m: float = 1.5,
             gate_rad: float = 0.15, gain: float = 0.5) -> VehiclePose:
    """A manoeuvre's dead-reckoned ``pose`` (in the frame of the lane where it began: x along it, y left of its
    centre) moved toward where the lane seen now puts the kart: ``lane`` (its centre's offset at the body's origin,
    left positive, and its heading) is the lane the kart began in or the one beside it to the left, ``lane_width_m``
    on; of the two readings on the road, the one nearer the pose is taken where it lies within ``gate_m`` and
    ``gate_rad`` of it and the other is farther by 0.4 m. Dead reckoning from a first view of the lane off by 4 to 6
    deg in heading put the kart's return onto the right line 20 m on (sweep events 10190, 10232); the lane in view
    on the way back says where the kart is."""
    offset, heading = lane
    on_road = [y for y in (-offset, lane_width_m - offset) if -lane_width_m / 2 <= y <= 1.5 * lane_width_m]
    readings = sorted((abs(y - pose.y_m), y) for y in on_road)
    if not readings:
        return pose
    miss, y = readings[0]
    yaw = -heading
    if miss > gate_m or (len(readings) > 1 and readings[1][0] - miss < 0.4) or abs(
            math.remainder(yaw - pose.yaw_rad, math.tau)) > gate_rad:
        return pose
    return replace(pose, y_m=pose.y_m + gain * (y - pose.y_m),
                   yaw_rad=pose.yaw_rad + gain * math.remainder(yaw - pose.yaw_rad, math.tau))


LANE_PRESETS: dict[str, LanePolicyConfig] = {
    # a kart's camera sees a wide road from close to the ground: the boundaries run out to the image's
    # sides at shallow slopes, so the region is a full-width band and shallow lines are kept
    # the side cameras' search ends 0.5 m out: the venue's lane is 3.0 m, so a centred 1.2 m kart has its
    # boundaries 0.9 m from its sides (sdc-assen's 4 to 6 m track: the default, 0.9 m)
    # the aim is the lane's centre about 4 m ahead (the paint finder's aim row), not the far meeting point: seen
    # from the bottom centre, the same steer is 2.5 to 4 times the angle in pixels, hence the lower gain
    "kart": LanePolicyConfig(lanes=_REAL_KART_LINES, far_m=0.5, follow=LaneFollowConfig(heading_gain=0.25)),
    # a car's dash camera, higher up and looking further: a trapezoid narrowing to the vanishing point
    "dashcam": LanePolicyConfig(lanes=LaneConfig()),
    # the thesis's edges and straight lines, sdc-assen's preset (its lane_preset): the paint finder halts at
    # sdc-assen's split, where the lane widens to 9 m (docs/real-kart.md)
    "kart-sim": LanePolicyConfig(),
    # a small car on a taped indoor track, through a wide-angle lens (a Donkey Car or a PiRacer)
    "tape": LanePolicyConfig(boundaries="tape"),
}


def side_search_band(camera: PinholeCamera, side: str, near_m: float, far_m: float, half_width_m: float
                     ) -> tuple[tuple[int, int], int]:
    """((far_row, near_row), inner_column) of the ground beside the kart as this camera sees it: abreast of
    the camera where it looks straight down at the side (the thesis's side cameras), else the nearest place
    ahead, up to 4 m, where it sees the whole band (a side camera turned forward, as the Hanze kart's are:
    abreast of it lies outside the image)."""
    sign = 1.0 if side == "left" else -1.0
    x0 = float(camera.pose_body_cam_array[0, 3])
    to_camera = invert_pose(camera.pose_body_cam_array)
    points = pixels = None
    for x in x0 + np.arange(0.0, 4.0, 0.1):
        body = np.array([[x, sign * (half_width_m + far_m), 0.0], [x, sign * (half_width_m + near_m), 0.0]])
        points = transform_points(to_camera, body)
        if np.any(points[:, 2] <= 0):
            continue
        pixels = camera.project(points)
        if np.all((pixels[:, 0] >= 0) & (pixels[:, 0] <= camera.width_px - 1)):
            break
    if points is None or pixels is None or np.any(points[:, 2] <= 0):
        raise CalibrationError(f"the {side} camera does not see the ground beside the kart")
    far_row, near_row = (round(v) for v in pixels[:, 1])
    if not (far_row < near_row and 0 <= far_row < camera.height_px - 8):
        raise CalibrationError(f"the {side} camera's region of search (rows {far_row} to {near_row}) is off the image")
    return (far_row, min(near_row, camera.height_px)), round(pixels[1, 0])


def _ground_row(camera: PinholeCamera, ahead_m: float) -> float:
    """The image row of the ground ``ahead_m`` in front of the camera, on the kart's centre line."""
    row = ground_row(camera, ahead_m)
    if not math.isfinite(row):
        raise CalibrationError("the centre camera does not look ahead")
    return row


def horizon_fraction(camera: PinholeCamera) -> float:
    """The horizon's row over the image's height for a camera on the kart (the ground 10 km ahead), clipped to
    the image."""
    return min(max(_ground_row(camera, 1.0e4) / camera.height_px, 0.0), 0.9)


class LanePolicy:
    """Holds the follower's state from frame to frame; everything else is pure functions."""

    def __init__(self, cameras: dict[str, PinholeCamera], config: LanePolicyConfig | None = None,
                 rate_hz: float = 30.0, max_steer_rad: float | None = None, lidar_mount: LidarMount | None = None
                 ) -> None:
        """``max_steer_rad`` is the kart's steering range: the follower's S_max never exceeds it. ``lidar_mount``:
        where the kart's LiDAR sits, if it has one (its sweeps come as ``FrameSet.scans["lidar"]``)."""
        self.config = config or LanePolicyConfig()
        if max_steer_rad is not None and max_steer_rad < self.config.follow.max_steer_rad:
            self.config = replace(self.config, follow=replace(self.config.follow, max_steer_rad=max_steer_rad))
        if "center" not in cameras:
            raise CalibrationError("lane following needs a camera named 'center'")
        centre = self.centre_camera = cameras["center"]
        top_row = _ground_row(centre, self.config.roi_far_m)
        lanes = replace(self.config.lanes, roi_top=min(max(top_row / centre.height_px, 0.0), 0.9),
                        curves=replace(self.config.lanes.curves, horizon=horizon_fraction(centre)))
        self.config = replace(self.config, lanes=lanes)
        # side cameras look out to the side; a forward-looking "left"/"right" (the rc-kart's stereo pair) is not one
        self.bands = {side: side_search_band(cameras[side], side, self.config.near_m, self.config.far_m,
                                             self.config.kart_half_width_m)
                      for side in ("left", "right")
                      if side in cameras and cameras[side].pose_body_cam_array[0, 2] < math.cos(math.radians(30))}
        # what each camera sees of the kart itself (the rig's body masks), left out of the search
        self.body_masks = {name: cam.body_mask_image() for name, cam in cameras.items()}
        self.state = LaneFollowState()
        self.dt_s = 1.0 / rate_hz
        self.last_observation: LaneObservation | None = None
        self.last_tape: TapeObservation | None = None
        self.last_decision: LaneDecision | None = None
        self.last_command: ActuatorCommand | None = None
        self.measured_speed_mps: float | None = None
        self.measured_steer_rad: float | None = None
        self.speed_state = SpeedPIState()
        self.objects = ObjectDetector(self.config.detector, centre) if self.config.events else None
        self.horizon = HorizonEstimator(centre, self.config.horizon)
        self.behaviour = BehaviourState.start(self.config.behaviour)
        self.last_behaviour: BehaviourDecision | None = None
        self.last_objects: list[Detection] = []
        # a manoeuvre under way: its path, the follower's state and the pose dead reckoned since it started
        self.manoeuvre: tuple[ReferencePath, PathFollowState, VehiclePose] | None = None
        self.lane_ground: tuple[int, tuple[float, float]] | None = None
        self.lidar_mount = lidar_mount
        self.lidar_watchdog = LidarWatchdog(["lidar"], self.config.lidar_health) if lidar_mount is not None else None
        self.lidar_agreement = LidarAgreement(self.config.lidar_reach_m) if lidar_mount is not None else None
        self.lidar: LidarView | None = None  # the latest good sweep's view, while the LiDAR is healthy
        self.lidar_problem = ""  # why the rules are camera-only, while they are
        self.lidar_events: list[tuple[int, str]] = []  # (stamp, problem or "" when it recovered), each change

    def _with_lidar(self, frames: FrameSet, detections: list[Detection]) -> tuple[LidarView | None, list[Detection]]:
        """The latest good sweep's view while the LiDAR is healthy and agrees with the camera, and the camera's
        detections placed by it; (None, the detections as they were) otherwise: camera-only."""
        if self.lidar_watchdog is None or self.lidar_mount is None or self.lidar_agreement is None:
            return None, detections
        problem = self.lidar_watchdog.check(frames).get("lidar", "")
        scan = frames.scans.get("lidar")
        if scan is not None and not self.lidar_watchdog.sweep_problems["lidar"]:  # this sweep is a good one
            self.lidar = lidar_view(scan, self.lidar_mount, self.config.scan)
        located = detections
        if not problem and self.lidar is not None:  # the camera says what it is, the scan where
            located = locate_detections(detections, list(self.lidar.clusters), self.lidar_mount, self.config.scan)
            problem = self.lidar_agreement.update(located)
        if bool(problem) != bool(self.lidar_problem):  # lost, or back: once each (the text counts up meanwhile)
            self.lidar_events.append((frames.stamp_ns, problem))
        self.lidar_problem = problem
        return (None, detections) if problem else (self.lidar, located)

    def observe_vehicle(self, feedback: VehicleFeedback) -> None:
        """The kart's own measurements before a step; a fresh speed closes the speed loop (``speed_mps``)."""
        self.measured_speed_mps = feedback.speed_mps
        self.measured_steer_rad = feedback.steer_rad

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        centre_image = frames.images.get("center")
        if self.config.boundaries == "tape":
            return self._follow_tape(frames.stamp_ns, centre_image)
        observation = (detect_lanes(centre_image, self.config.lanes, body_mask=self._mask("center", centre_image))
                       if centre_image is not None else None)
        away = {}
        for side, (band, column) in self.bands.items():
            image = frames.images.get(side)
            away[side] = detect_side_boundary(image, band, column, self.config.side, self._mask(side, image)
                                              ).steer if image is not None else 0.0
        decision, self.state = lane_follow_step(self.config.follow, self.state, observation, away.get("left", 0.0),
                                                away.get("right", 0.0), self.dt_s)
        self.last_observation = observation
        if self.objects is not None:
            # the camera as it is mounted, its pitch measured from the boundaries: what it finds placed with it
            moved = self.measured_speed_mps * self.dt_s if self.measured_speed_mps is not None else math.inf
            camera = self.objects.camera = self.horizon.update(observation, abs(moved))
            lane = lane_on_ground(observation, camera)
            if lane is not None:  # where the lane runs, for a manoeuvre that starts in a frame that lacks it
                self.lane_ground = (frames.stamp_ns, lane)
            found = self.objects(centre_image, abs(moved)) if centre_image is not None else []
            view, self.last_objects = self._with_lidar(frames, found)
            self.last_behaviour, self.behaviour = behaviour_step(
                self.config.behaviour, self.behaviour, self.last_objects, self.measured_speed_mps or 0.0, self.dt_s,
                view)
            decision = self._manoeuvre(frames.stamp_ns, decision)
        return self._command(frames.stamp_ns, decision)

    def _manoeuvre(self, stamp_ns: int, decision: LaneDecision) -> LaneDecision:
        """Where the rules planned a manoeuvre, the path follower steers along it instead of the lanes, on the
        pose dead reckoned from the kart's measured speed and steering (the commanded steering where none is
        measured). The path, planned along the lane, is laid where the lane runs (its centre and heading on the
        ground, from the boundaries last seen in the second before it starts); once the path is back within
        ``handover_m`` of the lane's centre, the lanes steer again."""
        b = self.last_behaviour
        if b is None or b.state not in ("overtake", "park", "parked"):
            self.manoeuvre = None
            return decision
        speed = self.measured_speed_mps or 0.0
        if b.path is not None and b.replanned and self.manoeuvre is not None:  # the same frame: the pose goes on
            self.manoeuvre = (b.path, *self.manoeuvre[1:])
        elif b.path is not None:
            seen_ns, lane = self.lane_ground or (0, (0.0, 0.0))
            if stamp_ns - seen_ns > 1_000_000_000:
                lane = (0.0, 0.0)  # not seen for a second: the kart's own heading is the lane's
            pose = VehiclePose(stamp_ns, 0.0, -lane[0], -lane[1], speed, 0.0, "bridged", "dead reckoning")
            self.manoeuvre = (b.path, PathFollowState(steer_rad=self.state.steer_rad), pose)
        if self.manoeuvre is None:
            return decision
        path, follow, pose = self.manoeuvre
        if b.path is None or b.replanned:
            steer = self.measured_steer_rad if self.measured_steer_rad is not None else (
                self.last_command.steer_rad if self.last_command is not None else 0.0)
            pose = dead_reckon(pose, speed, steer, self.config.wheelbase_m, self.dt_s, stamp_ns)
        peak = int(np.argmax(np.abs(path.y_m)))  # an overtake's return begins past its widest point
        if b.state == "overtake" and follow.index > peak and self.lane_ground is not None \
                and self.lane_ground[0] == stamp_ns:
            pose = lane_fix(pose, self.lane_ground[1], self.config.behaviour.passing.lane_offset_m)
        out, follow = path_follow_step(self.config.manoeuvre, follow, path, pose, self.dt_s, self.config.wheelbase_m,
                                       self.config.follow.max_steer_rad)
        self.manoeuvre = (path, follow, pose)
        self.state = replace(self.state, steer_rad=out.steer_rad)
        if b.state == "overtake":
            returning = out.index > peak
            if out.done or (returning and abs(float(path.y_m[out.index])) < self.config.handover_m):
                self.manoeuvre = None  # back in the lane: the lanes steer the rest
                return decision
            return LaneDecision(out.steer_rad, 1.0, 0.0, "path")  # the speed: the mode's, under the rules' cap
        # parking: the path's own speed (it slows to its end), under the rules' cap; stopped there, braked
        fraction = 0.0 if out.done else out.target_speed_mps / max(self.config.speed_mps, 1e-3)
        return LaneDecision(out.steer_rad, min(fraction, 1.0), 1.0 if out.done else 0.0, "path")

    def _mask(self, camera: str, image: Image | None) -> Image | None:
        """The camera's body mask at the image's size (a camera may deliver another size than calibrated)."""
        mask = self.body_masks.get(camera)
        if mask is None or image is None or mask.shape[:2] == image.shape[:2]:
            return mask
        mask = cv2.resize(mask, (image.shape[1], image.shape[0]), interpolation=cv2.INTER_NEAREST)
        self.body_masks[camera] = mask
        return mask

    def _follow_tape(self, stamp_ns: int, image: Image | None) -> ActuatorCommand:
        observation = detect_tape_track(image, self.config.tape) if image is not None else None
        decision, self.state = heading_follow_step(self.config.follow, self.state,
                                                   observation.seen_bearing_rad if observation else None, self.dt_s)
        self.last_tape = observation
        return self._command(stamp_ns, decision)

    def _command(self, stamp_ns: int, decision: LaneDecision) -> ActuatorCommand:
        self.last_decision = decision
        throttle, brake = decision.throttle, decision.brake
        if self.config.speed_mps > 0 and self.measured_speed_mps is not None and decision.reason != "halt":
            target = self.config.speed_mps * decision.throttle
            if self.last_behaviour is not None:  # the event's rules cap it (0: stand)
                target = min(target, self.last_behaviour.speed_cap_mps)
            throttle, brake, self.speed_state = speed_pi(self.config.speed_pi, self.speed_state, target,
                                                         self.measured_speed_mps, self.dt_s)
            if self.last_behaviour is not None and target < 0.05:
                throttle, brake = 0.0, max(brake, 1.0 if self.measured_speed_mps < 0.5 else brake)
        elif self.last_behaviour is not None and self.last_behaviour.speed_cap_mps < 0.05:
            throttle, brake = 0.0, 1.0  # no measured speed: a stop the rules ask for is a stop
        self.last_command = ActuatorCommand(stamp_ns, decision.steer_rad, throttle, brake)
        return self.last_command

    def fault(self) -> str:
        """What is wrong with the pipeline, for the supervisor: no boundary seen for longer than it may hold."""
        if self.last_decision is not None and self.last_decision.reason == "halt":
            return f"no lane boundary seen for more than {self.config.follow.hold_frames} frames"
        return ""

    def outputs(self) -> dict[str, dict[str, float | int | str]]:
        """The last step as the recording's ``lanes`` topic (pixels of the centre image; NaN where a
        boundary was not detected)."""
        observation, decision, command = self.last_observation, self.last_decision, self.last_command
        if decision is None or command is None:
            return {}
        values: dict[str, float | int | str] = {}
        if self.config.boundaries == "tape":
            tape = self.last_tape
            seen = tape if tape is not None and tape.any_detected else None
            values["target_bearing_rad"] = seen.bearing_rad if seen else math.nan
            values["target_x_m"], values["target_z_m"] = seen.target_m if seen else (math.nan, math.nan)
            values["confidence"] = tape.confidence if tape is not None else 0.0
            values.update(steer_rad=command.steer_rad, throttle=command.throttle, brake=command.brake,
                          rule=decision.reason)
            return {"lanes": values}
        for side in ("left", "right"):
            source = getattr(observation, f"{side}_source") if observation is not None else "none"
            ends = getattr(observation, side).as_tuple() if source == "detected" else (math.nan,) * 4
            for key, value in zip(("x_bottom", "y_bottom", "x_top", "y_top"), ends, strict=True):
                values[f"{side}_{key}_px"] = float(value)
            values[f"{side}_source"] = source
        meet = observation.intersection_px if observation is not None else None
        values["intersection_x_px"], values["intersection_y_px"] = meet if meet is not None else (math.nan, math.nan)
        values["confidence"] = observation.confidence if observation is not None else 0.0
        values.update(steer_rad=command.steer_rad, throttle=command.throttle, brake=command.brake,
                      rule=decision.reason)
        topics: dict[str, dict[str, float | int | str]] = {"lanes": values}
        if self.last_behaviour is not None:  # the event's rules: their state, reason and what they saw
            b = self.last_behaviour
            topics["behaviour"] = {"state": b.state, "reason": b.reason, "speed_cap_mps": b.speed_cap_mps,
                                   "stop_distance_m": b.stop_distance_m, "limit_kmh": self.behaviour.limit_kmh,
                                   "pitch_off_deg": self.horizon.pitch_deg,
                                   "objects": ";".join(f"{d.label}:{d.state}@{d.distance_m:.1f}"
                                                       for d in self.last_objects)}
            if self.lidar_watchdog is not None:  # a kart with a LiDAR: what the decision came from, and why not
                topics["behaviour"]["sensors"] = b.sensors
                topics["behaviour"]["lidar"] = (f"{self.lidar_problem}: camera only" if self.lidar_problem else
                                                "ok" if self.lidar is not None else "no sweep yet")
        return topics

    def overlay(self, frames: FrameSet) -> Image | None:
        """The pipeline's view: the centre image with the boundaries it found and where they meet (the
        video's caption gives the steer)."""
        image = frames.images.get("center")
        if image is not None and self.config.boundaries == "tape" and self.last_tape is not None:
            return draw_tape_track(image, self.last_tape)
        if image is None or self.last_observation is None:
            return None
        drawn = draw_lanes(image, self.last_observation)
        if self.last_behaviour is not None:  # the event's rules: what they see and what they decided
            for d in self.last_objects:
                left, top, right, bottom = (round(v) for v in d.box_px)
                cv2.rectangle(drawn, (left, top), (right, bottom), (0, 200, 255), 2)
                cv2.putText(drawn, f"{d.label} {d.state} {d.distance_m:.1f} m", (left, max(top - 4, 12)),
                            cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 200, 255), 1, cv2.LINE_AA)
            b = self.last_behaviour
            # along the bottom: a drive's video writes its own lines from the top
            text, where = f"{b.state}: {b.reason} (cap {b.speed_cap_mps * 3.6:.0f} km/h)", (10, drawn.shape[0] - 14)
            cv2.putText(drawn, text, where, cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 4, cv2.LINE_AA)
            cv2.putText(drawn, text, where, cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 200, 255), 2, cv2.LINE_AA)
        return drawn

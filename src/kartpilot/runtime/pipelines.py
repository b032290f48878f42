"""The pipelines by name: one factory each, from one typed context, for every backend.

The simulator, a replay and a live drive each describe what they have in a :class:`PipelineContext`
(the kart, the cameras the source delivers, the loop's rate, the stack's configuration, and what the
pipeline may localise against) and ask :func:`build_pipeline` for a policy. Adding a pipeline is one
entry in :data:`PIPELINES`.

- ``lanes``: lane boundaries from the centre camera, off-track avoidance from the side cameras
  (:class:`~kartpilot.runtime.lane_policy.LanePolicy`; the thesis's SDC pipeline, part 1).
- ``stereo-vo``: stereo VO (with the taught drive's visual map, if given) following a reference path
  (the thesis's small-scale kart, part 2).
- ``mono-vo``: one camera, monocular VO fused with place fixes from a place database, following the
  database's own drive or a given reference (the thesis's part 1 VO, made to work).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from kartpilot.calibration.lens import LensRemap
from kartpilot.calibration.rectify import StereoSetup
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, FrameSet, Image, VehicleFeedback
from kartpilot.core.vehicle import VehicleParams
from kartpilot.odometry.localizer import StereoVOLocalizer
from kartpilot.odometry.mono_localizer import MonoLocalizer
from kartpilot.odometry.places import PlaceDatabase
from kartpilot.odometry.visual_map import VisualMap
from kartpilot.planning.reference_path import ReferencePath
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.lane_policy import LanePolicy
from kartpilot.runtime.loop import Policy
from kartpilot.runtime.path_policy import PathFollowPolicy, places_reference

__all__ = ["PIPELINES", "PipelineContext", "PreparedPipeline", "Route", "StereoInput", "build_pipeline",
           "path_policy_of"]


@dataclass(frozen=True)
class StereoInput:
    """The stereo pair as the source delivers it: its names (left, right) and its setup. A setup with a
    rectification means the frames arrive raw (a live pair) and are rectified before the pipeline."""

    pair: tuple[str, str]
    setup: StereoSetup


@dataclass(frozen=True)
class Route:
    """What the path-following pipelines follow and localise against: a reference path, the taught drive's
    visual map (stereo), a place database (one camera). Each is optional; a pipeline says what it lacks."""

    reference: ReferencePath | None = None
    visual_map: VisualMap | None = None
    places: PlaceDatabase | None = None


@dataclass(frozen=True)
class PipelineContext:
    """What a pipeline is built from, whichever backend runs it.

    Attributes:
        vehicle: the kart.
        cameras: the cameras the source delivers images of, by name.
        rate_hz: the loop's rate (the cameras').
        stack: the stack's configuration (each pipeline reads its own sections; ``limits`` narrows the
            kart's steering range).
        stereo: the stereo pair, where the source delivers one.
        route: what the path-following pipelines follow and localise against.
        wrap_vo: the seam fault injection wraps a localiser's VO at (``vo-failure``); None: the VO itself.
    """

    vehicle: VehicleParams
    cameras: Mapping[str, PinholeCamera]
    rate_hz: float
    stack: StackConfig = field(default_factory=StackConfig)
    stereo: StereoInput | None = None
    route: Route = field(default_factory=Route)
    wrap_vo: Callable[[Any], Any] | None = None

    @property
    def max_steer_rad(self) -> float:
        """The steering range the pipeline may use: the kart's, narrowed by the stack's limits."""
        return self.stack.limits.for_vehicle(self.vehicle).max_steer_rad


class PreparedPipeline:
    """A pipeline whose images are prepared on the way in: a raw stereo pair rectified, a lens's image
    undistorted. The raw frames are what gets recorded; the pipeline, its outputs and its view see the
    prepared ones."""

    def __init__(self, policy: PathFollowPolicy, prepare: Callable[[FrameSet], FrameSet]) -> None:
        self.policy, self.prepare = policy, prepare

    def __call__(self, frames: FrameSet) -> ActuatorCommand:
        return self.policy(self.prepare(frames))

    def observe_vehicle(self, feedback: VehicleFeedback) -> None:
        self.policy.observe_vehicle(feedback)

    def fault(self) -> str:
        return self.policy.fault()

    def outputs(self) -> dict[str, dict[str, float | int | str]]:
        return self.policy.outputs()

    def overlay(self, frames: FrameSet) -> Image | None:
        return self.policy.overlay(self.prepare(frames))

    def close(self) -> None:
        self.policy.close()


def _rectifier(stereo: StereoInput) -> Callable[[FrameSet], FrameSet]:
    def prepare(frames: FrameSet) -> FrameSet:
        names = stereo.pair
        left, right = (frames.images.get(n) for n in names)
        if left is None or right is None:
            return frames
        left, right = stereo.setup.rectify(left, right)
        return FrameSet(frames.index, frames.stamp_ns, {**frames.images, names[0]: left, names[1]: right},
                        frames.capture_ns)

    return prepare


def _undistorter(name: str, lens: LensRemap) -> Callable[[FrameSet], FrameSet]:
    def prepare(frames: FrameSet) -> FrameSet:
        image = frames.images.get(name)
        if image is None:
            return frames
        return FrameSet(frames.index, frames.stamp_ns, {**frames.images, name: lens(image)}, frames.capture_ns)

    return prepare


def _lanes(context: PipelineContext) -> Policy:
    return LanePolicy(dict(context.cameras), context.stack.lane_policy, context.rate_hz, context.max_steer_rad,
                      context.vehicle.lidar)


def _stereo_vo(context: PipelineContext) -> Policy:
    stereo, route, stack = context.stereo, context.route, context.stack
    if stereo is None or not set(stereo.pair) <= set(context.cameras):
        raise ConfigError(f"the stereo-vo pipeline needs a stereo pair ({context.vehicle.name}'s cameras here: "
                          f"{', '.join(context.cameras) or 'none'})")
    if route.reference is None:
        raise ConfigError("the stereo-vo pipeline follows a reference: give --reference (kartpilot reference writes "
                          "one from a recorded drive)")
    config = replace(stack.drive.localizer, left_camera=stereo.pair[0], right_camera=stereo.pair[1])
    localizer = StereoVOLocalizer(stereo.setup.rig, stereo.setup.pose_body_left, stack.stereo_vo, config,
                                  route.visual_map, wrap_vo=context.wrap_vo)
    policy = PathFollowPolicy(localizer, route.reference, stack.drive.follow, context.vehicle.wheelbase_m,
                              context.max_steer_rad, context.rate_hz)
    return policy if stereo.setup.rectification is None else PreparedPipeline(policy, _rectifier(stereo))


def _mono_vo(context: PipelineContext) -> Policy:
    route, stack = context.route, context.stack
    if route.places is None:
        raise ConfigError("the mono-vo pipeline localises against a place database: give --places (kartpilot places "
                          "build writes one from a recorded drive)")
    name = stack.drive.mono.camera
    if name not in context.cameras:
        raise ConfigError(f"the mono-vo pipeline needs the {name!r} camera (the {context.vehicle.name} has "
                          f"{', '.join(context.cameras) or 'none'} here)")
    camera = context.cameras[name]
    lens = route.places.lens_for(camera, name)  # the one place the lens is taken out, as the database's images were
    pinhole = lens.pinhole if lens is not None else camera
    localizer = MonoLocalizer(pinhole, route.places, stack.mono_vo, stack.drive.mono, wrap_vo=context.wrap_vo,
                              vehicle=context.vehicle)
    path = route.reference or places_reference(route.places, pinhole.pose_body_cam_array, stack.drive.path)
    policy = PathFollowPolicy(localizer, path, stack.drive.follow, context.vehicle.wheelbase_m,
                              context.max_steer_rad, context.rate_hz)
    return policy if lens is None else PreparedPipeline(policy, _undistorter(name, lens))


PIPELINES: dict[str, Callable[[PipelineContext], Policy]] = {
    "lanes": _lanes,
    "stereo-vo": _stereo_vo,
    "mono-vo": _mono_vo,
}


def build_pipeline(name: str, context: PipelineContext) -> Policy:
    """The policy named ``name``; a :class:`ConfigError` naming the choices for an unknown name, and naming
    what is missing (a camera, a reference, a place database) for a known one."""
    factory = PIPELINES.get(name)
    if factory is None:
        raise ConfigError(f"unknown pipeline {name!r} ({', '.join(PIPELINES)})")
    return factory(context)


def path_policy_of(policy: Policy) -> PathFollowPolicy | None:
    """The path follower inside a pipeline (its drive log, its stop), or None for the lane follower."""
    if isinstance(policy, PreparedPipeline):
        return policy.policy
    return policy if isinstance(policy, PathFollowPolicy) else None

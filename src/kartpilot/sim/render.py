"""Rendering the simulated cameras with Panda3D, offscreen, on the CPU.

Panda3D's software rasteriser (``p3tinydisplay``) needs nothing but the pip
package, renders the same image for the same pose every time, and filters
textures as each texture asks with ``texture-quality-level best`` (see
``docs/simulator.md`` in the shared folder for the measurements behind the
choice). Textures are mipmapped and sampled bilinearly in the nearest mipmap
level: p3tinydisplay's trilinear filter (between two levels) drew bands of
unfiltered texture across the road at some distances, aliasing no lens makes
(noise that flickers as the kart moves, on which a feature tracker finds
corners that are not there), and took twice the time. All cameras of a kart
are display regions of one offscreen buffer, read back with one copy per
frame.

The world is flat (z = 0). Ground layers (grass, road surface, tyre marks,
curbs, painted lines) are drawn first, in order and without depth, so decals
never flicker; cones and tyre walls are drawn with depth on top. The
background panorama follows the cameras, so it behaves as if at infinity.

Camera model: each camera's projection is its OpenCV matrix exactly, with the
half-pixel shift between OpenCV's pixel centres and GL's accounted for, so a
3D point lands where ``cv2.projectPoints`` puts it (tested to 0.5 px).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import KartpilotError
from kartpilot.core.geometry import Array
from kartpilot.core.types import Image
from kartpilot.sim import textures
from kartpilot.sim.track import PROP_SIZES_M, SAMPLE_SPACING_M, Prop, Track, roadside_trees, scenery_boxes

__all__ = ["RenderConfig", "Renderer", "lighting_for_time", "shadow_polygons", "sun_direction"]

# state-cache false: Panda3D's cache of render states made a drawing depend on what an earlier renderer in the
# process drew (an object's edge a pixel column off), and through it the tests that ran before; a fresh process
# draws the same images with it or without it, at the same speed
_PRC = """
load-display p3tinydisplay
aux-display
window-type offscreen
audio-library-name null
texture-quality-level best
sync-video false
notify-level warning
notify-level-display error
state-cache false
"""


class RenderError(KartpilotError):
    """The renderer could not start or draw."""


@dataclass(frozen=True)
class RenderConfig:
    """How the world is drawn.

    Attributes:
        time_of_day_h: sets the sun's elevation and colour (6 = dawn, 13 = noon, 20 = dusk).
        sun_azimuth_deg: compass direction of the sun in the world frame (0 = +x, counter-clockwise).
        near_m, far_m: clipping planes (the near plane must be a few millimetres for a 19 cm camera).
        background_radius_m: radius of the panorama around the cameras.
        apron_m: width of the textured ground beside the road surface; beyond it the ground is one
            flat colour (texturing all of it would halve the frame rate for pixels that are far away).
        texture_seed: seed of the procedural textures (the world's look, not the run's randomness).
        scenery_spacing_m: roadside buildings and boards about this far apart along the track, each with its
            own facade (0: none, the bare circuit). Place recognition needs them: without, nothing near the
            track tells one place from another (:func:`kartpilot.sim.track.scenery_boxes`).
        sky: ``track`` (the track's own, ``TrackSpec.sky``), ``clear`` (a sun that casts its light) or
            ``overcast`` (light from the whole sky, a grey sky: the venue's frames).
        trees_spacing_m: trees and lamp poles beside the road about this far apart (0: none;
            :func:`kartpilot.sim.track.roadside_trees`), near enough to throw their shadows across the lane.
        shadows: under a clear sky, hard shadows on the ground of the trees, poles, buildings, barriers and props
            that stand still (a shadowed patch gets the sky's light only: as dark as the sun is bright). Off by
            default: every simulated figure before them was measured without.
    """

    time_of_day_h: float = 13.0
    sun_azimuth_deg: float = 135.0
    near_m: float = 0.005
    far_m: float = 2500.0
    background_radius_m: float = 1000.0
    apron_m: float = 15.0
    texture_seed: int = 0
    scenery_spacing_m: float = 0.0
    sky: Literal["track", "clear", "overcast"] = "track"
    trees_spacing_m: float = 0.0
    shadows: bool = False


def sun_direction(time_of_day_h: float, sun_azimuth_deg: float) -> Array:
    """The unit vector along the sun's light (from the sun toward the ground) in the world frame."""
    elevation, _, _ = lighting_for_time(time_of_day_h)
    az, el = math.radians(sun_azimuth_deg), math.radians(max(elevation, 2.0))
    return np.array([-math.cos(az) * math.cos(el), -math.sin(az) * math.cos(el), -math.sin(el)])


def shadow_polygons(boxes: Array, bottoms_m: Array, light: Array) -> list[Array]:
    """The shadows on the flat ground of boxes (rows ``x, y, yaw, width, depth, height`` standing from
    ``bottoms_m`` up) in light travelling along ``light``: each the convex hull of its corners cast along the light
    onto z = 0, as (K, 2) polygons (a box is convex, so is its shadow)."""
    import cv2

    light = np.asarray(light, float)
    if light[2] >= -1e-6:
        return []
    out = []
    for (x, y, yaw, width, depth, height), bottom in zip(np.asarray(boxes, float), bottoms_m, strict=True):
        c, s = math.cos(yaw), math.sin(yaw)
        foot = np.array([[x + dx * c - dy * s, y + dx * s + dy * c]
                         for dx in (-width / 2, width / 2) for dy in (-depth / 2, depth / 2)])
        corners = [np.c_[foot, np.full(4, z)] for z in (bottom, bottom + height)]
        points = np.vstack(corners)
        cast = points[:, :2] - points[:, 2:3] / light[2] * light[None, :2]
        hull = cv2.convexHull(cast.astype(np.float32))[:, 0].astype(float)
        out.append(hull)
    return out


def lighting_for_time(time_of_day_h: float, overcast: bool = False) -> tuple[float, tuple[float, float, float], float]:
    """(sun elevation in degrees, sun colour as RGB factors, ambient level) for an hour of the day; an overcast
    sky turns most of the sun's light into ambient light.

    Ambient plus sun never exceeds 0.95: the software rasteriser's colour interpolation wraps around
    (a stray yellow pixel) where a lit colour saturates at a triangle edge.
    """
    if overcast:
        phase = min(max((time_of_day_h - 6.0) / 14.0, 0.0), 1.0)
        level = 0.6 + 0.33 * math.sin(math.pi * phase)
        return 60.0 * math.sin(math.pi * phase), (0.02, 0.02, 0.02), level
    phase = min(max((time_of_day_h - 6.0) / 14.0, 0.0), 1.0)
    elevation = 60.0 * math.sin(math.pi * phase)
    height = math.sin(math.radians(max(elevation, 0.0)))
    strength = 0.15 + 0.45 * height
    warm = 1.0 - height  # low sun: warmer, dimmer
    ambient = 0.30 + 0.20 * height
    scale = min(1.0, 0.95 / (ambient + strength * (1.0 + 0.15 * warm)))
    colour = (scale * strength * (1.0 + 0.15 * warm), scale * strength, scale * strength * (1.0 - 0.25 * warm))
    return elevation, colour, scale * ambient


class Renderer:
    """Draws a track, as seen by a set of cameras, into BGR images."""

    def __init__(self, track: Track, cameras: Mapping[str, PinholeCamera], config: RenderConfig | None = None,
                 show_cones: bool = True) -> None:
        if not cameras:
            raise RenderError("the renderer needs at least one camera")
        self.config = config or RenderConfig()
        self._overcast = (self.config.sky if self.config.sky != "track" else track.spec.sky) == "overcast"
        self.cameras = dict(cameras)
        self._core = _panda()
        core = self._core
        self._width = sum(c.width_px for c in self.cameras.values())
        self._height = max(c.height_px for c in self.cameras.values())
        engine = core.GraphicsEngine.get_global_ptr()
        self._engine = engine
        pipe = _pipe()
        fb = core.FrameBufferProperties()
        fb.set_rgb_color(True)
        fb.set_rgba_bits(8, 8, 8, 0)
        fb.set_depth_bits(24)
        props = core.WindowProperties.size(self._width, self._height)
        buffer = engine.make_output(pipe, "kartpilot-cameras", 0, fb, props, core.GraphicsPipe.BF_refuse_window)
        if buffer is None:
            raise RenderError("Panda3D could not open an offscreen buffer")
        self._buffer = buffer
        self._texture = core.Texture("cameras")
        buffer.add_render_texture(self._texture, core.GraphicsOutput.RTM_copy_ram)
        buffer.set_clear_color(core.LColor(*(np.array(textures.HAZE_BGR[::-1]) / 255.0), 1))

        self.root = core.NodePath("world")
        self._textures: dict[tuple[int, bool], tuple[Image, Any]] = {}  # (id, wrap) -> (image kept alive, texture)
        self._lights = self._make_lights()
        self._background = self.root.attach_new_node("background")
        self._build_world(track, show_cones)
        self._camera_nodes: dict[str, Any] = {}
        self._slices: dict[str, tuple[int, int, int]] = {}
        left = 0
        for name, cam in self.cameras.items():
            node = self.root.attach_new_node(core.Camera(name, self._lens(cam)))
            region = buffer.make_display_region(left / self._width, (left + cam.width_px) / self._width,
                                                1.0 - cam.height_px / self._height, 1.0)
            region.set_camera(node)
            self._camera_nodes[name] = node
            self._slices[name] = (left, cam.width_px, cam.height_px)
            left += cam.width_px

    # --- public ---------------------------------------------------------------------------

    def render(self, poses_world_cam: Mapping[str, Array]) -> dict[str, Image]:
        """BGR images of the named cameras at the given 4x4 OpenCV camera poses."""
        core = self._core
        centre = np.mean([np.asarray(p)[:3, 3] for p in poses_world_cam.values()], axis=0)
        self._background.set_pos(float(centre[0]), float(centre[1]), 0.0)
        for name, node in self._camera_nodes.items():
            active = name in poses_world_cam
            node.node().set_active(active)
            if active:
                node.set_mat(_panda_matrix(core, np.asarray(poses_world_cam[name], float)))
        self._engine.render_frame()
        # Panda3D interns every transform and render state it sees; ShowBase collects the unused ones each frame,
        # and so must we (a moving camera's new poses would otherwise pile up: about 4 KB a frame)
        core.TransformState.garbage_collect()
        core.RenderState.garbage_collect()
        data = self._texture.get_ram_image_as("BGR")
        if not data:
            raise RenderError("the renderer returned no image")
        full = np.frombuffer(data, np.uint8).reshape(self._height, self._width, 3)[::-1]
        images = {}
        for name in poses_world_cam:
            left, width, height = self._slices[name]
            images[name] = np.ascontiguousarray(full[:height, left:left + width])
        return images

    def add_markers(self, points_world: Array, size_m: float = 0.02,
                    rgba: tuple[float, float, float, float] = (1.0, 0.0, 1.0, 1.0)) -> None:
        """Draw small unlit octahedra at 3D points (debug views, and the projection test)."""
        core = self._core
        pts = np.atleast_2d(np.asarray(points_world, float))
        h = size_m / 2
        template = np.array([[h, 0, 0], [-h, 0, 0], [0, h, 0], [0, -h, 0], [0, 0, h], [0, 0, -h]])
        faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
        vertices = (template[None] + pts[:, None]).reshape(-1, 3)
        triangles = (faces[None] + (np.arange(len(pts)) * 6)[:, None, None]).reshape(-1, 3)
        node = self.root.attach_new_node(_mesh(core, vertices, triangles, colors=np.tile(rgba, (len(vertices), 1))))
        node.set_texture_off(20)
        node.set_light_off(20)
        node.set_two_sided(True)

    def close(self) -> None:
        if self._buffer is not None:
            self._engine.remove_window(self._buffer)
            self._buffer = None
            self.root.remove_node()

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- scene ------------------------------------------------------------------------------

    def _lens(self, cam: PinholeCamera) -> Any:
        core = self._core
        lens = core.PerspectiveLens()
        aspect = cam.fx_px / cam.fy_px
        # Measured on p3tinydisplay: its viewport spans (size - 0.5) pixels, and OpenCV puts pixel centres on
        # integers where GL puts them on half-integers. With both accounted for, small markers land within
        # 0.4 px of cv2.projectPoints (the remainder is the rasteriser's vertex snapping).
        span_x, span_y = cam.width_px - 0.5, (cam.height_px - 0.5) * aspect
        lens.set_film_size(span_x, span_y)
        lens.set_focal_length(cam.fx_px)
        lens.set_film_offset(span_x / 2 - (cam.cx_px + 0.5), (cam.cy_px + 0.5) * aspect - span_y / 2)
        lens.set_near_far(self.config.near_m, self.config.far_m)
        return lens

    def _build_world(self, track: Track, show_cones: bool) -> None:
        core = self._core
        spec = track.spec
        seed = self.config.texture_seed
        self._add_background(seed)

        # far ground in one flat colour; textured only on aprons beside the road, where it is seen up close
        ground_tex = textures.surface_texture(spec.ground, 1024, seed + 1)
        ground_rgba = np.r_[ground_tex.reshape(-1, 3).mean(axis=0)[::-1] / 255.0, 1.0]
        x0, y0, x1, y1 = track.bounds_m(margin_m=400.0)
        corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        ground = _mesh(core, np.c_[corners, np.zeros(4)], np.array([[0, 1, 2], [0, 2, 3]]),
                       colors=np.tile(ground_rgba, (4, 1)))
        self._decal(ground, 1, None)

        surface_tex = textures.surface_texture(spec.surface, 2048, seed + 2)
        margin_left, margin_right = spec.surface_margin_m
        for piece in (track.route, *track.branches):
            left = piece.boundary("left", margin_left)
            right = piece.boundary("right", margin_right)
            for left_part, right_part in _chunks(left, right, closed=piece.closed):
                self._decal(_strip_mesh(core, left_part, right_part), 3, surface_tex)
            apron_left = piece.boundary("left", margin_left + self.config.apron_m)
            apron_right = piece.boundary("right", margin_right + self.config.apron_m)
            for outer, inner in _chunks(apron_left, left, closed=piece.closed):
                self._decal(_strip_mesh(core, outer, inner), 2, ground_tex)
            for inner, outer in _chunks(right, apron_right, closed=piece.closed):
                self._decal(_strip_mesh(core, inner, outer), 2, ground_tex)

        for mark in _tyre_marks(core, track, np.random.default_rng(spec.seed)):
            self._decal(mark, 4, None, alpha=True)
        for inner, outer in track.curbs:
            self._decal(_curb_mesh(core, inner, outer), 5, None)
        paint = textures.surface_texture("paint", 256, seed + 3)
        for line, width in zip(track.lines, track.line_widths_m, strict=True):
            left, right = _offset_polyline(line, width / 2), _offset_polyline(line, -width / 2)
            for left_part, right_part in _chunks(left, right):
                self._decal(_strip_mesh(core, left_part, right_part, tile_m=1.0), 6, paint)
        if track.road_marks:
            self._decal(_polygons_mesh(core, track.road_marks), 6, paint)

        solids = self.root.attach_new_node("solids")
        if show_cones and track.cones:
            marking = spec.left if spec.left.kind == "cones" else spec.right
            positions = np.array([c.xy_m for c in track.cones])
            for cell in _spatial_groups(positions, _CHUNK_M):
                cones = solids.attach_new_node(_cones_mesh(core, positions[cell], marking.cone_base_m,
                                                           marking.cone_height_m))
                cones.set_texture_off(10)
        if track.barriers:
            wall_tex = self._texture_of(textures.tyre_wall_texture(seed + 4))
            for wall in track.barriers:
                for (part,) in _chunks(wall):
                    node = solids.attach_new_node(_wall_mesh(core, part, spec.barrier_height_m))
                    node.set_texture(wall_tex)
                    node.set_two_sided(True)
        blocks = np.zeros((0, 6))
        if track.barrier_blocks:
            blocks = np.array([_box_of(footprint, block.height_m)
                               for footprint, block in zip(track.barrier_blocks, spec.barrier_blocks, strict=True)])
            node = solids.attach_new_node(_boxes_mesh(core, blocks))
            node.set_texture(self._texture_of(textures.barrier_texture()))
            node.set_two_sided(True)
        self._track = track
        self._people: list[tuple[Any, Prop, Array]] = []
        self._lamps: list[tuple[Any, Prop, str]] = []
        for number, prop in enumerate(spec.props):
            self._add_prop(solids, track, prop, number)
        boxes = scenery_boxes(track, self.config.scenery_spacing_m, seed + 5)
        for k in range(_FACADES):
            mine = boxes[k::_FACADES]
            if len(mine):
                node = solids.attach_new_node(_boxes_mesh(core, mine))
                node.set_texture(self._texture_of(textures.facade_texture(seed + 100 + k)))
                node.set_two_sided(True)
        casters: list[tuple[Array, Array]] = [(boxes, np.zeros(len(boxes)))]
        trees = roadside_trees(track, self.config.trees_spacing_m, seed + 6)
        if len(trees):
            trunks = np.c_[trees[:, :2], np.zeros(len(trees)), trees[:, 2], trees[:, 2], trees[:, 3]]
            leafy = trees[:, 4] > 0
            crowns = np.c_[trees[leafy, :2], np.zeros(leafy.sum()), trees[leafy, 4], trees[leafy, 4],
                           0.8 * trees[leafy, 4]]
            for part, bottoms, colour in ((trunks, np.zeros(len(trunks)), (0.33, 0.25, 0.18)),
                                          (crowns, trees[leafy, 3], (0.3, 0.45, 0.2))):
                if len(part):
                    node = solids.attach_new_node(_boxes_mesh(core, part, bottoms))
                    node.set_texture_off(10)
                    node.set_color(*colour, 1.0)
                    node.set_two_sided(True)
                    casters.append((part, bottoms))
        if track.barrier_blocks:
            casters.append((blocks, np.zeros(len(blocks))))
        standing = [p for p in spec.props if p.kind != "person"]
        casters += [(np.array([self._prop_box(track, p)]), np.zeros(1)) for p in standing]
        if self.config.shadows and not self._overcast:
            self._add_shadows(casters)
        self._light(solids)

    def _prop_box(self, track: Track, prop: Prop) -> list[float]:
        """A prop as the box its shadow is cast from: the car's body; a sign's or a light's pole and head, as one
        thin box as tall as the prop."""
        foot, facing = track.prop_frame(prop, 0.0)
        width, depth, height = PROP_SIZES_M[prop.kind]
        across = facing + math.pi / 2
        if prop.kind == "car":
            return [float(foot[0]), float(foot[1]), across, width, depth, height]
        return [float(foot[0]), float(foot[1]), across, 0.3 if prop.kind == "traffic_light" else 0.6, 0.05, height]

    def _add_shadows(self, casters: list[tuple[Array, Array]]) -> None:
        """The casters' hard shadows as dark decals over every ground layer: a shadowed patch keeps the sky's light
        and loses the sun's."""
        core = self._core
        light = sun_direction(self.config.time_of_day_h, self.config.sun_azimuth_deg)
        polygons = [p for boxes, bottoms in casters if len(boxes) for p in shadow_polygons(boxes, bottoms, light)]
        if not polygons:
            return
        elevation, colour, ambient = lighting_for_time(self.config.time_of_day_h, self._overcast)
        sun_on_ground = float(np.mean(colour)) * math.sin(math.radians(max(elevation, 2.0)))
        darkness = sun_on_ground / (sun_on_ground + ambient)
        node = self.root.attach_new_node(_polygons_mesh(core, tuple(polygons)))
        node.set_texture_off(10)
        node.set_light_off(10)
        node.set_color(0.0, 0.0, 0.0, darkness)
        node.set_transparency(core.TransparencyAttrib.M_alpha)
        node.set_bin("background", 7)
        node.set_depth_write(False)
        node.set_depth_test(False)

    def set_time(self, time_s: float) -> None:
        """Move the scenario's props to where they are at a time of the run: people walking, lights' phases."""
        for node, prop, start in self._people:
            foot, _ = self._track.prop_frame(prop, time_s)
            node.set_pos(float(foot[0] - start[0]), float(foot[1] - start[1]), 0.0)
        for node, prop, colour in self._lamps:
            node.set_color_scale(*((1.0, 1.0, 1.0, 1.0) if prop.light_at(time_s) == colour else (0.2, 0.2, 0.2, 1.0)))

    def _add_prop(self, parent: Any, track: Track, prop: Prop, number: int) -> None:
        """One scenario prop, as the real one looks: a signal head on a pole, a sign, a person, the car."""
        core = self._core
        foot, facing = track.prop_frame(prop, 0.0)
        width, depth, height = PROP_SIZES_M[prop.kind]
        across = facing + math.pi / 2
        toward = np.array([math.cos(facing), math.sin(facing)])
        if prop.kind == "car":
            node = parent.attach_new_node(_boxes_mesh(core, np.array([[foot[0], foot[1], across, width, depth,
                                                                        height]])))
            node.set_texture(self._texture_of(textures.car_texture()))
            node.set_two_sided(True)
            return
        if prop.kind == "person":
            # legs, a torso and a head: the outline a people detector knows, not a box
            jacket = tuple(float(v) / 255 for v in textures.person_texture(number)[80, 32][::-1])
            person = parent.attach_new_node("person")
            side = np.array([math.cos(across), math.sin(across)])
            parts = [(foot - 0.1 * side, 0.0, 0.14, 0.85, (0.2, 0.18, 0.18)),
                     (foot + 0.1 * side, 0.0, 0.14, 0.85, (0.2, 0.18, 0.18)),
                     (foot, 0.85, 0.44, 0.62, jacket), (foot, 1.5, 0.2, 0.25, (0.75, 0.6, 0.5))]
            for xy, z, w_m, h_m, colour in parts:
                part = person.attach_new_node(_boxes_mesh(core, np.array([[xy[0], xy[1], across, w_m, 0.25, h_m]])))
                part.set_z(z)
                part.set_texture_off(10)
                part.set_color(*colour, 1.0)
                part.set_two_sided(True)
            self._people.append((person, prop, foot.copy()))
            return
        pole_top = 1.5 if prop.kind == "traffic_light" else height - 0.6
        pole = parent.attach_new_node(_boxes_mesh(core, np.array([[foot[0], foot[1], across, 0.05, 0.05, pole_top]])))
        pole.set_texture_off(10)
        pole.set_color(0.25, 0.25, 0.25, 1.0)
        if prop.kind == "speed_sign":
            centre = np.r_[foot + 0.03 * toward, height - 0.3]
            sign = parent.attach_new_node(_disc_mesh(core, centre, across, 0.3))
            sign.set_texture(self._texture_of(textures.speed_sign_texture(prop.value_kmh)))
            sign.set_two_sided(True)
            return
        head = parent.attach_new_node(_boxes_mesh(core, np.array([[foot[0], foot[1], across, width, depth,
                                                                    height - pole_top]])))
        head.set_z(pole_top)  # the head sits on the pole
        head.set_texture_off(10)
        head.set_color(0.08, 0.08, 0.08, 1.0)
        head.set_two_sided(True)
        lamps: tuple[tuple[str, float, tuple[float, float, float, float]], ...] = (
            ("red", height - 0.15, (1.0, 0.12, 0.08, 1.0)), ("green", height - 0.45, (0.15, 1.0, 0.45, 1.0)))
        for lamp_colour, z, rgba in lamps:
            centre = np.r_[foot + (depth / 2 + 0.01) * toward, z]
            lamp = parent.attach_new_node(_disc_mesh(core, centre, across, 0.1, rgba))
            lamp.set_texture_off(10)
            lamp.set_light_off(10)
            lamp.set_two_sided(True)
            self._lamps.append((lamp, prop, lamp_colour))

    def _add_background(self, seed: int) -> None:
        """A plain sky gradient above a thin textured band of trees at the horizon: cheap to fill."""
        core = self._core
        radius = self.config.background_radius_m
        lo, hi = textures.HORIZON_BAND_DEG
        band = self._background.attach_new_node(_cylinder_mesh(core, radius, lo, hi))
        band.set_texture(self._texture_of(textures.horizon_band(seed, overcast=self._overcast), wrap=False))
        elevations = np.array([hi, 12.0, 25.0, 45.0])
        colours = [np.r_[np.array(textures.sky_bgr(e, self._overcast))[::-1] / 255.0, 1.0] for e in elevations]
        for (e0, e1), (c0, c1) in zip(itertools.pairwise(elevations),
                                      itertools.pairwise(colours), strict=True):
            sky = self._background.attach_new_node(_cylinder_mesh(core, radius, e0, e1, (c0, c1)))
            sky.set_texture_off(10)
        self._background.set_bin("background", 0)
        self._background.set_depth_write(False)
        self._background.set_depth_test(False)
        self._background.set_light_off(1)
        self._background.set_two_sided(True)

    def _decal(self, geom_node: Any, order: int, image: Image | None, alpha: bool = False) -> None:
        core = self._core
        node = self.root.attach_new_node(geom_node)
        if image is not None:
            node.set_texture(self._texture_of(image))
        else:
            node.set_texture_off(10)
        node.set_bin("background", order)
        node.set_depth_write(False)
        node.set_depth_test(False)
        if alpha:
            node.set_transparency(core.TransparencyAttrib.M_alpha)
        self._light(node)

    def _texture_of(self, image: Image, wrap: bool = True) -> Any:
        """The Panda3D texture of an image, made once and shared by every node that shows it: a texture per
        track chunk took 1.8 GB for sdc-assen, and Panda3D does not give it back when the renderer closes."""
        key = (id(image), wrap)
        if key not in self._textures:
            self._textures[key] = (image, _texture(self._core, image, wrap))
        return self._textures[key][1]

    def _make_lights(self) -> tuple[Any, Any]:
        core = self._core
        _, colour, ambient_level = lighting_for_time(self.config.time_of_day_h, self._overcast)
        ambient = core.AmbientLight("sky")
        ambient.set_color(core.LColor(ambient_level, ambient_level, ambient_level, 1))
        sun = core.DirectionalLight("sun")
        sun.set_color(core.LColor(*colour, 1))
        sun.set_direction(core.LVector3(*sun_direction(self.config.time_of_day_h, self.config.sun_azimuth_deg)))
        return self.root.attach_new_node(ambient), self.root.attach_new_node(sun)

    def _light(self, node: Any) -> None:
        for light in self._lights:
            node.set_light(light)


# --- Panda3D plumbing ---------------------------------------------------------------------------

_PANDA: Any = None
_PIPE: Any = None


def _panda() -> Any:
    """Import panda3d.core with kartpilot's settings (once per process)."""
    global _PANDA
    if _PANDA is None:
        try:
            from panda3d import core
        except ImportError as exc:  # pragma: no cover - panda3d is a dependency
            raise RenderError("the simulator needs Panda3D (pip install panda3d)") from exc
        core.load_prc_file_data("kartpilot", _PRC)
        _PANDA = core
    return _PANDA


def _pipe() -> Any:
    global _PIPE
    if _PIPE is None:
        core = _panda()
        selection = core.GraphicsPipeSelection.get_global_ptr()
        selection.get_num_pipe_types()  # loads the display module named in the PRC
        kind = core.TypeRegistry.ptr().find_type("TinyOffscreenGraphicsPipe")
        pipe = selection.make_pipe(kind) if kind else None
        if pipe is None:
            raise RenderError("Panda3D's software renderer (p3tinydisplay) is not available")
        _PIPE = pipe
    return _PIPE


def _panda_matrix(core: Any, pose_world_cam: Array) -> Any:
    """Panda3D's camera looks along +y with z up; OpenCV's along +z with y down."""
    cv_from_panda = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    world_from_panda = pose_world_cam @ cv_from_panda
    return core.LMatrix4f(*world_from_panda.T.ravel().tolist())  # row vectors


_FORMAT: Any = None


def _format(core: Any) -> Any:
    global _FORMAT
    if _FORMAT is None:
        c = core
        array = c.GeomVertexArrayFormat()
        array.add_column(c.InternalName.get_vertex(), 3, c.Geom.NT_float32, c.Geom.C_point)
        array.add_column(c.InternalName.get_normal(), 3, c.Geom.NT_float32, c.Geom.C_normal)
        array.add_column(c.InternalName.get_color(), 4, c.Geom.NT_float32, c.Geom.C_color)
        array.add_column(c.InternalName.get_texcoord(), 2, c.Geom.NT_float32, c.Geom.C_texcoord)
        _FORMAT = c.GeomVertexFormat.register_format(c.GeomVertexFormat(array))
    return _FORMAT


def _mesh(core: Any, vertices: Array, triangles: NDArray[Any], normals: Array | None = None,
          colors: Array | None = None, uvs: Array | None = None) -> Any:
    """A GeomNode from NumPy arrays (N x 3 vertices, M x 3 triangle indices)."""
    c = core
    n = len(vertices)
    rows = np.zeros((n, 12), np.float32)
    rows[:, 0:3] = vertices
    rows[:, 3:6] = (0.0, 0.0, 1.0) if normals is None else normals
    rows[:, 6:10] = 1.0 if colors is None else colors
    if uvs is not None:
        rows[:, 10:12] = uvs
    vdata = c.GeomVertexData("mesh", _format(c), c.Geom.UH_static)
    vdata.unclean_set_num_rows(n)
    memoryview(vdata.modify_array(0)).cast("B")[:] = rows.tobytes()
    prim = c.GeomTriangles(c.Geom.UH_static)
    prim.set_index_type(c.Geom.NT_uint32)
    index = prim.modify_vertices()
    index.unclean_set_num_rows(triangles.size)
    memoryview(index).cast("B")[:] = np.ascontiguousarray(triangles, np.uint32).tobytes()
    geom = c.Geom(vdata)
    geom.add_primitive(prim)
    node = c.GeomNode("mesh")
    node.add_geom(geom)
    return node


def _texture(core: Any, image: Image, wrap: bool = True) -> Any:
    c = core
    h, w = image.shape[:2]
    tex = c.Texture("procedural")
    tex.setup_2d_texture(w, h, c.Texture.T_unsigned_byte, c.Texture.F_rgb)
    tex.set_ram_image(np.ascontiguousarray(image[::-1]).tobytes())  # Panda3D stores BGR, bottom row first
    tex.set_minfilter(c.SamplerState.FT_linear_mipmap_nearest)  # not trilinear: see the module's docstring
    tex.set_magfilter(c.SamplerState.FT_linear)
    mode = c.SamplerState.WM_repeat if wrap else c.SamplerState.WM_clamp
    tex.set_wrap_u(c.SamplerState.WM_repeat)
    tex.set_wrap_v(mode)
    return tex


def _interleave(first: Array, second: Array) -> Array:
    """Rows first[0], second[0], first[1], second[1], ...: the vertex order of a ribbon."""
    out = np.empty((2 * len(first), *np.shape(first)[1:]))
    out[0::2], out[1::2] = first, second
    return out


def _ribbon_triangles(pairs: int, facing_up: bool = True, base: int = 0) -> NDArray[np.intp]:
    """Triangle indices of a ribbon of ``pairs`` interleaved vertex pairs; ``facing_up`` winds them
    counter-clockwise seen from above the first edge's left side (ground strips), else the other way."""
    k = base + np.arange(pairs - 1) * 2
    if facing_up:
        return np.concatenate([np.stack([k, k + 1, k + 2], 1), np.stack([k + 1, k + 3, k + 2], 1)])
    return np.concatenate([np.stack([k, k + 2, k + 1], 1), np.stack([k + 1, k + 2, k + 3], 1)])


def _unit_tangents(line: Array) -> Array:
    d = np.gradient(line, axis=0)
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)


def _strip_mesh(core: Any, left: Array, right: Array, tile_m: float = textures.SURFACE_TILE_M,
                color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)) -> Any:
    """A ribbon between two polylines, textured in world coordinates (so overlaps match seamlessly)."""
    n = len(left)
    xy = _interleave(left, right)
    vertices = np.c_[xy, np.zeros(2 * n)]
    triangles = _ribbon_triangles(n)
    colors = np.tile(np.asarray(color, np.float32), (2 * n, 1))
    return _mesh(core, vertices, triangles, colors=colors, uvs=xy / tile_m)


_CHUNK_M = 12.0
_RENDER_STEP = 5  # draw every 5th sample: 25 cm chords, under a millimetre of error on a 25 m bend


def _chunks(*lines: Array, closed: bool = False) -> list[tuple[Array, ...]]:
    """Cut parallel sampled polylines into pieces of about _CHUNK_M (so pieces out of view are culled),
    keeping every _RENDER_STEP-th sample. Consecutive pieces share their end sample."""
    if closed:
        lines = tuple(np.vstack([line, line[:1]]) for line in lines)
    n = len(lines[0])
    keep = np.r_[np.arange(0, n - 1, _RENDER_STEP), n - 1]
    per_chunk = int(_CHUNK_M / (SAMPLE_SPACING_M * _RENDER_STEP))
    out = []
    for a in range(0, len(keep) - 1, per_chunk):
        idx = keep[a:a + per_chunk + 1]
        out.append(tuple(line[idx] for line in lines))
    return out


def _spatial_groups(points: Array, cell_m: float) -> list[NDArray[np.intp]]:
    keys = np.floor(points / cell_m).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    return [np.flatnonzero(inverse.ravel() == k) for k in range(int(inverse.max()) + 1)]


def _offset_polyline(line: Array, offset_m: float) -> Array:
    d = _unit_tangents(line)
    return line + offset_m * np.stack([-d[:, 1], d[:, 0]], axis=1)


def _curb_mesh(core: Any, inner: Array, outer: Array) -> Any:
    """Alternating red and white blocks, one metre each."""
    n = len(inner)
    block = max(1, round(1.0 / SAMPLE_SPACING_M))
    quads_v, quads_c, tris = [], [], []
    for b, start in enumerate(range(0, n - 1, block)):
        end = min(start + block, n - 1)
        quad = np.array([inner[start], outer[start], outer[end], inner[end]])
        base = 4 * b
        quads_v.append(np.c_[quad, np.zeros(4)])
        rgba = (0.85, 0.12, 0.1, 1.0) if b % 2 == 0 else (0.92, 0.92, 0.92, 1.0)
        quads_c.append(np.tile(rgba, (4, 1)))
        tris += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return _mesh(core, np.vstack(quads_v), np.asarray(tris), colors=np.vstack(quads_c))


def _tyre_marks(core: Any, track: Track, rng: np.random.Generator) -> list[Any]:
    """Dark, translucent pairs of arcs on the route: the false edges the thesis's lane finder met. A mesh per pair,
    in the order they are drawn: each is culled where no camera sees it (as one mesh, all of sdc-assen's 56,000
    triangles were transformed for every camera in every frame, a sixth of its drawing time)."""
    route = track.route
    marks = []
    for _ in range(track.spec.tyre_marks):
        i0 = int(rng.integers(0, len(route.s_m)))
        length = int(rng.uniform(4.0, 18.0) / SAMPLE_SPACING_M)
        idx = (np.arange(i0, i0 + length) % len(route.s_m)) if route.closed else np.arange(
            i0, min(i0 + length, len(route.s_m)))
        if len(idx) < 4:
            continue
        half = route.half_width_m[idx]
        drift = rng.uniform(-0.6, 0.6) * np.linspace(-1, 1, len(idx)) ** 2
        offset = rng.uniform(-0.6, 0.6) * half + drift * half * 0.3
        alpha = rng.uniform(0.25, 0.55)
        strips_v, strips_c, tris = [], [], []
        base = 0
        for wheel in (-0.5, 0.5):
            centre = route.xy_m[idx] + (offset + wheel)[:, None] * route.normal()[idx]
            left, right = _offset_polyline(centre, 0.1), _offset_polyline(centre, -0.1)
            n = len(centre)
            strips_v.append(np.c_[_interleave(left, right), np.zeros(2 * n)])
            fade = np.minimum(1.0, np.minimum(np.arange(n), np.arange(n)[::-1]) / 20.0)
            a = np.repeat(alpha * fade, 2)
            strips_c.append(np.c_[np.full((2 * n, 3), 0.08), a])
            tris.append(_ribbon_triangles(n, base=base))
            base += 2 * n
        marks.append(_mesh(core, np.vstack(strips_v), np.vstack(tris), colors=np.vstack(strips_c)))
    return marks


def _cone_template(base_m: float, height_m: float, segments: int = 16) -> tuple[Array, Array, Array, Array]:
    """One traffic cone: a square dark base and an orange body with a white band, with normals."""
    plate = 0.08 * height_m
    r0, r1 = 0.40 * base_m, 0.06 * base_m
    orange, white, dark = (1.0, 0.45, 0.05, 1.0), (0.95, 0.95, 0.95, 1.0), (0.15, 0.07, 0.04, 1.0)
    bands = [(0.0, 0.45, orange), (0.45, 0.7, white), (0.7, 1.0, orange)]
    verts: list[tuple[float, float, float]] = []
    norms: list[tuple[float, float, float]] = []
    cols: list[tuple[float, float, float, float]] = []
    tris: list[tuple[int, int, int]] = []
    angles = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    slope = math.atan2(r0 - r1, height_m - plate)
    for lo, hi, colour in bands:
        z = plate + np.array([lo, hi]) * (height_m - plate)
        r = r0 + (r1 - r0) * np.array([lo, hi])
        base = len(verts)
        for a in angles:
            for zi, ri in zip(z, r, strict=True):
                verts.append((ri * math.cos(a), ri * math.sin(a), zi))
                norms.append((math.cos(a) * math.cos(slope), math.sin(a) * math.cos(slope), math.sin(slope)))
                cols.append(colour)
        for k in range(segments):
            a0, a1 = base + 2 * k, base + 2 * ((k + 1) % segments)
            tris += [(a0, a1, a0 + 1), (a1, a1 + 1, a0 + 1)]
    h = base_m / 2
    base = len(verts)
    for x, y in ((-h, -h), (h, -h), (h, h), (-h, h)):
        verts.append((x, y, plate))
        norms.append((0.0, 0.0, 1.0))
        cols.append(dark)
    tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.asarray(verts), np.asarray(norms), np.asarray(cols), np.asarray(tris)


def _cones_mesh(core: Any, positions: Array, base_m: float, height_m: float) -> Any:
    verts, norms, cols, tris = _cone_template(base_m, height_m)
    n = len(positions)
    offsets = np.c_[positions, np.zeros(n)]
    all_v = (verts[None] + offsets[:, None]).reshape(-1, 3)
    all_t = (tris[None] + (np.arange(n) * len(verts))[:, None, None]).reshape(-1, 3)
    return _mesh(core, all_v, all_t, normals=np.tile(norms, (n, 1)), colors=np.tile(cols, (n, 1)))


def _wall_mesh(core: Any, line: Array, height_m: float, tile_m: float = 0.6) -> Any:
    n = len(line)
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(line, axis=0).T))]
    vertices = _interleave(np.c_[line, np.zeros(n)], np.c_[line, np.full(n, height_m)])
    uvs = _interleave(np.c_[s / tile_m, np.zeros(n)], np.c_[s / tile_m, np.ones(n)])
    d = _unit_tangents(line)
    normals = np.repeat(np.c_[-d[:, 1], d[:, 0], np.zeros(n)], 2, axis=0)
    return _mesh(core, vertices, _ribbon_triangles(n, facing_up=False), normals=normals, uvs=uvs)


def _cylinder_mesh(core: Any, radius_m: float, low_deg: float, high_deg: float,
                   colours: tuple[Array, Array] | None = None, segments: int = 96) -> Any:
    """A band of a cylinder around the origin between two elevations; u goes once around."""
    a = np.linspace(0, 2 * np.pi, segments + 1)
    ring = np.c_[radius_m * np.cos(a), radius_m * np.sin(a)]
    vertices = _interleave(np.c_[ring, np.full(segments + 1, radius_m * math.tan(math.radians(low_deg)))],
                           np.c_[ring, np.full(segments + 1, radius_m * math.tan(math.radians(high_deg)))])
    uvs = _interleave(np.c_[a / (2 * np.pi), np.zeros(segments + 1)], np.c_[a / (2 * np.pi), np.ones(segments + 1)])
    colors = None
    if colours is not None:
        colors = _interleave(np.tile(colours[0], (segments + 1, 1)), np.tile(colours[1], (segments + 1, 1)))
    return _mesh(core, vertices, _ribbon_triangles(segments + 1, facing_up=False), colors=colors, uvs=uvs)


def _polygons_mesh(core: Any, polygons: tuple[Array, ...]) -> Any:
    """Flat convex polygons on the ground (fans), textured in world coordinates at a metre a tile."""
    vertices, triangles = [], []
    base = 0
    for polygon in polygons:
        n = len(polygon)
        vertices.append(np.c_[polygon, np.zeros(n)])
        triangles += [[base, base + k, base + k + 1] for k in range(1, n - 1)]
        base += n
    xyz = np.vstack(vertices)
    tris = np.asarray(triangles)
    # wind every triangle counter-clockwise seen from above
    a, b, c = xyz[tris[:, 0], :2], xyz[tris[:, 1], :2], xyz[tris[:, 2], :2]
    cw = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) < 0
    tris[cw] = tris[cw][:, [0, 2, 1]]
    return _mesh(core, xyz, tris, uvs=xyz[:, :2])


def _disc_mesh(core: Any, centre: Array, across_yaw: float, radius: float,
               rgba: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0), segments: int = 24) -> Any:
    """An upright disc about ``centre`` (x, y, z) in the plane of the horizontal direction ``across_yaw`` and
    the vertical, textured with a square image's inscribed circle (u along ``across_yaw``, v up)."""
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    across = np.array([math.cos(across_yaw), math.sin(across_yaw), 0.0])
    rim = centre + radius * (np.cos(a)[:, None] * across + np.sin(a)[:, None] * np.array([0.0, 0.0, 1.0]))
    vertices = np.vstack([centre, rim])
    uvs = np.vstack([[0.5, 0.5], np.column_stack([0.5 + 0.5 * np.cos(a), 0.5 + 0.5 * np.sin(a)])])
    triangles = np.array([[0, 1 + k, 1 + (k + 1) % segments] for k in range(segments)])
    normal = np.cross(across, [0.0, 0.0, 1.0])
    return _mesh(core, vertices, triangles, normals=np.tile(normal, (len(vertices), 1)),
                 colors=np.tile(rgba, (len(vertices), 1)), uvs=uvs)


def _box_of(footprint: Array, height_m: float) -> list[float]:
    """A footprint rectangle (4 x 2, corners in order) as a box row ``x, y, yaw, width, depth, height``."""
    centre = footprint.mean(axis=0)
    edge = footprint[1] - footprint[0]
    width, depth = float(np.hypot(*edge)), float(np.hypot(*(footprint[2] - footprint[1])))
    return [float(centre[0]), float(centre[1]), math.atan2(edge[1], edge[0]), width, depth, height_m]


_FACADES = 12  # distinct facade textures, handed out to the scenery boxes in turn


def _boxes_mesh(core: Any, boxes: Array, bottoms_m: Array | None = None) -> Any:
    """Boxes (rows ``x, y, yaw, width, depth, height``, standing from ``bottoms_m`` up, the ground by default) with
    four textured sides and a roof; each side's texture spans the side once."""
    bottoms = np.zeros(len(boxes)) if bottoms_m is None else np.asarray(bottoms_m, float)
    vertices: list[list[float]] = []
    normals: list[Array] = []
    uvs: list[list[float]] = []
    triangles: list[list[int]] = []
    for (x, y, yaw, width, depth, height), z0 in zip(boxes, bottoms, strict=True):
        c, s = math.cos(yaw), math.sin(yaw)
        footprint = [(-width / 2, -depth / 2), (width / 2, -depth / 2), (width / 2, depth / 2), (-width / 2, depth / 2)]
        corners = np.array([[x + dx * c - dy * s, y + dx * s + dy * c] for dx, dy in footprint])
        for k in range(4):
            a, b = corners[k], corners[(k + 1) % 4]
            edge = b - a
            normal = np.array([edge[1], -edge[0], 0.0]) / max(float(np.hypot(*edge)), 1e-9)
            base = len(vertices)
            vertices += [[*a, z0], [*b, z0], [*b, z0 + height], [*a, z0 + height]]
            normals += [normal] * 4
            uvs += [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
            triangles += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        base = len(vertices)
        vertices += [[*p, z0 + height] for p in corners]
        normals += [np.array([0.0, 0.0, 1.0])] * 4
        uvs += [[0.0, 0.0], [0.2, 0.0], [0.2, 0.2], [0.0, 0.2]]
        triangles += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return _mesh(core, np.array(vertices), np.array(triangles), normals=np.array(normals), uvs=np.array(uvs))

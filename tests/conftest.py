"""Shared fixtures: where the real data lives, and synthetic scenes with known geometry."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from kartpilot.core.camera import PinholeCamera, StereoRig
from kartpilot.core.geometry import mount_pose

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
TRACKS = Path(__file__).resolve().parents[1] / "src" / "kartpilot" / "sim" / "tracks"


# the SDC kart's centre camera: 60 cm above the road, 1.2 m ahead of the rear axle, pitched 12 degrees down
KART = PinholeCamera(480.0, 480.0, 319.5, 239.5, 640, 480, pose_body_cam=mount_pose(1.2, 0.0, 0.6, pitch_down_deg=12.0))


def road_texture(seed: int, size_px: int = 4000) -> np.ndarray:
    """A square of smoothed noise, a road's texture for :func:`road_view`."""
    noise = np.random.default_rng(seed).uniform(0, 255, (size_px, size_px)).astype(np.float32)
    texture = cv2.GaussianBlur(noise, (0, 0), 2.0)
    return cv2.normalize(texture, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def road_view(texture: np.ndarray, body_pose: np.ndarray, metres_per_px: float) -> np.ndarray:
    """The kart camera's view of a flat textured road (texture pixel (u, v) at x = u * res - 5, y = v * res - 20
    on the ground), with the rear axle at ``body_pose``."""
    cam_from_world = np.linalg.inv(body_pose @ KART.pose_body_cam_array)
    ground_to_image = KART.matrix @ cam_from_world[:3][:, [0, 1, 3]]
    texture_to_ground = np.array([[metres_per_px, 0.0, -5.0], [0.0, metres_per_px, -20.0], [0.0, 0.0, 1.0]])
    return cv2.warpPerspective(texture, ground_to_image @ texture_to_ground, (640, 480), flags=cv2.INTER_LINEAR)


def png_grey(image: np.ndarray) -> np.ndarray:
    """A BGR image in grey as a recording's PNG reads back with ``cv2.IMREAD_GRAYSCALE``: libpng's integer
    conversion (its weights 9797, 19234 and 3737 over 2**15, truncated), which is not ``cv2.cvtColor``'s by a level
    on about half the pixels. Equal to the PNG round trip on every one of the 2**24 colours
    (``tests/test_conftest_helpers.py``), without encoding and decoding a PNG (a tenth of a place test's time)."""
    b, g, r = (image[..., k].astype(np.uint32) for k in range(3))
    return ((9797 * r + 19234 * g + 3737 * b) >> 15).astype(np.uint8)


class GreyFrames:
    """A sink that keeps one camera's frames, grey, as a simulated drive draws them: a test that builds places from
    a drive, or queries them, needs its frames, not a recording of them (writing each as PNG to disk and reading it
    back was a fifth of such a test's time). :meth:`posed` gives them with the drive's true camera poses, as a
    recording's ``posed_frames`` does, the same grey images."""

    def __init__(self, camera: str) -> None:
        self.camera = camera
        self.frames: list[tuple[int, np.ndarray]] = []

    def write_frames(self, frames) -> None:
        image = frames.images.get(self.camera)
        if image is not None:
            self.frames.append((frames.stamp_ns, png_grey(image)))

    def send(self, command) -> None:
        pass

    def write_outputs(self, stamp_ns, outputs) -> None:
        pass

    def posed(self, truth):
        """(stamp_ns, grey image, pose_world_cam) of each frame kept, its pose the truth's at its stamp."""
        stamps_ns = np.round(np.asarray(truth.stamps_s) * 1e9)
        for stamp_ns, image in self.frames:
            index = int(np.argmin(np.abs(stamps_ns - stamp_ns)))
            assert abs(stamps_ns[index] - stamp_ns) < 1e6, "a frame without its true pose"
            yield stamp_ns, image, truth.poses[index]


class SteppedClock:
    """A monotonic clock in nanoseconds that moves only when a test advances it."""

    def __init__(self) -> None:
        self.ns = 0

    def __call__(self) -> int:
        return self.ns

    def advance(self, seconds: float) -> None:
        self.ns += round(seconds * 1e9)


def track_starting_at(folder: Path, name: str, start_s_m: float) -> str:
    """A built-in track's file as it is, with its start moved ``start_s_m`` along its route: a closed-loop drive
    through the stretch a test is about, without the metres before it. Returns the file's path."""
    spec = yaml.safe_load((TRACKS / f"{name}.yaml").read_text())
    spec["start_s_m"] = start_s_m
    path = folder / f"{name}-from-{start_s_m:g}m.yaml"
    path.write_text(yaml.safe_dump(spec))
    return str(path)


def subcommands(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, argparse.ArgumentParser]:
    """Every leaf subcommand of ``parser`` by its words (``"calibrate ground"``), with its own parser."""
    found: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found |= subcommands(sub, f"{prefix} {name}".strip())
    return found or {prefix: parser}


def data_path(*parts: str) -> Path:
    """A path under ../shared/data, or skip the test with the reason."""
    path = DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not present: {path} (see ../shared/data/README.md)")
    return path


def pytest_configure(config: pytest.Config) -> None:
    """Under ``make test`` each worker is one process per core: OpenCV's and the BLAS's own thread pools in every
    worker would only fight over the same cores (the mono drive's test took 136 s of CPU for 94 s of wall time, and
    112 s with one thread each: a sixth of the suite's CPU time spent on contention). A single process (a test run
    alone, or ``-n 0``) keeps the libraries' defaults."""
    workers = getattr(config, "workerinput", {}).get("workercount", 1)
    if workers > 1:
        from threadpoolctl import threadpool_limits

        cv2.setNumThreads(1)
        threadpool_limits(1)


PROFILE = Path(__file__).resolve().parents[1] / "docs" / "results" / "suite_profile.json"
"""The suite's last measured profile (``benchmarks/suite_profile.py``): its slowest tests and their seconds."""


def _module_seconds() -> dict[str, float]:
    """Each module's seconds in the measured profile (its tests' sum), by its path from the repository; none where
    the profile is missing or unreadable (the slow modules then start first, in their order)."""
    try:
        modules = json.loads(PROFILE.read_text(encoding="utf-8"))["modules"]
        return {str(k): float(v) for k, v in modules.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The longest modules first, then the other modules that hold slow tests, then the rest: ``make test`` gives
    each worker a module at a time, and a long one started last keeps one worker busy minutes after the other has
    finished. "Longest" is as the committed profile measured them (the longest first: each worker then ends with
    short modules), so the order follows the suite as it is measured again. A slow module the profile has not
    measured yet goes first: started last, it could be the longest."""
    root = Path(str(config.rootpath))
    measured = _module_seconds()
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}

    def order(item: pytest.Item) -> tuple[int, float]:
        module = item.path.relative_to(root).as_posix() if item.path.is_relative_to(root) else str(item.path)
        if module in measured:
            return (0, -measured[module])
        return (-1, 0.0) if item.path in slow else (2, 0.0)  # a new slow module, not measured yet, may be long

    items.sort(key=order)  # stable: each module's own order stays


@pytest.fixture
def rig() -> StereoRig:
    """A small-kart-like rectified rig: 960x540, f 743 px, 14 cm baseline."""
    return StereoRig(PinholeCamera(743.0, 743.0, 479.5, 269.5, 960, 540), 0.14)


@pytest.fixture
def scene_points() -> np.ndarray:
    """300 points spread 2 to 30 m in front of the camera."""
    rng = np.random.default_rng(7)
    depth = rng.uniform(2.0, 30.0, 300)
    x = rng.uniform(-0.5, 0.5, 300) * depth
    y = rng.uniform(-0.25, 0.3, 300) * depth
    return np.stack([x, y, depth], axis=1)

"""``kartpilot eval detect`` and ``kartpilot eval lanes``: kartpilot scored on a team's own labelled frames, with
the matching, act windows and tables the docs' figures come from (:mod:`kartpilot.eval.detection`,
:mod:`kartpilot.eval.lanes`)."""

from __future__ import annotations

import argparse
import functools
from dataclasses import replace
from pathlib import Path

from kartpilot.behaviour.events import ACTED_ON, BehaviourConfig, act_window
from kartpilot.calibration.rig import load_rig
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError, DataError
from kartpilot.core.files import write_json_atomic, write_text_atomic
from kartpilot.core.types import Image
from kartpilot.core.vehicle import get_vehicle
from kartpilot.eval.detection import read_labels, score_detections
from kartpilot.eval.lanes import read_lane_labels, score_lanes
from kartpilot.perception.detect import DetectorConfig, ObjectDetector
from kartpilot.perception.lanes import detect_lanes
from kartpilot.perception.road_marks import camera_for_image
from kartpilot.runtime.config import load_stack_config
from kartpilot.sensors.base import read_image

__all__ = ["eval_detect", "eval_lanes", "rig_for_images"]


def _class_map(text: str | None) -> dict[str, str]:
    """``THEIRS=OURS,...`` (``THEIRS=`` leaves the class out)."""
    mapping = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        if "=" not in item:
            raise ConfigError(f"--class-map {text!r}: expected THEIRS=OURS[,THEIRS=OURS...]")
        theirs, ours = (part.strip() for part in item.split("=", 1))
        mapping[theirs] = ours
    return mapping


def rig_for_images(values: list[str] | None) -> tuple[PinholeCamera | None, list[tuple[str, PinholeCamera]]]:
    """``--rig`` given as ``RIG`` (every image) or ``PREFIX=RIG`` (the images whose name starts with ``PREFIX``):
    the default centre camera, and the prefixed ones, longest prefix first."""
    default, prefixed = None, []
    for value in values or []:
        prefix, _, path = value.rpartition("=") if "=" in value else ("", "", value)
        camera = load_rig(path).camera("center")
        if prefix:
            prefixed.append((prefix, camera))
        elif default is None:
            default = camera
        else:
            raise ConfigError("--rig: give one rig for every image, and PREFIX=RIG for the others")
    return default, sorted(prefixed, key=lambda p: -len(p[0]))


def _camera_of(name: str, image: Image, default: PinholeCamera, prefixed: list[tuple[str, PinholeCamera]]
               ) -> PinholeCamera:
    camera = next((c for prefix, c in prefixed if name.startswith(prefix)), default)
    try:
        return camera_for_image(camera, image.shape[1], image.shape[0])
    except ConfigError as exc:
        raise ConfigError(f"{name}: {exc}") from None


def _image_of(frames: Path, name: str) -> Path:
    """The frame a label names: its path under the frames' folder, or (a YOLO folder names stems) the one file
    with that stem."""
    path = frames / name
    if path.is_file():
        return path
    found = sorted(p for p in frames.rglob(f"{Path(name).name}.*") if p.is_file() and p.suffix.lower() != ".txt")
    if len(found) == 1:
        return found[0]
    raise DataError(f"the labelled image {name} is not in {frames}" if not found
                    else f"the labelled image {name} could be any of {', '.join(str(p) for p in found[:3])}")


def _write(args: argparse.Namespace, table: str, payload: dict[str, object]) -> None:
    print(table)
    if args.out:
        write_text_atomic(args.out, table + "\n")
        print(f"table written to {args.out}")
    if args.json:
        write_json_atomic(args.json, payload)
        print(f"scores written to {args.json}")


def eval_detect(args: argparse.Namespace) -> int:
    """The detectors on each labelled frame, scored against the labels: per class, what was labelled, what of it
    concerns the kart, what was found, the states read, and the false alarms; each miss and false alarm listed."""
    frames = Path(args.frames)
    if not frames.is_dir():
        raise DataError(f"the frames' folder {frames} is not a folder")
    stack = load_stack_config(args.config) if args.config else None
    base = stack.lane_policy.detector if stack is not None else DetectorConfig()
    config = replace(base, detector=args.detector or base.detector, classes=args.classes or base.classes)
    behaviour = stack.lane_policy.behaviour if stack is not None else BehaviourConfig()
    default, prefixed = rig_for_images(args.rig)
    default = default or get_vehicle("sdc-kart").camera("center")

    @functools.lru_cache(maxsize=4)
    def image(name: str) -> Image:
        return read_image(_image_of(frames, name))

    labels = read_labels(args.labels, lambda stem: image(stem).shape[1::-1], _class_map(args.class_map))
    found, cameras = {}, {}
    for name in labels:
        picture = image(name)
        cameras[name] = _camera_of(name, picture, default, prefixed)
        # each labelled image on its own: nothing tracked from one to the next
        found[name] = ObjectDetector(config, cameras[name])(picture)
    windows = {label: act_window(label, behaviour) for label in ACTED_ON}
    score = score_detections(found, labels, cameras.__getitem__, windows, args.slack)
    _write(args, score.table(), {**score.to_json(), "act_windows_m": windows, "slack_px": args.slack})
    for miss in score.misses:
        where = f", {miss['ahead_m']} m ahead" if miss["ahead_m"] == miss["ahead_m"] else ""
        print(f"  missed: {miss['label']} in {miss['image']}{where}"
              + ("" if miss["concerns"] else " (not the kart's concern)"))
    for alarm in score.false_alarms:
        print(f"  false alarm: {alarm['label']} {alarm['state']} in {alarm['image']} at {alarm['distance_m']} m")
    return 0


def eval_lanes(args: argparse.Namespace) -> int:
    """The lane finder on each labelled frame, scored against its boundary points: per labelled row, the share
    within ``--within`` pixels and the median error."""
    frames = Path(args.frames)
    if not frames.is_dir():
        raise DataError(f"the frames' folder {frames} is not a folder")
    lanes = load_stack_config(args.config, args.preset).lane_policy.lanes
    labels = read_lane_labels(args.labels)
    observations = {name: detect_lanes(read_image(_image_of(frames, name)), lanes) for name in labels}
    score = score_lanes(observations, labels, args.within)
    _write(args, score.table(), score.to_json())
    print(f"both boundaries found in {score.both_found} of {len(labels)} labelled frames")
    return 0

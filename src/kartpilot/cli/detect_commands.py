"""``kartpilot detect``: the event's objects (traffic lights, speed signs, stop lines, zebras, people, a car, barriers,
a parking bay) in an image, a folder, a video or a recording, to CSV, with optional overlays."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from kartpilot.calibration.rig import load_rig
from kartpilot.cli.values import report_left_out
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import ConfigError, DataError
from kartpilot.core.files import write_csv_atomic
from kartpilot.core.vehicle import get_vehicle
from kartpilot.perception.continuity import with_scene_starts
from kartpilot.perception.detect import DetectorConfig, ObjectDetector
from kartpilot.perception.objects import Detection
from kartpilot.perception.road_marks import camera_for_image
from kartpilot.record.replay import VIDEO_SUFFIXES, open_frames
from kartpilot.runtime.config import load_stack_config

__all__ = ["DETECT_COLUMNS", "detect", "draw_detections"]

DETECT_COLUMNS = ("frame", "file", "class", "x1", "y1", "x2", "y2", "confidence", "value", "distance_m", "lateral_m",
                  "track_id", "source", "new_scene")
"""One row per detection: the frame's index and file, the class, the box (left, top, right, bottom, pixels), the
confidence, the value (a light's colour, a sign's limit in km/h, a person's place against a crossing, a bay's free
length in metres), where it stands on the ground (metres ahead and to the left), its track id, which detector
found it, and whether a new scene starts at this frame. A frame with nothing in it has one row with no class."""

_COLOURS = {"traffic_light": (0, 200, 255), "speed_sign": (0, 0, 255), "stop_line": (255, 255, 255),
            "crosswalk": (255, 255, 0), "person": (255, 0, 255), "car": (255, 128, 0), "barrier": (0, 0, 180),
            "parking_bay": (0, 255, 0)}


def draw_detections(image: np.ndarray, detections: list[Detection]) -> np.ndarray:
    """The image with each detection's box, label, state, distance and track id."""
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    for d in detections:
        colour = _COLOURS.get(d.label, (200, 200, 200))
        left, top, right, bottom = (round(v) for v in d.box_px)
        cv2.rectangle(canvas, (left, top), (right, bottom), colour, 2)
        text = f"{d.label}{' ' + d.state if d.state else ''} #{d.track_id}"
        if math.isfinite(d.distance_m):
            text += f" {d.distance_m:.1f} m"
        cv2.putText(canvas, text, (left, max(top - 4, 10)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
    return canvas


def _camera(args: argparse.Namespace) -> PinholeCamera:
    """The centre camera whose mount places the objects: the rig's, else the real kart's model."""
    if args.rig:
        return load_rig(args.rig).camera("center")
    return get_vehicle("sdc-kart").camera("center")


def detect(args: argparse.Namespace) -> int:
    """Objects per frame to CSV, one row per object (a frame with none has one row with an empty label)."""
    # the detector's settings from the stack's YAML (lane_policy.detector: the same file a drive takes), the
    # command line's over them
    base = load_stack_config(args.config).lane_policy.detector if args.config else DetectorConfig()
    config = replace(base, detector=args.detector or base.detector, classes=args.classes or base.classes,
                     people=not args.no_people)
    camera = _camera(args)
    detector = ObjectDetector(config, camera)
    left_out: list[str] = []
    kind, frames = open_frames(args.input, left_out=left_out)
    overlay = Path(args.overlay) if args.overlay else None
    video = None
    if overlay is not None and overlay.suffix.lower() not in VIDEO_SUFFIXES:
        overlay.mkdir(parents=True, exist_ok=True)
    rows: list[list[object]] = []
    counts: dict[str, int] = {}
    frames_seen = 0
    try:
        for frame_set, new_scene in with_scene_starts(frames, args.independent):
            image = frame_set.images["center"]
            if kind == "folder":  # another camera's photo among a folder's is left out as an unreadable one is
                try:
                    camera_for_image(camera, image.shape[1], image.shape[0])
                except ConfigError as exc:
                    left_out.append(f"{frame_set.name}: {exc}")
                    continue
            if new_scene:
                detector.reset()
            found = detector(image)
            frames_seen += 1
            head: list[object] = [frame_set.index, frame_set.name]
            if not found:
                rows.append([*head, "", "", "", "", "", "", "", "", "", "", "", int(new_scene)])
            for d in found:
                counts[d.label] = counts.get(d.label, 0) + 1
                rows.append([*head, d.label, *(f"{v:.1f}" for v in d.box_px), f"{d.confidence:.3f}", d.state,
                             f"{d.distance_m:.2f}" if math.isfinite(d.distance_m) else "",
                             f"{d.lateral_m:.2f}" if math.isfinite(d.lateral_m) else "", d.track_id, d.source,
                             int(new_scene)])
            if overlay is not None:
                drawn = draw_detections(image, found)
                if overlay.suffix.lower() in VIDEO_SUFFIXES:
                    from kartpilot.record.video import VideoFile

                    if video is None:
                        video = VideoFile(overlay, 30.0, (drawn.shape[1], drawn.shape[0]))
                    video.write(drawn)
                else:
                    cv2.imwrite(str(overlay / f"{frame_set.index:06d}.png"), drawn)
    finally:
        if video is not None:
            video.close()
    if frames_seen == 0 and left_out:
        raise DataError(f"no image in {args.input} could be used (the first: {left_out[0]})")
    write_csv_atomic(args.out, DETECT_COLUMNS, rows)
    summary = ", ".join(f"{n} {label}" for label, n in sorted(counts.items())) or "nothing"
    print(f"{frames_seen} frames ({kind}): {summary} -> {args.out}")
    return report_left_out(left_out, args.out)

"""Scoring a detector against a team's own labelled frames: which labelled things it found, which of those concern
the kart, whether it read their state, and what it reported that is not there.

The labels are read from the common formats (:func:`read_labels`):

- **kartpilot JSON**: ``{"images": {"IMAGE": [{"label": CLASS, "box": [left, top, right, bottom], "state": ...}]}}``,
  the image's path relative to the frames' folder; ``state`` (optional) is a light's colour or a sign's value.
- **COCO JSON** (what CVAT, Label Studio and Roboflow export): ``images`` (``id``, ``file_name``), ``annotations``
  (``image_id``, ``category_id``, ``bbox`` as left, top, width, height) and ``categories`` (``id``, ``name``);
  an annotation's ``attributes.state`` is its state.
- **YOLO** (what labelImg and Roboflow export): a folder of one ``.txt`` per image, a line per box
  ``CLASS_ID CX CY W H`` (fractions of the image's size), and ``classes.txt`` beside them (a class name per line,
  its line number the id).

A label's class is kartpilot's own (:data:`CLASSES`) or is mapped to one (``class_map``: a team's ``red_light``
to ``traffic_light``, say); a class that is neither is an error naming it. A box that matches a detection of the
same class (overlapping by a third, or either's centre inside the other grown by ``slack_px``, a hand-drawn label's
accuracy) is found; each detection matches one label at most. A labelled thing on the ground *concerns* the kart
where it stands within the kart's act window for its class (metres ahead of the rear axle, from the rules:
:func:`kartpilot.behaviour.events.act_window`) and reaches into the zone its detector watches (a car: the kart's
corridor; people and barriers: the spectators' fence; stop lines and zebras: where road marks are sought): the
detectors leave out by design what lies beyond, so a miss there is not a fault. A light always concerns the kart;
a sign does where its size puts it inside its window.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kartpilot.calibration.ground import ground_points
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import DataError
from kartpilot.core.files import read_json_file, read_text_file
from kartpilot.perception.objects import CLASSES, Detection, box_iou
from kartpilot.perception.obstacles import ObstacleConfig
from kartpilot.perception.road_marks import RoadMarkConfig
from kartpilot.perception.signals import SignalConfig

__all__ = ["ON_GROUND", "ClassScore", "DetectionScore", "Label", "boxes_match", "concerns", "read_labels",
           "score_detections", "watched_zone_m"]

ON_GROUND = ("car", "person", "barrier", "stop_line", "crosswalk", "parking_bay")
"""The classes placed by where their box meets the ground."""

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class Label:
    """One labelled thing in one image: its class (kartpilot's), its box (left, top, right, bottom, pixels) and
    its state where the label gives one (a light's colour, a sign's value)."""

    label: str
    box_px: Box
    state: str = ""


def boxes_match(box: Box | list[float], label_box: Box | list[float], slack_px: float = 0.0) -> bool:
    """The same object: boxes overlapping by a third, or one's centre inside the other grown by ``slack_px`` (a
    hand-drawn label's accuracy; a far object's box is a few pixels; a light's label may box the head only)."""
    a, b = tuple(float(v) for v in box), tuple(float(v) for v in label_box)

    def inside(c: tuple[float, float], r: tuple[float, ...]) -> bool:
        return r[0] - slack_px <= c[0] <= r[2] + slack_px and r[1] - slack_px <= c[1] <= r[3] + slack_px

    return (box_iou(a, b) >= 0.3 or inside(((a[0] + a[2]) / 2, (a[1] + a[3]) / 2), b)  # type: ignore[arg-type]
            or inside(((b[0] + b[2]) / 2, (b[1] + b[3]) / 2), a))


def watched_zone_m(label: str) -> float:
    """How far either side of the kart's line the detector of a class on the ground watches."""
    obstacles, marks = ObstacleConfig(), RoadMarkConfig()
    return {"car": obstacles.corridor_half_width_m, "stop_line": marks.search_half_width_m,
            "crosswalk": marks.search_half_width_m}.get(label, obstacles.max_lateral_m)


def concerns(label: str, box: Box | list[float], camera: PinholeCamera, window_m: tuple[float, float],
             slack_px: float = 0.0) -> tuple[bool, float, float]:
    """Whether a labelled thing concerns the kart, and where its box's foot stands (metres ahead of the rear axle,
    metres left; NaN where not placed): see the module's note. A sign is placed by its size (the label's, grown by
    ``slack_px``: the nearest it may be)."""
    if label == "speed_sign":
        size_px = max(box[2] - box[0], box[3] - box[1]) + slack_px
        ahead = camera.fx_px * SignalConfig().sign_diameter_m / size_px + float(camera.pose_body_cam_array[0, 3])
        return bool(ahead <= window_m[1]), float(ahead), math.nan
    if label not in ON_GROUND:
        return True, math.nan, math.nan
    foot = ground_points(camera, np.array([[box[0], box[3]], [box[2], box[3]]], np.float64))
    ahead, left = (float(v) for v in foot.mean(axis=0))
    side = watched_zone_m(label)
    beside = foot[:, 1].min() > side or foot[:, 1].max() < -side  # wholly to one side of the zone
    return bool(window_m[0] <= ahead <= window_m[1] and not beside), ahead, left


@dataclass
class ClassScore:
    """One class's counts over the labelled images."""

    labelled: int = 0
    concerning: int = 0
    found: int = 0
    found_concerning: int = 0
    state_right: int = 0
    false_alarms: int = 0


@dataclass
class DetectionScore:
    """What :func:`score_detections` counted: per class, and each miss and false alarm with where it was."""

    classes: dict[str, ClassScore] = field(default_factory=dict)
    misses: list[dict[str, Any]] = field(default_factory=list)
    false_alarms: list[dict[str, Any]] = field(default_factory=list)
    images: int = 0

    def to_json(self) -> dict[str, Any]:
        return {"images": self.images, "classes": {k: vars(v) for k, v in sorted(self.classes.items())},
                "misses": self.misses, "false_alarms": self.false_alarms}

    def table(self) -> str:
        """The Markdown table the docs show for real frames (``docs/detection.md``)."""
        lines = ["| class | labelled (real) | of them concerning the kart | found of those | found of all | "
                 "state right | false alarms (labelled images) |", "|---|---|---|---|---|---|---|"]
        for name, row in sorted(self.classes.items()):
            lines.append(f"| {name} | {row.labelled} | {row.concerning} | {row.found_concerning} | {row.found} | "
                         f"{row.state_right} | {row.false_alarms} |")
        return "\n".join(lines)


def score_detections(found: Mapping[str, list[Detection]], labels: Mapping[str, list[Label]],
                     cameras: Callable[[str], PinholeCamera], windows_m: Mapping[str, tuple[float, float]],
                     slack_px: float = 5.0) -> DetectionScore:
    """Score the detections of each labelled image (``found``, by the labels' image names) against its labels.
    ``cameras(name)``: the camera (its mount, at the image's size) that places that image's things on the ground;
    ``windows_m``: each class's act window; ``slack_px``: the labels' accuracy."""
    score = DetectionScore(images=len(labels))
    for name, objects in labels.items():
        detections = found.get(name, [])
        camera = cameras(name)
        used: set[int] = set()
        for obj in objects:
            row = score.classes.setdefault(obj.label, ClassScore())
            row.labelled += 1
            concern, ahead, left = concerns(obj.label, obj.box_px, camera, windows_m.get(obj.label, (0.0, math.inf)),
                                            slack_px)
            row.concerning += int(concern)
            hit = next((k for k, d in enumerate(detections) if k not in used and d.label == obj.label
                        and boxes_match(d.box_px, obj.box_px, slack_px)), None)
            if hit is None:
                score.misses.append({"image": name, "label": obj.label, "height_px": obj.box_px[3] - obj.box_px[1],
                                     "concerns": concern, "ahead_m": round(ahead, 1), "left_m": round(left, 1)})
                continue
            used.add(hit)
            row.found += 1
            row.found_concerning += int(concern)
            row.state_right += int(detections[hit].state == (obj.state or detections[hit].state))
        for k, d in enumerate(detections):
            if k not in used:
                score.classes.setdefault(d.label, ClassScore()).false_alarms += 1
                score.false_alarms.append({"image": name, "label": d.label, "state": d.state,
                                           "box": [round(v) for v in d.box_px], "distance_m": round(d.distance_m, 1)})
    return score


# --- reading labels ---------------------------------------------------------------------------------------------

def _class(name: str, class_map: Mapping[str, str], where: str) -> str:
    label = class_map.get(name, name)
    if label not in CLASSES:
        raise DataError(f"{where}: the class {name!r} is none of kartpilot's ({', '.join(CLASSES)}); map it to one "
                        "(--class-map THEIRS=OURS) or leave it out (--class-map THEIRS=)")
    return label


def _box(values: Iterable[Any], where: str) -> Box:
    try:
        box = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise DataError(f"{where}: a box must be four numbers") from None
    if len(box) != 4 or not all(math.isfinite(v) for v in box) or box[2] <= box[0] or box[3] <= box[1]:
        raise DataError(f"{where}: a box must be four finite numbers, left < right and top < bottom, got {box}")
    return box


def _kartpilot_json(data: dict[str, Any], path: Path, class_map: Mapping[str, str]) -> dict[str, list[Label]]:
    images = data["images"]
    if not isinstance(images, dict):
        raise DataError(f"{path}: 'images' must map each image's name to its list of objects")
    labels: dict[str, list[Label]] = {}
    for name, objects in images.items():
        if not isinstance(objects, list):
            raise DataError(f"{path}: image {name!r}: a list of objects is expected")
        kept = []
        for k, obj in enumerate(objects):
            where = f"{path}: {name}, object {k + 1}"
            if not isinstance(obj, dict) or "label" not in obj or "box" not in obj:
                raise DataError(f"{where}: an object needs 'label' and 'box'")
            if class_map.get(obj["label"], obj["label"]) == "":
                continue
            kept.append(Label(_class(str(obj["label"]), class_map, where), _box(obj["box"], where),
                              str(obj.get("state", ""))))
        labels[str(name)] = kept
    return labels


def _coco_json(data: dict[str, Any], path: Path, class_map: Mapping[str, str]) -> dict[str, list[Label]]:
    try:
        names = {int(c["id"]): str(c["name"]) for c in data["categories"]}
        files = {int(im["id"]): str(im["file_name"]) for im in data["images"]}
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{path}: a COCO file's categories and images need 'id', 'name' and 'file_name' ({exc})") \
            from None
    labels: dict[str, list[Label]] = {name: [] for name in files.values()}
    for k, ann in enumerate(data.get("annotations", [])):
        where = f"{path}: annotation {k + 1}"
        try:
            image, category, (x, y, w, h) = files[int(ann["image_id"])], names[int(ann["category_id"])], ann["bbox"]
        except (KeyError, TypeError, ValueError):
            raise DataError(f"{where}: needs an 'image_id' and a 'category_id' the file defines, and a 'bbox' of "
                            "left, top, width, height") from None
        if class_map.get(category, category) == "":
            continue
        state = ann.get("attributes", {}).get("state", "") if isinstance(ann.get("attributes"), dict) else ""
        labels[image].append(Label(_class(category, class_map, where),
                                   _box((x, y, float(x) + float(w), float(y) + float(h)), where), str(state)))
    return labels


def _yolo_folder(folder: Path, sizes: Callable[[str], tuple[int, int]], class_map: Mapping[str, str]
                 ) -> dict[str, list[Label]]:
    classes_file = folder / "classes.txt"
    if not classes_file.is_file():
        raise DataError(f"{folder}: a YOLO label folder needs classes.txt (a class name per line, its line number "
                        "the id)")
    names = [line.strip() for line in read_text_file(classes_file).splitlines() if line.strip()]
    labels: dict[str, list[Label]] = {}
    for path in sorted(folder.glob("*.txt")):
        if path.name == "classes.txt":
            continue
        width, height = sizes(path.stem)
        kept = []
        for n, line in enumerate(read_text_file(path).splitlines(), start=1):
            if not line.strip():
                continue
            where = f"{path}, line {n}"
            parts = line.split()
            try:
                index, (cx, cy, w, h) = int(parts[0]), (float(v) for v in parts[1:5])
            except (ValueError, IndexError):
                raise DataError(f"{where}: expected CLASS_ID CX CY W H, got {line.strip()!r}") from None
            if not 0 <= index < len(names):
                raise DataError(f"{where}: class id {index}, but classes.txt names {len(names)}")
            if class_map.get(names[index], names[index]) == "":
                continue
            kept.append(Label(_class(names[index], class_map, where), _box(
                ((cx - w / 2) * width, (cy - h / 2) * height, (cx + w / 2) * width, (cy + h / 2) * height), where)))
        labels[path.stem] = kept
    return labels


def read_labels(path: str | Path, sizes: Callable[[str], tuple[int, int]] | None = None,
                class_map: Mapping[str, str] | None = None) -> dict[str, list[Label]]:
    """The labels in ``path``, by image name: a kartpilot or COCO JSON file, or a YOLO folder (see the module's
    note). ``sizes(stem)``: an image's width and height by its name without suffix (YOLO's boxes are fractions of
    it). ``class_map``: a team's class names to kartpilot's (to ``""``: left out). A YOLO folder's image names
    are the label files' stems, to be matched to the frames by stem."""
    path, class_map = Path(path), class_map or {}
    if path.is_dir():
        if sizes is None:
            raise DataError(f"{path}: YOLO labels need the images' sizes")
        return _yolo_folder(path, sizes, class_map)
    if not path.is_file():
        raise DataError(f"labels not found: {path}")
    try:
        data = read_json_file(path)
    except DataError as exc:
        raise DataError(f"{exc}; labels are a kartpilot or COCO JSON file, or a YOLO folder") from None
    if isinstance(data, dict) and "images" in data and isinstance(data["images"], dict):
        return _kartpilot_json(data, path, class_map)
    if isinstance(data, dict) and {"images", "annotations", "categories"} <= data.keys():
        return _coco_json(data, path, class_map)
    raise DataError(f"{path}: neither kartpilot labels ('images' by name) nor COCO ('images', 'annotations', "
                    "'categories')")

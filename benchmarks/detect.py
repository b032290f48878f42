"""The event's objects: the classical detectors on the labelled real frames, on the 119 venue frames (false alarms
of the classes they do not hold), on rendered frames of the venue track with exact truth (stop lines and zebras:
their distance), and their cost per detector on one core.

    python benchmarks/detect.py --data ../shared/data --out docs/results/detect.json
    python benchmarks/detect.py --render docs/results/detect.json   # into docs/detection.md

Which data is which: the detectors' thresholds were set while looking at the 5 scenes, the Hanze kart's centre
image and the 119 frames; every real figure here is on that development data. The rendered frames (seed 2) were
not looked at while setting them.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common import write_json
from kartpilot.calibration.board import BoardConfig, find_board
from kartpilot.calibration.ground import calibrate_ground, ground_points
from kartpilot.core.vehicle import get_vehicle
from kartpilot.perception.detect import DetectorConfig, ObjectDetector, detect_classical
from kartpilot.perception.objects import box_iou
from kartpilot.perception.obstacles import ObstacleConfig, detect_barriers, detect_car, detect_people
from kartpilot.perception.road_marks import RoadMarkConfig, camera_for_image, detect_road_marks
from kartpilot.perception.signals import detect_speed_signs, detect_traffic_lights
from vo_table import put_between_markers

ROOT = Path(__file__).resolve().parents[1]
LABELS = ROOT / "tests" / "data" / "rdw_objects.json"
PAGE = ROOT / "docs" / "detection.md"
BOARD = BoardConfig(kind="charuco", columns=10, rows=8, square_m=0.115, marker_m=0.086, dictionary="DICT_4X4_100")


def _matches(box: tuple[float, ...], label_box: list[float]) -> bool:
    """The same object: boxes overlapping by a third, or one's centre inside the other (a far object's box is a
    few pixels; the lamp's box is the head's)."""
    def inside(c: tuple[float, float], b: tuple[float, ...] | list[float]) -> bool:
        return b[0] <= c[0] <= b[2] and b[1] <= c[1] <= b[3]

    lb = tuple(label_box)
    return (box_iou(tuple(box), lb) >= 0.3 or inside(((box[0] + box[2]) / 2, (box[1] + box[3]) / 2), lb)  # type: ignore[arg-type]
            or inside(((lb[0] + lb[2]) / 2, (lb[1] + lb[3]) / 2), box))


ACT_M = 15.0
"""The distance within which the kart must have seen an object to act on it: from 20 km/h (the highest limit
posted at the 2024 event), 0.4 s of the brake's delay and 1.5 m/s² of braking stop the kart in 12.5 m, and its
front is 1.5 m ahead of its rear axle, where distances on the ground are measured from."""
KART_CAMERA_AHEAD_M = float(get_vehicle("sdc-kart").camera("center").pose_body_cam_array[0, 3])
ON_GROUND = ("car", "person", "barrier", "stop_line", "zebra", "parking_bay")
NEAR_M = 2.0
"""Nearer than this (ahead of the rear axle) the kart has passed the point of acting on a thing: its front is at
1.5 m. The rendered marks' window below starts here too."""


def concerns(label: str, box: list[float], camera: Any) -> tuple[bool, float, float]:
    """Whether a labelled thing on the ground concerns the kart, and where its box's foot stands (ahead, left,
    metres on the ground from the rear axle): :data:`NEAR_M` to :data:`ACT_M` ahead, and reaching into the side
    limits the detectors are held to (a car in the kart's corridor, people and barriers this side of the
    spectators' fence, a stop line in the lane, a zebra across it). A light or a sign, placed by its size, always
    counts."""
    if label not in ON_GROUND:
        return True, math.nan, math.nan
    foot = ground_points(camera, np.array([[box[0], box[3]], [box[2], box[3]]], np.float64))
    ahead, left = foot.mean(axis=0)
    # from the SDC kart's rear axle: the Hanze calibration measures from the ground under the camera
    ahead += KART_CAMERA_AHEAD_M - float(camera.pose_body_cam_array[0, 3])
    obstacles, marks = ObstacleConfig(), RoadMarkConfig()
    side = {"car": obstacles.corridor_half_width_m, "stop_line": marks.lane_half_width_m,
            "zebra": marks.zebra_half_width_m}.get(label, obstacles.max_lateral_m)
    beside = foot[:, 1].min() > side or foot[:, 1].max() < -side  # wholly to one side of the zone
    return bool(NEAR_M <= ahead <= ACT_M and not beside), float(ahead), float(left)


def labelled(data: Path) -> dict[str, Any]:
    """Each labelled object found or missed, counted apart where it concerns the kart (:func:`concerns`): the
    detectors leave out by design what lies beyond, or off to the side (a car on another part of the course,
    people across the field), so a miss there is what they were built to do."""
    labels = json.loads(LABELS.read_text())["images"]
    kart = get_vehicle("sdc-kart").camera("center")
    hanze = data / "rdw-kart" / "hanze-calibration"
    images = {n: cv2.imread(str(hanze / f"{n}.jpg")) for n in ("left", "center", "right")}
    hanze_camera = calibrate_ground({n: find_board(im, BOARD, n) for n, im in images.items()},  # type: ignore[misc]
                                    {n: (1920, 1080) for n in images})["center"].camera
    per_class: dict[str, dict[str, int]] = {}
    false_alarms: list[dict[str, Any]] = []
    misses: list[dict[str, Any]] = []
    for name, objects in labels.items():
        camera = hanze_camera if name.startswith("hanze") else kart
        image = cv2.imread(str(data / "rdw-kart" / name))
        found = ObjectDetector(DetectorConfig(), camera)(image)
        placed = camera_for_image(camera, image.shape[1], image.shape[0])
        used: set[int] = set()
        for obj in objects:
            row = per_class.setdefault(obj["label"], dict.fromkeys(
                ("labelled", "found", "state_right", "false_alarms", "concerning", "found_concerning"), 0))
            row["labelled"] += 1
            concern, ahead, left = concerns(obj["label"], obj["box"], placed)
            row["concerning"] += int(concern)
            hit = next((k for k, d in enumerate(found) if k not in used and d.label == obj["label"]
                        and _matches(d.box_px, obj["box"])), None)
            if hit is None:
                misses.append({"image": name, "label": obj["label"], "height_px": obj["box"][3] - obj["box"][1],
                               "concerns": concern, "ahead_m": round(ahead, 1), "left_m": round(left, 1)})
                continue
            used.add(hit)
            row["found"] += 1
            row["found_concerning"] += int(concern)
            row["state_right"] += int(found[hit].state == obj.get("state", found[hit].state))
        for k, d in enumerate(found):
            if k not in used:
                per_class.setdefault(d.label, dict.fromkeys(
                    ("labelled", "found", "state_right", "false_alarms", "concerning", "found_concerning"), 0))
                per_class[d.label]["false_alarms"] += 1
                false_alarms.append({"image": name, "label": d.label, "state": d.state,
                                     "box": [round(v) for v in d.box_px], "distance_m": round(d.distance_m, 1)})
    return {"classes": per_class, "misses": misses, "false_alarms": false_alarms, "near_m": NEAR_M, "act_m": ACT_M}


def venue_frames(data: Path) -> dict[str, Any]:
    """Detections of the classes the 119 frames do not hold (false alarms), and counts of the others."""
    absent = json.loads(LABELS.read_text())["absent_in_frames"]
    detector = ObjectDetector(DetectorConfig(), get_vehicle("sdc-kart").camera("center"))
    paths = sorted((data / "rdw-kart" / "lelystad-2024" / "frames").glob("*.jpg"))
    counts: dict[str, int] = {}
    alarms = 0
    for path in paths:
        for d in detector(cv2.imread(str(path))):
            counts[d.label] = counts.get(d.label, 0) + 1
            alarms += d.label in absent
    return {"frames": len(paths), "false_alarms_of_absent_classes": alarms, "absent_classes": absent,
            "detections": counts}


def rendered(count: int = 60, seed: int = 2) -> dict[str, Any]:
    """Stop lines and zebras on rendered frames of the venue track, against the track's geometry: found where
    one lies 2 to 15 m ahead in the lane, its distance error, and reports where none does."""
    from kartpilot.sim.dynamics import VehicleState
    from kartpilot.sim.simulator import SimConfig, Simulator

    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {"frames": count, "seed": seed}
    rows: dict[str, dict[str, Any]] = {k: {"in_view": 0, "found": 0, "errors_m": [], "false_alarms": 0}
                                       for k in ("stop_line", "zebra")}
    with Simulator(SimConfig(track="lelystad", vehicle="sdc-kart", seed=seed, cameras=("center",))) as sim:
        route, camera = sim.track.route, sim.cameras["center"]
        marks: dict[str, float] = {m.kind: m.s_m for m in sim.track.spec.road_marks}
        for _ in range(count):
            label = "stop_line" if rng.random() < 0.5 else "zebra"
            ahead = float(rng.uniform(0.0, 20.0))
            s = marks[label] - ahead
            i = route.index_at(s)
            x, y = route.xy_m[i] + float(rng.uniform(-0.3, 0.3)) * route.normal()[i]
            sim.state = VehicleState(x_m=float(x), y_m=float(y), yaw_rad=float(route.heading_rad[i]
                                                                                 + rng.uniform(-0.05, 0.05)))
            frame = sim.read()
            assert frame is not None
            found = detect_road_marks(frame.images["center"], camera)
            in_view = 2.0 <= ahead <= 15.0
            for kind in rows:
                mine = [d for d in found if d.label == kind]
                if kind == label and in_view:
                    rows[kind]["in_view"] += 1
                    if mine:
                        rows[kind]["found"] += 1
                        rows[kind]["errors_m"].append(min(abs(d.distance_m - ahead) for d in mine))
                elif kind != label and mine:
                    rows[kind]["false_alarms"] += 1
    for row in rows.values():
        errors = np.asarray(row.pop("errors_m"))
        row["median_error_m"] = float(np.median(errors)) if len(errors) else float("nan")
        row["max_error_m"] = float(errors.max()) if len(errors) else float("nan")
    out["marks"] = rows
    return out


def rendered_props(count: int = 40, seed: int = 3) -> dict[str, Any]:
    """The scenario props on rendered frames of the venue track with exact truth (``Simulator.object_truth``):
    a signal head (red, then green), a 20 km/h sign, a person and the car, the kart 4 to 25 m before them, a
    little off the lane's centre. Per class: in view (and nearer than 25 m), found (the same class, the boxes
    matching), the state right, the median distance error; and false alarms (a detection matching no object of
    its class)."""
    from kartpilot.sim.dynamics import VehicleState
    from kartpilot.sim.simulator import SimConfig, Simulator
    from kartpilot.sim.track import Prop

    props = (Prop(kind="traffic_light", s_m=30.5, offset_m=-2.0, phases=(("red", count / 4), ("green", 1e6))),
             Prop(kind="speed_sign", s_m=70.0, offset_m=-2.3, value_kmh=20),
             Prop(kind="person", s_m=148.0, offset_m=-2.4),
             Prop(kind="car", s_m=190.0, offset_m=0.0))
    rng = np.random.default_rng(seed)
    rows: dict[str, dict[str, Any]] = {}
    with Simulator(SimConfig(track="lelystad", vehicle="sdc-kart", seed=seed, cameras=("center",), props=props,
                             camera_rate_hz=2.0)) as sim:
        route, camera = sim.track.route, sim.cameras["center"]
        detector = DetectorConfig()
        for k in range(count):
            prop = props[k % len(props)]
            i = route.index_at(prop.s_m - float(rng.uniform(4.0, 25.0)))
            x, y = route.xy_m[i] + float(rng.uniform(-0.3, 0.3)) * route.normal()[i]
            sim.state = VehicleState(x_m=float(x), y_m=float(y),
                                     yaw_rad=float(route.heading_rad[i] + rng.uniform(-0.04, 0.04)))
            sim.step_index = k
            seen = [d for d in sim.object_truth("center") if d.label in {p.kind for p in props}
                    and d.distance_m <= 25.0]
            # in view: a light or a sign wholly in the image (one cut by the image's top as the kart passes
            # under it cannot be read, and the kart acted on it metres before), a thing on the ground with its
            # foot and sides in it; one cut off counts neither way
            truth = [d for d in seen if _whole(d, camera)]
            cut = [d for d in seen if not _whole(d, camera)]
            frame = sim.read()
            assert frame is not None
            found = [d for d in detect_classical(frame.images["center"], camera, detector)
                     if d.label in {p.kind for p in props}]
            used: set[int] = set()
            for obj in truth:
                row = rows.setdefault(obj.label, {"in_view": 0, "found": 0, "state_right": 0, "errors_m": [],
                                                  "false_alarms": 0, "in_act": 0, "found_in_act": 0})
                row["in_view"] += 1
                row["in_act"] += int(obj.distance_m <= ACT_M)
                hit = next((n for n, d in enumerate(found) if n not in used and d.label == obj.label
                            and _matches(d.box_px, list(obj.box_px))), None)
                if hit is None:
                    continue
                used.add(hit)
                row["found"] += 1
                row["found_in_act"] += int(obj.distance_m <= ACT_M)
                row["state_right"] += int(found[hit].state == obj.state)
                row["errors_m"].append(abs(found[hit].distance_m - obj.distance_m))
                if 8.0 <= obj.distance_m <= 12.0:
                    row.setdefault("rel_errors_10m", []).append(abs(found[hit].distance_m / obj.distance_m - 1))
            for n, d in enumerate(found):
                if n not in used and any(c.label == d.label and _matches(d.box_px, list(c.box_px)) for c in cut):
                    used.add(n)  # a detection of an object cut off by the image's border: not a false alarm
            for n, d in enumerate(found):
                if n not in used:
                    rows.setdefault(d.label, {"in_view": 0, "found": 0, "state_right": 0, "errors_m": [],
                                              "false_alarms": 0, "in_act": 0, "found_in_act": 0}
                                    )["false_alarms"] += 1
    return {"frames": count, "seed": seed, "classes": rows}


def _whole(d: Any, camera: Any) -> bool:
    left, top, right, bottom = d.box_px
    sides = left > 0 and right < camera.width_px - 1 and bottom < camera.height_px - 1
    return sides and (top > 0 or d.label not in ("traffic_light", "speed_sign"))


def props_over_seeds(seeds: tuple[int, ...] = (4, 5, 6), count: int = 40) -> dict[str, Any]:
    """:func:`rendered_props` on several seeds, summed per class (none looked at while tuning: 3 and 10 to 19
    were)."""
    rows: dict[str, dict[str, Any]] = {}
    for seed in seeds:
        for name, row in rendered_props(count, seed)["classes"].items():
            into = rows.setdefault(name, {})
            for key, value in row.items():
                into[key] = into.get(key, [] if isinstance(value, list) else 0) + value
    for row in rows.values():
        errors = np.asarray(row.pop("errors_m"))
        rel = np.asarray(row.pop("rel_errors_10m", []))
        row["median_error_m"] = float(np.median(errors)) if len(errors) else float("nan")
        row["median_rel_error_10m"] = float(np.median(rel)) if len(rel) else float("nan")
        row["recall_in_act"] = row["found_in_act"] / row["in_act"] if row["in_act"] else float("nan")
        reported = row["found"] + row["false_alarms"]
        row["precision"] = row["found"] / reported if reported else float("nan")
    return {"frames": count * len(seeds), "seeds": list(seeds), "act_m": ACT_M, "classes": rows}


def timing(data: Path) -> dict[str, float]:
    """Milliseconds per 848x480 frame on one core, per detector (the best of three passes over the scenes)."""
    cv2.setNumThreads(1)
    camera = get_vehicle("sdc-kart").camera("center")
    images = [cv2.imread(str(p)) for p in sorted((data / "rdw-kart" / "lelystad-2024" / "scenes").glob("*.jpg"))]
    stages = {"traffic lights + speed signs": lambda im: detect_traffic_lights(im) + detect_speed_signs(im),
              "stop lines + zebras": lambda im: detect_road_marks(im, camera),
              "people (HOG)": lambda im: detect_people(im, camera),
              "car": lambda im: detect_car(im, camera),
              "barriers": lambda im: detect_barriers(im, camera),
              "all classical, people off": lambda im: detect_classical(im, camera, DetectorConfig(people=False)),
              "all classical, people on": lambda im: detect_classical(im, camera, DetectorConfig())}
    out = {}
    for name, run in stages.items():
        best = np.inf
        for _ in range(3):
            start = time.perf_counter()
            for image in images:
                run(image)
            best = min(best, (time.perf_counter() - start) / len(images))
        out[name] = 1000 * best
    return out


def render(results: dict[str, Any]) -> str:
    lines = ["Measured by `benchmarks/detect.py`. Real frames: development data (the thresholds were set looking "
             "at them); rendered frames: not looked at.", "",
             f"A labelled thing on the ground concerns the kart {results['labelled']['near_m']:.0f} to "
             f"{results['labelled']['act_m']:.0f} m ahead, reaching into the zone its detector watches (a car: the "
             "kart's corridor; people and barriers: 6 m either side; a stop line: the lane; a zebra: 2.5 m either "
             "side); the detectors leave out what lies beyond by design. A light or a sign always counts.", "",
             "| class | labelled (real) | of them concerning the kart | found of those | found of all | state right "
             "| false alarms (labelled images) |",
             "|---|---|---|---|---|---|---|"]
    for name, row in sorted(results["labelled"]["classes"].items()):
        lines.append(f"| {name} | {row['labelled']} | {row['concerning']} | {row['found_concerning']} | "
                     f"{row['found']} | {row['state_right']} | {row['false_alarms']} |")
    v = results["frames"]
    lines += ["", f"On the {v['frames']} venue frames (no traffic light, speed sign, stop line or zebra in them): "
                  f"{v['false_alarms_of_absent_classes']} false alarms of those classes; detections of the others "
                  f"(far, unlabelled): {', '.join(f'{k} {n}' for k, n in sorted(v['detections'].items())) or 'none'}.",
              "", "Misses: " + ("; ".join(f"{m['label']} in {m['image'].split('/')[-1]} ({m['height_px']} px tall"
                                         + ("" if not math.isfinite(m["ahead_m"]) else
                                            f", {m['ahead_m']:.0f} m ahead, {abs(m['left_m']):.0f} m to the "
                                            f"{'left' if m['left_m'] >= 0 else 'right'}"
                                            + ("" if m["concerns"] else ": not the kart's concern"))
                                         + ")" for m in results["labelled"]["misses"]) or "none") + ".",
              "", "False alarms on the labelled images: " + ("; ".join(
                  f"{a['label']} in {a['image'].split('/')[-1]} at {a['distance_m']} m"
                  for a in results["labelled"]["false_alarms"]) or "none") + ".", "",
              f"Rendered venue frames ({results['rendered']['frames']}, seed {results['rendered']['seed']}, one mark "
              "2 to 15 m ahead or none in view):", "",
              "| mark | in view | found | median / max distance error | false alarms |", "|---|---|---|---|---|"]
    for name, row in results["rendered"]["marks"].items():
        lines.append(f"| {name} | {row['in_view']} | {row['found']} | {row['median_error_m']:.2f} / "
                     f"{row['max_error_m']:.2f} m | {row['false_alarms']} |")
    props = results.get("rendered_props")
    if props:
        lines += ["", f"Rendered scenario props ({props['frames']} frames, seeds "
                      f"{', '.join(map(str, props['seeds']))}, held out (seeds 3 and 10 to 19 were looked at while "
                      "building the detectors): a signal head red then green, a 20 km/h sign, a person, the car; the "
                      "kart 4 to 25 m before one of them), against exact truth. A light or sign counts when it is "
                      "wholly in the image, a person or the car when its foot and sides are. "
                      f"Recall is counted within {props['act_m']:.0f} m, where the kart must have seen an object to "
                      "act on it from 20 km/h; precision over all detections of the class:", "",
                  "| class | in view (< 25 m) | found | recall within act | precision | state right | median "
                  "distance error | median error at 8 to 12 m | false alarms |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for name, row in sorted(props["classes"].items()):
            lines.append(f"| {name} | {row['in_view']} | {row['found']} | {row['recall_in_act']:.2f} "
                         f"({row['found_in_act']}/{row['in_act']}) | {row['precision']:.2f} | {row['state_right']} | "
                         f"{row['median_error_m']:.2f} m | {100 * row['median_rel_error_10m']:.0f} % | "
                         f"{row['false_alarms']} |")
    lines += ["", "| detector | ms per 848x480 frame, one core | frames/s |", "|---|---|---|"]
    lines += [f"| {name} | {ms:.1f} | {1000 / ms:.0f} |" for name, ms in results["timing_ms"].items()]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "detect.json")
    parser.add_argument("--render", type=Path, help="write this JSON's tables into docs/detection.md")
    args = parser.parse_args()
    if args.render:
        put_between_markers(PAGE, render(json.loads(args.render.read_text())), "<!-- detection -->",
                            "<!-- /detection -->")
        return 0
    write_json(args.out, {"labelled": labelled(args.data), "frames": venue_frames(args.data),
                          "rendered": rendered(), "rendered_props": props_over_seeds(), "timing_ms": timing(args.data)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

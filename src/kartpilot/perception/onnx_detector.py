"""A team's own detector: a YOLO model exported to ONNX, run through onnxruntime on the CPU.

Teams train YOLO models on their own photos of the event and export them to ONNX (``yolo export format=onnx``).
:class:`OnnxDetector` runs such a model: the image letterboxed to the model's input size (grey padding, the
aspect kept), RGB in [0, 1], channels first; the output decoded in either of the two layouts the exports use,
``(1, 4 + classes, boxes)`` (YOLOv8 and later: centre, size, one score per class) or ``(1, boxes, 5 + classes)``
(YOLOv5: centre, size, objectness, class scores); boxes above ``score_threshold`` kept after non-maximum
suppression per class, and mapped back to the image's pixels.

The model's class ids are its own: a YAML file maps each to one of kartpilot's classes and, where the class says
it, a state::

    classes:
      0: {label: traffic_light, state: red}
      1: {label: traffic_light, state: green}
      2: {label: speed_sign, state: "20"}
      3: {label: person}
      4: {label: car}
    score_threshold: 0.4     # optional
    nms_iou: 0.45            # optional

A class id the map does not name is dropped. Nothing is downloaded: the model is the team's file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from kartpilot.core.config import load_yaml_mapping
from kartpilot.core.errors import ConfigError
from kartpilot.core.types import Image
from kartpilot.perception.objects import CLASSES, Detection

__all__ = ["ClassMap", "OnnxDetector", "load_class_map"]


@dataclass(frozen=True)
class ClassMap:
    """The model's class ids to kartpilot's (label, state), and the decoding thresholds."""

    classes: dict[int, tuple[str, str]] = field(default_factory=dict)
    score_threshold: float = 0.4
    nms_iou: float = 0.45


def load_class_map(path: str | Path) -> ClassMap:
    """A class map YAML (see the module's docstring); every error names the key."""
    mapping = load_yaml_mapping(path)
    unknown = set(mapping) - {"classes", "score_threshold", "nms_iou"}
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {', '.join(sorted(map(str, unknown)))} (known: classes, "
                          "score_threshold, nms_iou)")
    raw = mapping.get("classes")
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(f"{path}: 'classes' must map the model's class ids to {{label: ..., state: ...}}")
    classes: dict[int, tuple[str, str]] = {}
    for key, value in raw.items():
        try:
            class_id = int(key)
        except (TypeError, ValueError):
            raise ConfigError(f"{path}: classes.{key}: a class id must be a whole number") from None
        if isinstance(value, str):
            value = {"label": value}
        if not isinstance(value, dict) or value.get("label") not in CLASSES:
            raise ConfigError(f"{path}: classes.{key}.label must be one of {', '.join(CLASSES)}")
        extra = set(value) - {"label", "state"}
        if extra:
            raise ConfigError(f"{path}: classes.{key}: unknown key(s) {', '.join(sorted(extra))}")
        classes[class_id] = (str(value["label"]), str(value.get("state", "")))
    out = ClassMap(classes)
    for name in ("score_threshold", "nms_iou"):
        if name in mapping:
            number = mapping[name]
            if isinstance(number, bool) or not isinstance(number, (int, float)) or not 0.0 < float(number) < 1.0:
                raise ConfigError(f"{path}: {name} must be a number between 0 and 1")
            out = ClassMap(out.classes, **{**{"score_threshold": out.score_threshold, "nms_iou": out.nms_iou},
                                           name: float(number)})
    return out


class OnnxDetector:
    """Holds the onnxruntime session (loaded once); call it with a BGR image."""

    def __init__(self, model: str | Path, class_map: ClassMap, threads: int = 1) -> None:
        try:
            import onnxruntime as ort
        except ImportError as exc:  # pragma: no cover - a dependency
            raise ConfigError("--detector onnx needs onnxruntime (pip install onnxruntime)") from exc
        path = Path(model)
        if not path.is_file():
            raise ConfigError(f"no ONNX model at {path}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        try:
            self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own types for a corrupt or foreign file
            raise ConfigError(f"{path} is not an ONNX model onnxruntime can run: {exc}") from exc
        inputs = self.session.get_inputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise ConfigError(f"{path}: expected one image input (1, 3, H, W), found "
                              f"{[tuple(i.shape) for i in inputs]}")
        shape = inputs[0].shape
        self.input_name = inputs[0].name
        self.size_hw = (int(shape[2]) if isinstance(shape[2], int) else 640,
                        int(shape[3]) if isinstance(shape[3], int) else 640)
        self.class_map = class_map
        self.name = path.name

    def __call__(self, image: Image) -> list[Detection]:
        blob, scale, pad = _letterbox(image, self.size_hw)
        outputs: list[Any] = self.session.run(None, {self.input_name: blob})
        boxes, scores, ids = _decode(np.asarray(outputs[0]))
        h, w = image.shape[:2]
        out: list[Detection] = []
        keep = scores >= self.class_map.score_threshold
        boxes, scores, ids = boxes[keep], scores[keep], ids[keep]
        for class_id in np.unique(ids):
            if int(class_id) not in self.class_map.classes:
                continue
            mine = np.flatnonzero(ids == class_id)
            xywh = [[float(b[0] - b[2] / 2), float(b[1] - b[3] / 2), float(b[2]), float(b[3])] for b in boxes[mine]]
            chosen = cv2.dnn.NMSBoxes(xywh, [float(s) for s in scores[mine]], self.class_map.score_threshold,
                                      self.class_map.nms_iou)
            label, state = self.class_map.classes[int(class_id)]
            for k in np.ravel(chosen):
                cx, cy, bw, bh = boxes[mine[int(k)]]
                left, top = (cx - bw / 2 - pad[0]) / scale, (cy - bh / 2 - pad[1]) / scale
                right, bottom = (cx + bw / 2 - pad[0]) / scale, (cy + bh / 2 - pad[1]) / scale
                box = (float(np.clip(left, 0, w - 1)), float(np.clip(top, 0, h - 1)),
                       float(np.clip(right, 0, w - 1)), float(np.clip(bottom, 0, h - 1)))
                out.append(Detection(label, box, float(scores[mine[int(k)]]), state, source=self.name))
        return out


def _letterbox(image: Image, size_hw: tuple[int, int]) -> tuple[np.ndarray, float, tuple[float, float]]:
    h, w = image.shape[:2]
    scale = min(size_hw[0] / h, size_hw[1] / w)
    nh, nw = round(h * scale), round(w * scale)
    colour = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    resized = cv2.resize(colour, (nw, nh), interpolation=cv2.INTER_LINEAR)
    canvas = np.full((size_hw[0], size_hw[1], 3), 114, np.uint8)
    top, left = (size_hw[0] - nh) // 2, (size_hw[1] - nw) // 2
    canvas[top:top + nh, left:left + nw] = resized
    blob = canvas[..., ::-1].transpose(2, 0, 1)[None].astype(np.float32) / 255.0
    return np.ascontiguousarray(blob), scale, (float(left), float(top))


def _decode(output: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N x 4 centre-size boxes, N scores, N class ids) from either YOLO layout."""
    if output.ndim != 3 or output.shape[0] != 1:
        raise ConfigError(f"the ONNX model's output has shape {output.shape}; expected (1, 4 + classes, boxes) "
                          "or (1, boxes, 5 + classes)")
    rows = output[0]
    if rows.shape[0] < rows.shape[1]:  # (4 + classes, boxes): YOLOv8
        rows = rows.T
        boxes, class_scores = rows[:, :4], rows[:, 4:]
    else:  # (boxes, 5 + classes): YOLOv5, objectness times the class score
        boxes, class_scores = rows[:, :4], rows[:, 5:] * rows[:, 4:5]
    if class_scores.shape[1] == 0:
        raise ConfigError("the ONNX model's output has no class scores")
    ids = np.argmax(class_scores, axis=1)
    return boxes.astype(np.float64), class_scores[np.arange(len(ids)), ids].astype(np.float64), ids

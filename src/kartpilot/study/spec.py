"""A study as data: parts, each a grid of configuration variants × seeds × sources, and the cells it expands to.

A study spec is a YAML file (the built-in ones are in ``study/specs/``)::

    name: filters
    title: Which noise and outlier filters matter (RQ3)
    report: filters                # how ``study report`` presents it (``table`` for any spec)
    questions:
      RQ3: Which noise and outlier filters matter for stereo VO?
    parts:
      - name: open loop
        job: stereo_vo             # one of ``JOB_NAMES`` (each run by ``study.jobs.JOBS``)
        sources: [straight20, utrack, kitti-06]
        seeds: [1, 2, 3, 4, 5]     # simulated sources only; a real dataset is one cell per variant
        params: {speed_mps: 1.0}   # the job's own settings (``JobParams``)
        base: {stereo_vo: {features: {max_features: 2500}}}   # stack overrides for every cell
        variants:                  # named stack overrides, each with an optional group
          - {name: defaults}
          - {name: epipolar off, group: epipolar band, overrides: {stereo_vo: {stereo: {epipolar_band_px: 60}}}}
        sweep:                     # and/or a Cartesian product over dotted stack keys
          stereo_vo.pnp.reprojection_px: [0.5, 3, 8]
        quick: {seeds: [1, 2], sources: [straight20]}   # the --quick size

Every cell's stack configuration is the defaults with ``base`` and then the variant merged over them
(``core.config.merge_config``), so a typo in a key fails the study before anything runs, naming the key.
A cell's hash covers the job, its parameters, the source, the seed and the whole merged configuration:
two spellings of the same configuration share one cached result.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

import kartpilot
from kartpilot.core.config import config_to_dict, load_yaml_mapping, merge_config
from kartpilot.core.errors import ConfigError
from kartpilot.runtime.config import StackConfig

__all__ = ["BUILT_IN", "JOB_NAMES", "Cell", "JobParams", "Part", "StudySpec", "Variant", "code_version",
           "dotted_overrides", "expand_cells", "load_spec", "nested_override", "part_cells"]

BUILT_IN = ("features", "filters", "detectors", "robustness", "lanes", "controllers")

REAL_SOURCES = ("kitti-06", "kitti-raw-city")

JOB_NAMES = ("stereo_vo", "two_view", "lanes", "path_follow", "teach_repeat", "scenario")
"""The jobs a part may name: a spec is checked against these without importing the jobs (which import the
whole stack, and this module: ``study.jobs.JOBS`` runs exactly these)."""


@dataclass(frozen=True)
class JobParams:
    """A job's own settings (not the stack's).

    Attributes:
        vehicle: the simulated vehicle (``rc-kart``: the small kart's 14 cm stereo rig; ``sdc-kart``).
        speed_mps: the speed of the centre-line drive a simulated recording is made with.
        camera_rate_hz: the cameras' frame rate in the simulator.
        seconds: how long a simulated run lasts (0: the whole track, or until the referee ends it).
        frames: how many frames of a real dataset (0: all).
        near_m: the depth under which a final point counts as near (the thesis's 2 to 3 m band).
        pose_noise_m, heading_noise_deg, pose_latency_frames: what the path follower's pose is given in the
            ``path_follow`` job: the true pose with white noise (standard deviations), this many frames old,
            as visual odometry would give it.
        path_noise_m: the ``path_follow`` job's reference is the centre line moved sideways by a smooth random
            offset of this standard deviation (a new value every metre), as a reference taught with VO is.
    """

    vehicle: str = "rc-kart"
    speed_mps: float = 1.0
    camera_rate_hz: float = 10.0
    seconds: float = 0.0
    frames: int = 0
    near_m: float = 3.0
    pose_noise_m: float = 0.0
    heading_noise_deg: float = 0.0
    pose_latency_frames: int = 0
    path_noise_m: float = 0.0

    def __post_init__(self) -> None:
        if not self.speed_mps > 0 or not self.camera_rate_hz > 0:
            raise ConfigError("study params.speed_mps and params.camera_rate_hz must be positive")
        if min(self.seconds, self.frames, self.pose_noise_m, self.heading_noise_deg, self.path_noise_m,
               self.pose_latency_frames) < 0 or not self.near_m > 0:
            raise ConfigError("study params must not be negative (near_m positive)")


@dataclass(frozen=True)
class Variant:
    """One named configuration: stack overrides, and the group it belongs to (one filter, one gain)."""

    name: str
    overrides: Mapping[str, Any] = field(default_factory=dict)
    group: str = ""


@dataclass(frozen=True)
class Part:
    """One job over variants × seeds × sources, with its ``--quick`` size."""

    name: str
    job: str
    sources: tuple[str, ...]
    seeds: tuple[int, ...]
    params: JobParams
    base: Mapping[str, Any]
    variants: tuple[Variant, ...]
    quick_sources: tuple[str, ...]
    quick_seeds: tuple[int, ...]
    quick_params: JobParams
    in_quick: bool = True


@dataclass(frozen=True)
class StudySpec:
    name: str
    title: str
    report: str
    questions: Mapping[str, str]
    parts: tuple[Part, ...]
    tune: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Cell:
    """One job to run: pure in its inputs, so its result is cached under ``key``.

    ``stack`` is the merged stack configuration as a plain mapping (what the worker rebuilds).
    """

    study: str
    part: str
    job: str
    variant: str
    group: str
    source: str
    seed: int
    params: Mapping[str, Any]
    stack: Mapping[str, Any]
    key: str

    def labels(self) -> dict[str, Any]:
        return {"study": self.study, "part": self.part, "job": self.job, "variant": self.variant,
                "group": self.group, "source": self.source, "seed": self.seed, "config_hash": self.key}


def nested_override(dotted: str, value: Any) -> dict[str, Any]:
    """``"a.b.c", 1`` -> ``{"a": {"b": {"c": 1}}}``."""
    out: Any = value
    for part in reversed(dotted.split(".")):
        out = {part: out}
    return dict(out)


def _deep_merge(a: Mapping[str, Any], b: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def dotted_overrides(values: Mapping[str, Any], base: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``{"a.b": 1, "a.c": 2}`` -> ``{"a": {"b": 1, "c": 2}}``, merged over ``base``."""
    out = dict(base or {})
    for key, value in values.items():
        out = _deep_merge(out, nested_override(key, value))
    return out


def _strings(value: Any, where: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"study key '{where}' must be a non-empty list of names")
    return tuple(value)


def _ints(value: Any, where: str) -> tuple[int, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(v, int) and not isinstance(v, bool)
                                                           for v in value):
        raise ConfigError(f"study key '{where}' must be a non-empty list of integers")
    return tuple(value)


def _mapping(value: Any, where: str) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ConfigError(f"study key '{where}' must be a mapping")
    return dict(value)


def _check_keys(data: Mapping[str, Any], known: set[str], where: str) -> None:
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"unknown study key '{where}{unknown[0]}' (known here: {', '.join(sorted(known))})")


def _variants(data: Mapping[str, Any], where: str) -> tuple[Variant, ...]:
    listed: list[Variant] = []
    for i, item in enumerate(data.get("variants") or [{"name": "defaults"}]):
        item = _mapping(item, f"{where}variants[{i}]")
        _check_keys(item, {"name", "group", "overrides"}, f"{where}variants[{i}].")
        if not isinstance(item.get("name"), str):
            raise ConfigError(f"study key '{where}variants[{i}].name' must be a string")
        listed.append(Variant(item["name"], _mapping(item.get("overrides"), f"{where}variants[{i}].overrides"),
                              str(item.get("group", ""))))
    sweep = _mapping(data.get("sweep"), f"{where}sweep")
    if not sweep:
        return tuple(listed)
    for key, values in sweep.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"study key '{where}sweep.{key}' must be a non-empty list of values")
    out = []
    for variant in listed:
        for combo in itertools.product(*sweep.values()):
            overrides = dotted_overrides(dict(zip(sweep, combo, strict=True)), variant.overrides)
            label = ", ".join(f"{key.split('.')[-1]}={value}" for key, value in zip(sweep, combo, strict=True))
            name = label if variant.name == "defaults" and len(listed) == 1 else f"{variant.name}, {label}"
            out.append(Variant(name, overrides, variant.group or ", ".join(k.split(".")[-1] for k in sweep)))
    return tuple(out)


def _params(value: Any, where: str, default: JobParams | None = None) -> JobParams:
    return merge_config(default or JobParams(), _mapping(value, where), where)


def _part(data: Any, index: int) -> Part:
    where = f"parts[{index}]."
    data = _mapping(data, f"parts[{index}]")
    _check_keys(data, {"name", "job", "sources", "seeds", "params", "base", "variants", "sweep", "quick"}, where)
    job = data.get("job")
    if job not in JOB_NAMES:
        raise ConfigError(f"study key '{where}job' must be one of {', '.join(sorted(JOB_NAMES))}, got {job!r}")
    sources = _strings(data.get("sources"), f"{where}sources")
    seeds = _ints(data.get("seeds", [1]), f"{where}seeds")
    params = _params(data.get("params"), f"{where}params")
    in_quick = data.get("quick") is not False  # `quick: false`: the part is left out of the quick size
    quick = _mapping(data.get("quick") if in_quick else None, f"{where}quick")
    _check_keys(quick, {"sources", "seeds", "params"}, f"{where}quick.")
    return Part(
        name=str(data.get("name", f"part {index + 1}")), job=job, sources=sources, seeds=seeds, params=params,
        base=_mapping(data.get("base"), f"{where}base"), variants=_variants(data, where),
        quick_sources=_strings(quick["sources"], f"{where}quick.sources") if "sources" in quick else sources,
        quick_seeds=_ints(quick["seeds"], f"{where}quick.seeds") if "seeds" in quick else seeds,
        quick_params=_params(quick.get("params"), f"{where}quick.params", params), in_quick=in_quick)


def parse_spec(data: Mapping[str, Any], origin: str) -> StudySpec:
    _check_keys(data, {"name", "title", "report", "questions", "parts", "tune"}, "")
    if not isinstance(data.get("name"), str) or not data["name"]:
        raise ConfigError(f"study spec {origin} needs a 'name'")
    parts = data.get("parts")
    if not isinstance(parts, list) or not parts:
        raise ConfigError(f"study spec {origin} needs a non-empty list 'parts'")
    questions = {str(k): str(v) for k, v in _mapping(data.get("questions"), "questions").items()}
    spec = StudySpec(data["name"], str(data.get("title", data["name"])), str(data.get("report", "table")), questions,
                     tuple(_part(p, i) for i, p in enumerate(parts)), _mapping(data.get("tune"), "tune"))
    expand_cells(spec, quick=False)  # every variant's overrides are checked now, not after an hour of cells
    return spec


def load_spec(name_or_path: str | Path) -> StudySpec:
    """A built-in study by name, or a spec file."""
    text = str(name_or_path)
    if text in BUILT_IN:
        source = resources.files("kartpilot.study") / "specs" / f"{text}.yaml"
        with resources.as_file(source) as path:
            return parse_spec(load_yaml_mapping(path), text)
    path = Path(text)
    if path.suffix not in (".yaml", ".yml") and not path.exists():
        raise ConfigError(f"unknown study {text!r}: a built-in one ({', '.join(BUILT_IN)}) or a spec .yaml file")
    return parse_spec(load_yaml_mapping(path), str(path))


@functools.cache
def code_version() -> str:
    """The package version and a hash of its source files (the study specs aside: a cell's key holds all of
    its configuration), so a row computed by other code is not reused. Hashed once per process: the code a
    process runs is the code it imported."""
    root = Path(kartpilot.__file__).parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*")):
        if path.suffix in (".py", ".yaml", ".dbc") and "__pycache__" not in path.parts and \
                path.parent.name != "specs":
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    return f"{kartpilot.__version__}+{digest.hexdigest()[:12]}"


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def cell_key(job: str, source: str, seed: int, params: Mapping[str, Any], stack: Mapping[str, Any]) -> str:
    """The hash a cell's result is cached under: everything that decides it, and nothing else."""
    blob = _canonical({"job": job, "source": source, "seed": seed, "params": params, "stack": stack})
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def part_cells(study: str, part: Part, variant: Variant, sources: Sequence[str], seeds: Sequence[int],
               quick: bool) -> list[Cell]:
    """The cells of one variant of ``part`` over ``sources`` × ``seeds`` (a real dataset: one cell, seed 0)."""
    plain_params = config_to_dict(part.quick_params if quick else part.params)
    stack = merge_config(merge_config(StackConfig(), part.base, "base"), variant.overrides,
                         f"{part.name}/{variant.name}")
    plain = config_to_dict(stack)
    return [Cell(study, part.name, part.job, variant.name, variant.group, source, seed, plain_params, plain,
                 cell_key(part.job, source, seed, plain_params, plain))
            for source in sources for seed in ((0,) if source in REAL_SOURCES else seeds)]


def expand_cells(spec: StudySpec, quick: bool) -> list[Cell]:
    """Every cell of the study, in a stable order (variants, then sources, then seeds). Cells of equal
    configuration share a key, and are computed once."""
    cells: list[Cell] = []
    for part in spec.parts:
        if quick and not part.in_quick:
            continue
        sources, seeds = (part.quick_sources, part.quick_seeds) if quick else (part.sources, part.seeds)
        for variant in part.variants:
            cells += part_cells(spec.name, part, variant, sources, seeds, quick)
    return cells


def stack_of(cell: Cell) -> StackConfig:
    """The cell's stack configuration, rebuilt from its plain mapping."""
    return merge_config(StackConfig(), cell.stack, "stack")


def params_of(cell: Cell) -> JobParams:
    return replace(JobParams(), **cell.params)

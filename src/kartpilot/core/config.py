"""Typed configuration: dataclass defaults in code, one YAML file merged over them.

Every component owns one frozen config dataclass whose defaults are the
recommended values. A YAML file is merged over the defaults with
:func:`merge_config`; an unknown key or a value of the wrong type raises
:class:`~kartpilot.core.errors.ConfigError` naming the full dotted key, so a
typo never silently falls back to a default. There is no global configuration
and nothing is read from environment variables.

Example:
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Blur:
    ...     kernel_px: int = 5
    ...     sigma_px: float = 1.0
    >>> merge_config(Blur(), {"sigma_px": 2})
    Blur(kernel_px=5, sigma_px=2.0)
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from kartpilot.core.errors import ConfigError
from kartpilot.core.files import parse_yaml, read_text_file

__all__ = ["config_to_dict", "load_yaml_mapping", "merge_config"]

T = TypeVar("T")


INT_LIMIT = 2**31 - 1

def load_yaml_mapping(path: str | Path) -> dict[str, Any]:
    """Read a YAML file whose top level is a mapping (an empty file gives ``{}``)."""
    path = Path(path)
    if not path.exists():  # a folder or a pipe is said by the text reader's own check
        raise ConfigError(f"config file not found: {path}")
    try:
        data = parse_yaml(read_text_file(path), path)
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file {path} is not valid YAML: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} must hold a mapping at the top level")
    return data


def merge_config(default: T, overrides: Mapping[str, Any] | None, where: str = "") -> T:
    """Return ``default`` with ``overrides`` merged in, checking every key and type.

    Args:
        default: a dataclass instance holding the defaults.
        overrides: a mapping from field names to values (nested dataclasses take mappings).
        where: dotted prefix used in error messages.
    """
    if not dataclasses.is_dataclass(default) or isinstance(default, type):
        raise TypeError("merge_config needs a dataclass instance")
    if overrides is None:
        return default
    if not isinstance(overrides, Mapping):
        raise ConfigError(f"config key '{where or '<root>'}' must be a mapping")
    hints = typing.get_type_hints(type(default))
    names = {f.name for f in dataclasses.fields(default)}
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        dotted = f"{where}.{key}" if where else str(key)
        if key not in names:
            known = ", ".join(sorted(names))
            raise ConfigError(f"unknown config key '{dotted}' (known here: {known})")
        current = getattr(default, key)
        if dataclasses.is_dataclass(current) and not isinstance(current, type):
            changes[key] = merge_config(current, value, dotted)
        else:
            changes[key] = _coerce(value, hints[key], dotted)
    try:
        return dataclasses.replace(default, **changes)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"config '{where or '<root>'}': {exc}") from exc


def check_values(section: str, config: Any, checks: Iterable[tuple[str, bool, str]]) -> None:
    """A config's own checks of its numbers, each ``(field, it holds, what it must be)``: the first that fails, or
    whose value is not finite, is an error naming ``section.field``, its value and what it must be."""
    for name, ok, allowed in checks:
        value = getattr(config, name)
        if not (ok and math.isfinite(float(value))):
            raise ConfigError(f"{section}.{name} {value}: must be {allowed}")


def config_to_dict(config: Any) -> dict[str, Any]:
    """A plain, YAML- and JSON-serialisable dict of a config dataclass."""
    def plain(value: Any) -> Any:
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        return value

    return {k: plain(v) for k, v in dataclasses.asdict(config).items()}


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, dotted: str) -> Any:
    """Check ``value`` against the annotation ``tp``; convert only lossless cases."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    bad = ConfigError(
        f"config key '{dotted}' must be {_type_name(tp)}, got {type(value).__name__} {value!r}"
    )
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for option in args:
            if option is type(None):
                continue
            try:
                return _coerce(value, option, dotted)
            except ConfigError:
                continue
        raise bad
    if origin is typing.Literal:
        if value in args:
            return value
        choices = ", ".join(repr(a) for a in args)
        raise ConfigError(f"config key '{dotted}' must be one of {choices}, got {value!r}")
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise bad
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{dotted}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"config key '{dotted}' needs {len(args)} values, got {len(value)}")
        return tuple(_coerce(v, a, f"{dotted}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if origin is dict:  # a mapping of names to values (a LiDAR's dropout per kind of surface)
        if not isinstance(value, Mapping):
            raise bad
        key_tp, value_tp = args or (Any, Any)
        return {_coerce(k, key_tp, f"{dotted}.{k}"): _coerce(v, value_tp, f"{dotted}.{k}") for k, v in value.items()}
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise bad
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            if abs(value) > INT_LIMIT:  # beyond what OpenCV and NumPy's fixed-width integers hold
                raise ConfigError(f"config key '{dotted}' is out of range: {value}")
            return value
        raise bad
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise ConfigError(f"config key '{dotted}' must be a finite number, got {value!r}")
            return float(value)
        raise bad
    if tp is str:
        if isinstance(value, str):
            return value
        raise bad
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    if dataclasses.is_dataclass(tp) and isinstance(tp, type) and isinstance(value, Mapping):
        try:
            default = tp()
        except TypeError as exc:
            raise ConfigError(f"config key '{dotted}': {tp.__name__} has required fields ({exc})") from exc
        return merge_config(default, value, dotted)
    raise bad

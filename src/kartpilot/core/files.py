"""Files written whole or not at all: a crash, a full disk or Ctrl-C leaves the old file (or none), never half
of a new one. Everything kartpilot writes in one piece (results, rig files, manifests, place databases)
goes through here."""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import yaml

from kartpilot.core.errors import DataError

YAML_MAX_VALUES = 100_000
"""The most values a YAML file may stand for once its aliases are expanded (a config is a few hundred; "a billion
laughs", nine anchors of ten aliases each, stands for a billion)."""

__all__ = ["is_torn_last_line", "parse_yaml", "read_text_file", "write_atomic", "write_bytes_atomic",
           "write_csv_atomic", "write_json_atomic", "write_text_atomic"]


def is_torn_last_line(content: str, line: int, last_line: int) -> bool:
    """Whether ``line`` (numbered like ``last_line``) is the last line of a text file cut off mid-write: the
    writer was killed inside it, so the file does not end with a newline. Readers skip such a line; any other
    bad line is an error."""
    return line == last_line and not content.endswith("\n")


def read_text_file(path: str | Path) -> str:
    """A text file's contents, with Windows line ends and a byte-order mark (as other tools write them) read as
    plain text; a file that cannot be read, is not a regular file (a pipe, a device), or is not UTF-8 text, raises
    DataError naming it."""
    if Path(path).exists() and not Path(path).is_file():
        raise DataError(f"{path} is not a regular file (a pipe or a device): save it to a file first")
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path} is not a UTF-8 text file (byte {exc.start}: {exc.reason})") from None
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc.strerror or exc}") from None


def parse_yaml(text: str, source: str | Path) -> Any:
    """YAML text as Python values, as ``yaml.safe_load`` reads it, except that a document whose aliases expand to
    more than :data:`YAML_MAX_VALUES` values, or that nests too deeply to read, raises DataError naming
    ``source``; a syntax error raises ``yaml.YAMLError`` as before."""
    loader = yaml.SafeLoader(text)
    try:
        try:
            node = loader.get_single_node()
        except RecursionError:
            raise DataError(f"{source}: nested too deeply to read") from None
        if node is None:
            return None
        if _expanded_size(node) > YAML_MAX_VALUES:
            raise DataError(f"{source}: its aliases (*name) expand to more than {YAML_MAX_VALUES} values; write "
                            "the values out instead")
        try:
            return loader.construct_document(node)
        except RecursionError:
            raise DataError(f"{source}: nested too deeply to read") from None
    finally:
        loader.dispose()


def _expanded_size(root: yaml.Node) -> int:
    """How many values a YAML node stands for with every alias expanded: each node's size counted once and
    reused where an alias repeats it, so a document that expands to billions is measured in its own length."""
    sizes: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        if id(node) in sizes:
            continue
        children: list[yaml.Node] = []
        if isinstance(node, yaml.SequenceNode):
            children = list(node.value)
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        if done or not children:
            sizes[id(node)] = 1 + sum(sizes.get(id(c), 0) for c in children)
            if sizes[id(node)] > YAML_MAX_VALUES:
                return sizes[id(node)]
            continue
        stack.append((node, True))
        stack.extend((c, False) for c in children if id(c) not in sizes)
    return sizes[id(root)]


def write_atomic(path: str | Path, write: Callable[[BinaryIO], object]) -> Path:
    """Call ``write`` with a temporary file beside ``path``, then put it in place in one step (the folder is
    created). If ``write`` raises, the temporary file is removed and ``path`` is untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.partial")
    try:
        with temporary.open("wb") as handle:
            write(handle)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    return write_atomic(path, lambda handle: handle.write(data))


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_bytes_atomic(path, text.encode())


def write_csv_atomic(path: str | Path, header: Sequence[object], rows: Iterable[Sequence[object]]) -> Path:
    """A CSV file with ``header`` and ``rows``, written whole or not at all."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return write_text_atomic(path, text.getvalue())


def write_json_atomic(path: str | Path, payload: Any) -> Path:
    """``payload`` as indented JSON (the text is made first: a value JSON cannot hold writes nothing)."""
    return write_text_atomic(path, json.dumps(payload, indent=2))

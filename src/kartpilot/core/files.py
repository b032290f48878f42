"""Files written whole or not at all: a crash, a full disk or Ctrl-C leaves the old file (or none), never half
of a new one. Everything kartpilot writes in one piece (results, rig files, manifests, place databases)
goes through here."""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import yaml

from kartpilot.core.errors import DataError

YAML_MAX_VALUES = 100_000
"""The most values a YAML file may stand for once its aliases are expanded (a config is a few hundred; "a billion
laughs", nine anchors of ten aliases each, stands for a billion)."""

__all__ = ["MAX_FILE_BYTES", "MAX_JSON_DEPTH", "MAX_TEXT_BYTES", "check_readable", "csv_records", "free_bytes",
           "is_torn_last_line", "iter_csv_file", "parse_csv", "parse_json", "parse_yaml", "read_file_bytes",
           "read_json_file", "read_text_file", "write_atomic", "write_bytes_atomic", "write_csv_atomic",
           "write_json_atomic", "write_text_atomic"]


def is_torn_last_line(content: str, line: int, last_line: int) -> bool:
    """Whether ``line`` (numbered like ``last_line``) is the last line of a text file cut off mid-write: the
    writer was killed inside it, so the file does not end with a newline. Readers skip such a line; any other
    bad line is an error."""
    return line == last_line and not content.endswith("\n")


MAX_TEXT_BYTES = 512 * 2**20
"""The largest text file kartpilot reads whole (a config is kilobytes, a long drive's CSV tens of megabytes)."""

MAX_JSON_DEPTH = 100
"""The deepest nesting a JSON file may have (kartpilot's own files nest five deep)."""


def read_text_file(path: str | Path) -> str:
    """A text file's contents, with Windows line ends and a byte-order mark (as other tools write them) read as
    plain text; a file that is missing, a folder, not a regular file (a pipe, a device), larger than
    :data:`MAX_TEXT_BYTES`, unreadable, or not UTF-8 text raises DataError naming it. The one door for text
    files: JSON (:func:`read_json_file`), CSV (:func:`parse_csv`) and YAML (:func:`parse_yaml`) come through it."""
    path = Path(path)
    check_readable(path, MAX_TEXT_BYTES)
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path} is not a UTF-8 text file (byte {exc.start}: {exc.reason})") from None
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc.strerror or exc}") from None


MAX_FILE_BYTES = 2 * 2**30
"""The largest file kartpilot reads whole as bytes (an image of a recording, copied into an export)."""


def read_file_bytes(path: str | Path) -> bytes:
    """A file's bytes, copied as they are (an export embeds a recording's images); a missing file, a folder, a
    pipe, or one larger than :data:`MAX_FILE_BYTES` raises DataError naming it."""
    path = Path(path)
    check_readable(path, MAX_FILE_BYTES)
    try:
        return path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc.strerror or exc}") from None


def parse_json(text: str, source: str | Path, allow_nan: bool = True) -> Any:
    """JSON text as Python values; invalid JSON (with its line and column) and nesting deeper than
    :data:`MAX_JSON_DEPTH` raise DataError naming ``source``. NaN and Infinity, which Python's JSON writes for
    a figure that has none (kartpilot's results do), are read unless ``allow_nan`` is False."""
    if _bracket_depth(text) > MAX_JSON_DEPTH:
        raise DataError(f"{source}: nested more than {MAX_JSON_DEPTH} deep")

    def no_constant(name: str) -> Any:
        raise ValueError(f"{name} is not a JSON number")

    try:
        return json.loads(text, parse_constant=None if allow_nan else no_constant)
    except json.JSONDecodeError as exc:
        raise DataError(f"{source}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    except (ValueError, RecursionError) as exc:
        raise DataError(f"{source}: not valid JSON ({exc})") from None


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_YAML_NOT_FLOW = re.compile(r'"(?:[^"\\]|\\.)*"|\'(?:[^\']|\'\')*\'|(?:^|(?<=\s))#[^\n]*', re.MULTILINE)
"""What in YAML text is no flow bracket, whatever brackets it holds: quoted scalars and comments."""


def _bracket_depth(text: str, strings: re.Pattern[str] = _JSON_STRING) -> int:
    """The deepest nesting of brackets outside strings: the strings taken out by one regular expression, then the
    brackets' running count (no recursion, and C speed on a label file of megabytes). YAML's flow collections are
    counted the same way, ``strings`` then matching its quoted scalars and comments."""
    if text.count("[") + text.count("{") <= MAX_JSON_DEPTH:
        return 0  # too few brackets to nest too deep: most files stop here
    brackets = np.frombuffer(strings.sub('""', text).encode("utf-8", "replace"), np.uint8)
    steps = np.zeros(len(brackets), np.int64)
    steps[(brackets == ord("[")) | (brackets == ord("{"))] = 1
    steps[(brackets == ord("]")) | (brackets == ord("}"))] = -1
    return int(np.cumsum(steps).max(initial=0))


def read_json_file(path: str | Path, allow_nan: bool = True) -> Any:
    """A JSON file's values (see :func:`read_text_file` and :func:`parse_json`)."""
    return parse_json(read_text_file(path), path, allow_nan)


def parse_csv(text: str, source: str | Path, required: Sequence[str] = ()) -> list[dict[str, str]]:
    """CSV text with a header line as one dict per row; a header without the ``required`` columns, or a row with
    more or fewer fields than the header, raises DataError naming ``source`` and the line."""
    reader = csv.DictReader(io.StringIO(text))
    header = reader.fieldnames or []
    missing = [name for name in required if name not in header]
    if missing:
        raise DataError(f"{source}: no column {', '.join(missing)} in its header ({', '.join(header) or 'empty'})")
    rows = []
    try:
        for row in reader:
            if None in row or any(v is None for v in row.values()):
                raise DataError(f"{source}, line {reader.line_num}: not the header's {len(header)} fields")
            rows.append(row)
    except csv.Error as exc:
        raise DataError(f"{source}, line {reader.line_num}: {exc}") from None
    return rows


def csv_records(text: str) -> list[dict[str, Any]]:
    """CSV text with a header line as one dict per row, as :class:`csv.DictReader` gives them (a short row's
    missing fields None, a long row's extra ones under None): for readers that judge a row themselves (a
    recording's last line, cut off by a crash, is skipped rather than refused)."""
    return list(csv.DictReader(io.StringIO(text)))


def iter_csv_file(path: str | Path, skip_torn: bool = False) -> Iterator[dict[str, str]]:
    """A CSV file with a header line, a row at a time (a long drive's log need not be read whole), through the
    same checks as :func:`read_text_file`. A row with more or fewer fields than the header raises DataError
    naming the file and line, or is skipped (``skip_torn``: a recording's rows, one of which a crash may cut)."""
    path = Path(path)
    check_readable(path)
    try:
        with path.open(encoding="utf-8-sig", newline="") as handle:
            reader = csv.DictReader(handle)
            width = len(reader.fieldnames or [])
            for row in reader:
                if None in row or any(v is None for v in row.values()):
                    if skip_torn:
                        continue
                    raise DataError(f"{path}, line {reader.line_num}: not the header's {width} fields")
                yield row
    except UnicodeDecodeError as exc:
        raise DataError(f"{path} is not a UTF-8 text file (byte {exc.start}: {exc.reason})") from None
    except csv.Error as exc:
        raise DataError(f"{path}: {exc}") from None
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc.strerror or exc}") from None


def check_readable(path: Path, most_bytes: int | None = None, what: str = "file") -> None:
    """What every reader checks before it reads (text, bytes, a CSV stream, an image): a folder, not a regular file
    (a pipe, a device), missing, or larger than ``most_bytes``, each a DataError naming the file; ``what`` names
    the kind of file in the messages ("image file": "is a folder, not an image file", "image not found")."""
    if path.is_dir():
        raise DataError(f"{path} is a folder, not {'an' if what[0] in 'aeiou' else 'a'} {what}")
    if path.exists() and not path.is_file():
        raise DataError(f"{path} is not a regular file (a pipe or a device): save it to a file first")
    if not path.exists():
        raise DataError(f"{what.removesuffix(' file')} not found: {path}")
    size = path.stat().st_size
    if most_bytes is not None and size > most_bytes:
        raise DataError(f"{path} is {size / 2**20:.0f} MB: more than the {most_bytes // 2**20} MB kartpilot reads "
                        "in one piece")


def parse_yaml(text: str, source: str | Path) -> Any:
    """YAML text as Python values, as ``yaml.safe_load`` reads it, except that a document whose aliases expand to
    more than :data:`YAML_MAX_VALUES` values, or that nests too deeply to read, raises DataError naming
    ``source``; a syntax error raises ``yaml.YAMLError`` as before, its message one line (what is wrong, and
    where: a person's terminal and a command's one-line error, not PyYAML's excerpt of the file)."""
    if _bracket_depth(text, _YAML_NOT_FLOW) > MAX_JSON_DEPTH:
        # PyYAML's scanner takes time quadratic in the nesting before its composer runs out of stack (3 s for a
        # 200 kB file of brackets); no kartpilot file nests flow collections more than a few deep
        raise DataError(f"{source}: nested too deeply to read")
    loader = yaml.SafeLoader(text)
    try:
        try:
            node = loader.get_single_node()
        except RecursionError:
            raise DataError(f"{source}: nested too deeply to read") from None
        except yaml.MarkedYAMLError as exc:
            raise yaml.YAMLError(_yaml_error_line(exc)) from None
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


def _yaml_error_line(exc: yaml.MarkedYAMLError) -> str:
    """PyYAML's error as one line: the problem, where it is, and what it was reading."""
    mark = exc.problem_mark or exc.context_mark
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    context = f" ({exc.context})" if exc.context else ""
    return f"{exc.problem or 'not YAML'}{where}{context}"


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


def free_bytes(path: str | Path) -> int:
    """The bytes free for this user on the disk that holds ``path`` (or its nearest folder that exists)."""
    place = Path(path).absolute()
    while not place.exists() and place != place.parent:
        place = place.parent
    return shutil.disk_usage(place).free


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

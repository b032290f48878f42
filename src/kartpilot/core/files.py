"""Files written whole or not at all: a crash, a full disk or Ctrl-C leaves the old file (or none), never half
of a new one. Everything kartpilot writes in one piece (results, rig files, manifests, place databases)
goes through here."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

__all__ = ["write_atomic", "write_bytes_atomic", "write_json_atomic", "write_text_atomic"]


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


def write_json_atomic(path: str | Path, payload: Any) -> Path:
    """``payload`` as indented JSON (the text is made first: a value JSON cannot hold writes nothing)."""
    return write_text_atomic(path, json.dumps(payload, indent=2))

"""Where the command line's values are checked, for every command: numbers (finite, in range), output paths
(they can be written, before any work is done), and usage errors (one line). Inputs are checked by the
readers that open them, which name the file.

A value that fails is a usage error: one line starting with ``kartpilot:``, naming the option, exit code 2.
Config files are checked where they are merged (:mod:`kartpilot.core.config`).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

__all__ = ["VIEW_HELP", "OneLineParser", "file_or_new_folder", "new_folder", "number", "output_file", "results_folder",
           "view_target"]


class OneLineParser(argparse.ArgumentParser):
    """argparse, with a usage error on one line (``kartpilot: error: ...``) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        command = self.prog.removeprefix("kartpilot").strip()
        where = f"{command}: " if command else ""
        print(f"kartpilot: error: {where}{message} (see `{self.prog} --help`)", file=sys.stderr)
        raise SystemExit(2)


def number(kind: type[int] | type[float] = float, *, minimum: float | None = None, maximum: float | None = None,
           above: float | None = None) -> Callable[[str], float]:
    """An argparse ``type`` for a finite number in a range: ``minimum``/``maximum`` inclusive, ``above``
    exclusive. NaN and infinity are refused by name."""
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") \
                from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"{text} is below the least allowed, {minimum:g}")
        if above is not None and value <= above:
            raise argparse.ArgumentTypeError(f"{text} must be above {above:g}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"{text} is above the most allowed, {maximum:g}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def output_file(text: str) -> Path:
    """A file to write: its folder must exist and be writable, and the path must not be a folder or a device.
    The command writes it whole or not at all (through a temporary file and a rename)."""
    path = Path(text)
    if not text:
        raise argparse.ArgumentTypeError("an empty path")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a folder, not a file to write")
    if path.exists() and not path.is_file():
        raise argparse.ArgumentTypeError(f"{text} exists and is not a regular file")
    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{parent} is a file, not a folder to write {path.name} in")
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"the folder {parent} cannot be written to")
    return path


VIEW_HELP = "a Rerun view of the run as it goes: a .rrd file, or 'live' for a viewer (docs/viewing.md)"


def view_target(text: str) -> str:
    """Where a Rerun view goes: ``live`` (a viewer, started if none is running) or a ``.rrd`` file to write."""
    if text == "live":
        return text
    if Path(text).suffix != ".rrd":
        raise argparse.ArgumentTypeError(f"{text!r}: give a .rrd file or 'live'")
    return str(output_file(text))


def new_folder(text: str) -> Path:
    """A folder to create: it must not exist yet, or be empty; its parent must be writable (it is created
    with its parents where missing)."""
    path = Path(text)
    if not text:
        raise argparse.ArgumentTypeError("an empty path")
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} exists and is not a folder")
    if path.is_dir() and any(path.iterdir()):
        raise argparse.ArgumentTypeError(f"{text} exists and is not empty: give a new folder")
    parent = next((p for p in path.absolute().parents if p.exists()), Path("/"))
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{parent} cannot be written to")
    return path


def file_or_new_folder(text: str) -> Path:
    """A file to write where the path has a suffix (``overlay.mp4``), else a new or empty folder."""
    return output_file(text) if Path(text).suffix else new_folder(text)


def results_folder(text: str) -> Path:
    """A folder a command keeps adding to (a study's results): new, empty, or one it wrote before (it holds
    ``study.json``)."""
    path = Path(text)
    if path.is_dir() and any(path.iterdir()) and not (path / "study.json").is_file():
        raise argparse.ArgumentTypeError(f"{text} holds other files and no study: give a new folder, or a "
                                         "study's own to continue it")
    return new_folder(text) if not path.is_dir() or not any(path.iterdir()) else path

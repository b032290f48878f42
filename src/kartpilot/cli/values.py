"""Where the command line's values are checked, for every command: numbers (finite, in range), output paths
(they can be written, before any work is done), and usage errors (one line). Inputs are checked by the
readers that open them, which name the file; a command that read a folder reports the images it left out
(:func:`report_left_out`).

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

__all__ = ["OUTPUT_TYPES", "VIEW_HELP", "OneLineParser", "check_paths", "file_or_new_folder", "new_folder", "number",
           "output_file", "output_folder", "results_folder", "view_target", "written_path"]


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


def input_path(text: str) -> str:
    """A file or folder the command reads, as given: its reader checks it where it is read (the one door of each
    kind, ``core.files`` and ``core.images``). The type marks the argument as an input, for the matrix that tries
    every bad file on every input (``tests/robustness/test_input_matrix.py``)."""
    return text


def config_path(text: str) -> str:
    """A YAML file merged over a command's defaults (:func:`input_path`; an empty one is the defaults)."""
    return text


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
    path = output_folder(text)
    if path.is_dir() and any(path.iterdir()):
        raise argparse.ArgumentTypeError(f"{text} exists and is not empty: give a new folder")
    return path


def output_folder(text: str) -> Path:
    """A folder a command writes into again on every run (a demo's, an experiment's): it may exist, but must not be
    a file; its parent must be writable."""
    path = Path(text)
    if not text:
        raise argparse.ArgumentTypeError("an empty path")
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} exists and is not a folder")
    parent = next((p for p in path.absolute().parents if p.exists()), Path("/"))
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{parent} cannot be written to")
    return path


def written_path(text: str) -> Path:
    """A path the command writes whose kind (a file or a folder) hangs on another option, so the command checks it
    itself once it knows (``recordings export --format``); declared here so that the guard counts it an output."""
    if not text:
        raise argparse.ArgumentTypeError("an empty path")
    return Path(text)


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


OUTPUT_TYPES = (output_file, view_target, new_folder, file_or_new_folder, results_folder, output_folder, written_path)
"""The argparse types that name something a command writes."""


def output_dests(parser: argparse.ArgumentParser, args: argparse.Namespace | None = None) -> dict[str, bool]:
    """Every option of ``parser`` and its subcommands (its ``dest``), and whether it names something written. With
    ``args``, only the subcommands they chose: an option is an output by its own command's declaration (``sim
    --video`` writes a video, ``calibrate mono --video`` reads one)."""
    dests: dict[str, bool] = {}
    for action in parser._actions:
        dests[action.dest] = dests.get(action.dest, False) or action.type in OUTPUT_TYPES
        if isinstance(action, argparse._SubParsersAction):
            chosen = getattr(args, action.dest, None) if args is not None else None
            subs = [action.choices[chosen]] if chosen in action.choices else list(action.choices.values())
            for sub in subs:
                for dest, written in output_dests(sub, args).items():
                    dests[dest] = dests.get(dest, False) or written
    return dests


def _option(dest: str, positional: bool) -> str:
    return dest.upper() if positional else f"--{dest.replace('_', '-')}"


class DevicePath(str):
    """An option's value that names a device (a serial port, a joystick): opened by its driver, not read as a file,
    so the file checks of :func:`check_paths` leave it alone."""


def device(text: str) -> DevicePath:
    """``type=`` of an option that names a device (``/dev/ttyUSB0``, ``/dev/input/js0``, a pyserial URL)."""
    if not text:
        raise argparse.ArgumentTypeError("name the device")
    return DevicePath(text)


def _paths(value: object) -> list[str]:
    """The paths an option's value names: itself, each of a list's, and the file of a ``NAME=FILE`` value (a
    camera's image, a folder's rig) where the value itself is no file. A device names none."""
    if isinstance(value, DevicePath):
        return []
    if isinstance(value, (str, Path)):
        text = str(value)
        name, equals, file = text.partition("=")
        if equals and file and name and not Path(text).exists():
            return [text, file]
        return [text]
    if isinstance(value, (list, tuple)):
        return [p for v in value for p in _paths(v)]
    return []


def _in_recording(folder: Path) -> bool:
    """Whether ``folder`` is a recording or a dataset's own tree (it holds a manifest, a tub's catalog, a sequence's
    calibration or a bag's metadata): writing anything inside changes what it holds."""
    marks = ("manifest.json", "calib.txt", "times.txt", "metadata.yaml")
    return any((folder / m).is_file() for m in marks)


def check_paths(args: argparse.Namespace, dests: dict[str, bool], positionals: frozenset[str] = frozenset()) -> None:
    """What every command's paths must be, checked once where the command line is read (a usage error names the
    option): valid UTF-8 (a name OpenCV cannot open otherwise); an input that exists is a regular file or a
    folder (not a pipe or a device: readers seek, and a pipe with no writer hangs); no output is one of the
    inputs or a file inside an input folder, and no two outputs are the same path (each would destroy a file).
    ``dests`` says which options name outputs (:func:`output_dests`); ``positionals`` are named without dashes."""
    outputs = {dest for dest, written in dests.items() if written}
    given = {dest: _paths(value) for dest, value in vars(args).items() if dest not in ("handler", "check")}
    for dest, paths in given.items():
        for text in paths:
            try:
                text.encode("utf-8")
            except UnicodeEncodeError:
                raise argparse.ArgumentTypeError(f"{_option(dest, dest in positionals)}: the name {text!r} is not "
                                                 "valid UTF-8; rename the file") from None
    inputs = {dest: [Path(p) for p in paths if p and Path(p).exists()] for dest, paths in given.items()
              if dest not in outputs}
    for dest, found in inputs.items():
        for path in found:
            if not (path.is_file() or path.is_dir()):
                raise argparse.ArgumentTypeError(f"{_option(dest, dest in positionals)}: {path} is not a regular file "
                                                 "or a folder (a pipe or a device); save it to a file first")
    written: dict[Path, str] = {}
    for dest in sorted(outputs & given.keys()):
        for text in given[dest]:
            if not text or text == "live":
                continue
            target = Path(text).absolute().resolve()
            option = _option(dest, dest in positionals)
            if target in written:
                raise argparse.ArgumentTypeError(f"{option} and {written[target]} are the same path, {text}: give "
                                                 "each output its own")
            written[target] = option
            for other, found in inputs.items():
                for p in found:
                    folder = p.absolute().resolve()
                    # a file already in an input folder (one of its images, or any file of a recording's) is the
                    # input's, and anything written into a recording changes what the recording holds
                    inside = p.is_dir() and folder in target.parents and (
                        (target.is_file() and target.suffix.lower() in _MEDIA) or _in_recording(folder))
                    if folder == target or (target.exists() and _same(p, target)) or inside:
                        raise argparse.ArgumentTypeError(
                            f"{option} {text} is {'inside' if inside else 'also'} an input "
                            f"({_option(other, other in positionals)}{' ' + str(p) if inside else ''}): it would "
                            f"{'change what the input holds' if inside else 'be overwritten'}; give another path")


_MEDIA = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".mp4", ".avi", ".mkv", ".mov"}
"""What a folder given as an input holds for the readers: an output may not replace one of them there (a rig file
written again beside its calibration images may)."""


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def report_left_out(left_out: list[str], out: Path | str) -> int:
    """The exit status of a command that read a folder: each image it left out (:func:`open_frames`'s
    ``left_out``) on one line of stderr, and 1 if any was, though ``out`` holds every other image's rows."""
    for entry in left_out:
        print(f"kartpilot: left out {entry}", file=sys.stderr)
    if left_out:
        print(f"kartpilot: error: {len(left_out)} image(s) could not be used; {out} holds the others",
              file=sys.stderr)
    return 1 if left_out else 0

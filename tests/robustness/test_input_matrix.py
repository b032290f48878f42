"""Every bad file on every input argument (issue 56): the arguments come from the CLI's own definitions (those
typed ``values.input_path`` or ``values.config_path``), so a new command's inputs are tried without a line here.
Each is given a path that does not exist, a folder, a file of random bytes, an empty file (not for a YAML config,
where empty means the defaults), a name that is not UTF-8, a named pipe (a reader that opens it waits for good), a
loop of symbolic links, UTF-16 text, text with a byte-order mark and Windows line ends whose keys nothing knows,
brackets nested 100,000 deep, a YAML cut off mid-line, a PNG cut off in its data and one whose header claims 3.6
gigapixels, and (where the tests do not run as root) a file nobody may read; every required argument beside it gets
the same, and the outputs a scratch folder. Each case must end at once with exit 1 (or 2, a usage error), a last line of
``kartpilot: ...`` or a usage error, and no traceback. A 60 s alarm catches a command that goes on with a bad input
instead (one did: the teach-and-repeat experiment waited for good on a track that did not exist)."""

from __future__ import annotations

import argparse
import os
import signal
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from tests.conftest import subcommands

from kartpilot.cli import values
from kartpilot.cli.main import build_parser, main

KINDS = ("missing", "folder", "garbage", "empty", "not utf-8", "fifo", "symlink loop", "utf-16", "bom crlf",
         "nested bomb", "cut text", "cut png", "huge header") + (("unreadable",) if os.geteuid() != 0 else ())
"""The kinds of bad file; ``unreadable`` only where the tests do not run as root (root reads every file)."""


def _png(width: int = 64, height: int = 48) -> bytes:
    """A small PNG of noise, its header then saying ``width`` x ``height`` (the header's CRC made right again)."""
    image = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    data = bytearray(cv2.imencode(".png", image)[1].tobytes())
    data[16:24] = struct.pack(">II", width, height)  # IHDR's width and height
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    return bytes(data)


COMMANDS = subcommands(build_parser())


def _inputs() -> list[tuple[str, str]]:
    """(the command's words, the input argument's option or name) of every input argument of every command."""
    return [(command, action.option_strings[0] if action.option_strings else action.dest)
            for command, parser in COMMANDS.items() for action in parser._actions
            if action.type in (values.input_path, values.config_path)]


INPUTS = _inputs()


def _bad(tmp: Path, kind: str) -> str:
    if kind == "missing":
        return str(tmp / "no-such-input.yaml")
    if kind == "folder":
        (tmp / "a-folder").mkdir(exist_ok=True)
        return str(tmp / "a-folder")
    if kind == "fifo":  # a reader that opens it waits for a writer for good
        if not (tmp / "a-fifo").exists():
            os.mkfifo(tmp / "a-fifo")
        return str(tmp / "a-fifo")
    if kind == "symlink loop":
        if not (tmp / "loop-a").is_symlink():
            (tmp / "loop-a").symlink_to(tmp / "loop-b")
            (tmp / "loop-b").symlink_to(tmp / "loop-a")
        return str(tmp / "loop-a")
    contents = {"garbage": os.urandom(512), "empty": b"", "not utf-8": b": [\n",
                "utf-16": "speed_mps: 1.0\nname: x\n".encode("utf-16"),
                "bom crlf": b"\xef\xbb\xbfno_such_key: 1\r\nnor_this: [1, 2]\r\n",
                "nested bomb": b"[" * 100_000 + b"]" * 100_000,
                "cut text": b"name: x\nitems: [1, 2\nspeed_m",  # a YAML, JSON or CSV cut off mid-line
                "cut png": _png()[:300],  # an image cut off in its data
                "huge header": _png(60_000, 60_000),  # 3.6 gigapixels by its header
                "unreadable": b"name: x\n"}
    suffix = ".png" if kind in ("cut png", "huge header") else ".yaml"
    name = os.fsdecode(b"input-\xff.yaml") if kind == "not utf-8" else f"{kind.replace(' ', '-')}{suffix}"
    (tmp / name).write_bytes(contents[kind])
    if kind == "unreadable":
        (tmp / name).chmod(0)
    return str(tmp / name)


def _argv(command: str, target: str, bad: str, tmp: Path, output: str | None = None) -> list[str]:
    """The command with ``bad`` in ``target`` and in every required input, ``output`` (default: a scratch file) in
    every required output, a choice's first."""
    parser = COMMANDS[command]
    argv = command.split()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction) or action.dest == "help":
            continue
        mine = (action.option_strings[0] if action.option_strings else action.dest) == target
        if not mine and action.option_strings and not action.required:
            continue
        if mine or action.type in (values.input_path, values.config_path) or (action.type is None \
                and action.choices is None):
            value = bad
        elif action.choices is not None:
            value = sorted(action.choices)[0]
        else:
            value = output or str(tmp / "out" / "result.txt")
        argv += [action.option_strings[0], value] if action.option_strings else [value]
    return argv


def _ends_in_one_line(code: int, capsys: pytest.CaptureFixture[str], case: str) -> None:
    """The command ended with exit 1 or 2 and a last line ``kartpilot: ... error ...``, no traceback."""
    err = capsys.readouterr().err.strip().splitlines()
    assert code in (1, 2), f"{case} exited {code}"
    assert err and not any("Traceback" in line for line in err), f"{case}: {err}"
    assert err[-1].startswith("kartpilot") and "error" in err[-1], f"{case}: {err[-1]}"


class _HangError(Exception):
    pass


def _hang(*_: object) -> None:
    raise _HangError


@pytest.mark.parametrize(("command", "target"), INPUTS, ids=[f"{c} {t}" for c, t in INPUTS])
def test_every_bad_file_on_every_input_is_one_line(tmp_path, capsys, command, target):
    parser = COMMANDS[command]
    config = any(a.type is values.config_path and (a.option_strings or [a.dest])[0] == target
                 for a in parser._actions)
    previous = signal.signal(signal.SIGALRM, _hang)
    try:
        for kind in KINDS:
            if kind == "empty" and config:
                continue  # an empty YAML config is the defaults
            argv = _argv(command, target, _bad(tmp_path, kind), tmp_path)
            signal.alarm(60)
            try:
                code = main(argv)
            except _HangError:
                pytest.fail(f"{' '.join(argv)}: still running after 60 s with a bad input")
            finally:
                signal.alarm(0)
            _ends_in_one_line(code, capsys, f"{kind}: {argv}")
    finally:
        signal.signal(signal.SIGALRM, previous)


def test_the_matrix_covers_the_commands_that_read_files():
    """Each command that takes a file or folder in is in the matrix (its arguments are typed as inputs)."""
    commands = {c for c, _ in INPUTS}
    for command in ("odometry kitti", "eval trajectory", "lanes", "detect", "calibrate ground", "replay",
                    "recordings info", "places query", "drive", "sim", "study run"):
        assert command in commands, command


def _onto_input(command: str, target: str, kept: Path, tmp: Path) -> list[str]:
    """The command with ``kept`` as the input ``target`` and as every output it names (its folder-typed ones too)."""
    argv = _argv(command, target, str(kept), tmp, output=str(kept))
    for action in COMMANDS[command]._actions:
        if action.type in values.OUTPUT_TYPES and action.option_strings and not action.required:
            argv += [action.option_strings[0], str(kept)]
    return argv


OUTPUT_COMMANDS = [(c, t) for c, t in INPUTS if any(a.type in values.OUTPUT_TYPES for a in COMMANDS[c]._actions)]


@pytest.mark.parametrize(("command", "target"), OUTPUT_COMMANDS, ids=[f"{c} {t}" for c, t in OUTPUT_COMMANDS])
def test_an_output_onto_an_input_is_refused_and_the_input_kept(tmp_path, capsys, command, target):
    """The matrix's last kind: a path that is an input and the command's outputs at once. The command ends with one
    line and the file is as it was (the guard of ``values.check_paths``, or the output's own type)."""
    kept = tmp_path / "input.yaml"
    kept.write_bytes(b"name: kept\n")
    argv = _onto_input(command, target, kept, tmp_path)
    _ends_in_one_line(main(argv), capsys, str(argv))
    assert kept.read_bytes() == b"name: kept\n", f"{argv} changed its input"

"""Kinds of bad input checked once where they enter: where outputs go (one of the inputs, a file inside an input
folder, two outputs on one path), what kind of file (a named pipe, a name that is not UTF-8), and text written by
other tools (a byte-order mark, Windows line ends) read as plain text by every text reader."""

from __future__ import annotations

import os
import sys

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kartpilot.cli.main import main
from kartpilot.core.errors import DataError
from kartpilot.core.files import parse_yaml, read_text_file
from kartpilot.runtime.config import load_stack_config
from kartpilot.sensors.base import read_image


@pytest.fixture()
def photos(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    image = np.full((120, 160, 3), 120, np.uint8)
    cv2.imwrite(str(folder / "a.png"), image)
    return folder


def _refused(capsys, argv: list[str], says: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    print(err)
    assert err.startswith("kartpilot: error:") and says in err and len(err.splitlines()) == 1


def test_an_output_that_is_an_input_or_inside_an_input_folder_is_refused_and_the_file_kept(photos, capsys):
    before = (photos / "a.png").read_bytes()
    _refused(capsys, ["detect", str(photos / "a.png"), "--out", str(photos / "a.png")], "also an input")
    _refused(capsys, ["detect", str(photos), "--out", str(photos / "a.png")], "inside an input")
    assert (photos / "a.png").read_bytes() == before


def test_an_output_inside_an_input_recording_or_onto_a_named_input_is_refused(photos, tmp_path, capsys):
    """Issue 56: an output among a recording's own files (not only its images), a new file written into a
    recording, and an output on a camera's image given as NAME=FILE are all refused, and the files kept."""
    recording = tmp_path / "rec"
    (recording / "cameras").mkdir(parents=True)
    (recording / "manifest.json").write_text("{}")
    (recording / "commands.csv").write_text("stamp_ns,steer_rad,throttle,brake\n")
    before = (recording / "commands.csv").read_bytes()
    _refused(capsys, ["can", "monitor", "--recording", str(recording), "--json", str(recording / "commands.csv")],
             "inside an input")
    _refused(capsys, ["replay", str(recording), "--pipeline", "lanes", "--out", str(recording / "replayed")],
             "inside an input")
    assert (recording / "commands.csv").read_bytes() == before and not (recording / "replayed").exists()
    image = photos / "a.png"
    kept = image.read_bytes()
    _refused(capsys, ["calibrate", "ground", "--image", f"center={image}", "--out", str(image)], "also an input")
    assert image.read_bytes() == kept


def test_two_outputs_on_one_path_are_refused(photos, tmp_path, capsys):
    _refused(capsys, ["detect", str(photos), "--out", str(tmp_path / "o.csv"), "--overlay", str(tmp_path / "o.csv")],
             "the same path")
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes are POSIX")
def test_a_named_pipe_is_refused_without_hanging(tmp_path, capsys):
    pipe = tmp_path / "frames"
    os.mkfifo(pipe)
    _refused(capsys, ["detect", str(pipe), "--out", str(tmp_path / "o.csv")], "not a regular file")
    with pytest.raises(Exception, match="not a regular file"):
        read_text_file(pipe)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX file names are bytes")
def test_a_file_name_that_is_not_utf8_is_refused_on_the_command_line_and_read_by_the_reader(photos, capsys):
    name = os.fsdecode(b"caf\xe9.png")  # Latin-1, as an old camera or a Windows share names it
    os.rename(photos / "a.png", photos / name)
    assert read_image(photos / name).shape == (120, 160, 3)  # OpenCV's own reader fails on it
    _refused(capsys, ["detect", str(photos / name), "--out", str(photos.parent / "o.csv")], "not valid UTF-8")


@settings(max_examples=30, deadline=None, derandomize=True, database=None)
@given(bom=st.booleans(), crlf=st.booleans(), speed=st.floats(0.5, 8.0))
def test_a_config_written_by_another_tool_reads_as_the_same_config(tmp_path_factory, bom, crlf, speed):
    text = f"lane_policy:\n  speed_mps: {speed}\n"
    if crlf:
        text = text.replace("\n", "\r\n")
    data = (b"\xef\xbb\xbf" if bom else b"") + text.encode()
    path = tmp_path_factory.mktemp("cfg") / "kart.yaml"
    path.write_bytes(data)
    assert load_stack_config(path, "kart").lane_policy.speed_mps == pytest.approx(speed)


BILLION_LAUGHS = "".join(
    [f"{name}: &{name} [{', '.join(['*' + prev if prev else 'lol'] * 10)}]\n"
     for prev, name in zip(["", "a", "b", "c", "d", "e", "f", "g"], "abcdefgh", strict=True)])


@pytest.mark.parametrize("text", [BILLION_LAUGHS, "x: " + "[" * 3000 + "]" * 3000 + "\n"])
def test_a_yaml_that_expands_or_nests_without_end_is_refused_with_one_line(tmp_path, capsys, text):
    path = tmp_path / "kart.yaml"
    path.write_text(text)
    with pytest.raises(Exception, match=r"expand to more than|nested too deeply") as caught:
        load_stack_config(path, "kart")
    assert "kart.yaml" in str(caught.value)
    # through the command line: one line, nothing written
    assert main(["sim", "--config", str(path), "--result", str(tmp_path / "r.json"), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("kartpilot: error:") and len(err.splitlines()) == 1
    assert not (tmp_path / "r.json").exists()


def test_aliases_that_stay_small_still_read():
    from kartpilot.core.files import parse_yaml

    assert parse_yaml("base: &b {speed_mps: 2.0}\nfast: *b\n", "x.yaml") == {"base": {"speed_mps": 2.0},
                                                                            "fast": {"speed_mps": 2.0}}


def test_an_option_is_an_output_or_an_input_by_its_own_command(photos, capsys):
    """`sim --video` writes a video and `calibrate mono --video` reads one: the guard judges each by its own
    command, so the video read is an input that an output may not overwrite (it was taken for a second output)."""
    video = photos.parent / "board.avi"
    video.write_bytes(b"not really a video")
    _refused(capsys, ["calibrate", "mono", "--video", str(video), "--out", str(video)], "also an input (--video)")
    assert video.read_bytes() == b"not really a video"


def test_a_yaml_cut_off_is_one_line_saying_where_and_a_folder_given_for_a_file_is_named_a_folder(tmp_path, capsys):
    """PyYAML's error is an excerpt of the file over several lines; a command's error is one. And a folder given
    where a rig or a config file is wanted was answered "not found" for a path that exists."""
    from kartpilot.cli.main import main

    cut = tmp_path / "cut.yaml"
    cut.write_text("cameras:\n  center: {width_px: 640")
    (tmp_path / "folder").mkdir()
    for argv, said in ((["sim", "--track", "straight20", "--config", str(cut)], "at line 2, column 25"),
                       (["lidar", "monitor", "--recording", str(tmp_path / "folder")], "not a kartpilot recording"),
                       (["sim", "--track", "straight20", "--config", str(tmp_path / "folder")], "is a folder"),
                       (["calibrate", "lidar", str(tmp_path), "--rig", str(tmp_path / "folder"), "--board", "7x5",
                         "--out", str(tmp_path / "out.yaml")], "is a folder")):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and said in err, err
    assert not (tmp_path / "out.yaml").exists()


def test_brackets_in_yaml_strings_and_comments_do_not_count_as_nesting_but_deep_flow_does():
    """The nesting bound counts flow brackets only: 300 of them inside quoted scalars and comments read as they
    are; 300 nested flow collections are refused by the count, before PyYAML's scanner (quadratic in the nesting)
    sees them, and a nesting within the bound reads."""
    text = ("a: \"" + "[" * 300 + "\"\nb: '" + "{" * 300 + "'\n# " + "[" * 300 + "\nc: [[1]] # " + "{" * 300 + "\n")
    assert parse_yaml(text, "quoted.yaml") == {"a": "[" * 300, "b": "{" * 300, "c": [[1]]}
    assert parse_yaml("x: " + "[" * 90 + "]" * 90 + "\n", "deep.yaml")["x"] is not None
    with pytest.raises(DataError, match=r"deep\.yaml: nested too deeply"):
        parse_yaml("x: " + "[" * 300 + "]" * 300 + "\n", "deep.yaml")

"""Every file reader, fed arbitrary bytes and near-valid text (Hypothesis, fixed seed and budget): it returns an
object or raises one KartpilotError, never another exception."""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from kartpilot.actuation.kartpilot_protocol import load_dbc
from kartpilot.calibration.rig import load_rig
from kartpilot.core.errors import KartpilotError
from kartpilot.core.trajectory import read_kitti_poses, read_tum
from kartpilot.odometry.places import load_places
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.config import load_stack_config
from kartpilot.sensors.kitti import read_kitti_calib
from kartpilot.sim.track import load_track

FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])

# pieces of the real formats, so the fuzzer gets past the first line often
TOKENS = ["stereo_vo:", "  max_speed_mps: 3", "cameras:", "  left:", "    fx_px: 700", "P0: 1 0 0 0 1 0 0 0 1 0 0 0",
          "1 0 0 0 0 1 0 0 0 0 1 0", "0.1 0 0 0 0 0 0 1", "# comment", ".nan", "-.inf", "1e309", "[1, 2", "{a: }",
          "stamp_ns,steer_rad,throttle,brake", "10,0.1,0.2,0", "nan,x,,", "name: t", "width_m: -3", "\x00", "é",
          "points:", "  - [0, 0]", "    - 1", "\t", "", 'VERSION ""', "BO_ 256 Command: 8 Vector__XXX",
          ' SG_ Counter : 0|4@1+ (1,0) [0|15] "" Vector__XXX', "BU_: Kart"]
TEXT = st.lists(st.sampled_from(TOKENS) | st.text(max_size=20), max_size=12).map("\n".join)
BYTES = st.binary(max_size=300)


def _check(read: Callable[[Path], Any], name: str, content: bytes) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / name
        path.write_bytes(content)
        with contextlib.suppress(KartpilotError):
            read(path)


def _recording(path: Path) -> Any:
    """A recording folder whose manifest is the fuzzed file, with a frame list and commands beside it."""
    folder = path.parent / "rec"
    (folder / "cameras" / "center").mkdir(parents=True)
    path.rename(folder / "manifest.json")
    reader = RecordingReader(folder)
    for camera in reader.cameras:
        reader.frames(camera)
    return reader.commands()


def _commands(path: Path) -> Any:
    folder = path.parent / "rec"
    (folder / "cameras" / "center").mkdir(parents=True)
    (folder / "manifest.json").write_text('{"format": "kartpilot-recording", "version": 1, "cameras": {}}')
    path.rename(folder / "commands.csv")
    try:
        reader = RecordingReader(folder)
    except KartpilotError:
        pytest.fail("the minimal manifest should open")
    return reader.commands()


READERS: dict[str, tuple[Callable[[Path], Any], str]] = {
    "stack config": (load_stack_config, "stack.yaml"),
    "rig": (load_rig, "rig.yaml"),
    "track": (load_track, "track.yaml"),
    "TUM trajectory": (read_tum, "t.tum"),
    "KITTI poses": (read_kitti_poses, "t.txt"),
    "KITTI calib": (read_kitti_calib, "calib.txt"),
    "place database": (load_places, "places.npz"),
    "recording manifest": (_recording, "manifest.json"),
    "DBC": (load_dbc, "kart.dbc"),
}


@pytest.mark.parametrize("reader", sorted(READERS))
@seed(20261123)
@FUZZ
@given(text=TEXT)
def test_a_reader_given_near_valid_text_returns_or_raises_one_known_error(reader, text):
    read, name = READERS[reader]
    _check(read, name, text.encode("utf-8", "surrogatepass"))


@pytest.mark.parametrize("reader", sorted(READERS))
@seed(20261123)
@FUZZ
@given(content=BYTES)
def test_a_reader_given_arbitrary_bytes_returns_or_raises_one_known_error(reader, content):
    read, name = READERS[reader]
    _check(read, name, content)


@seed(20261123)
@FUZZ
@given(text=TEXT)
def test_recorded_commands_are_read_or_refused_naming_the_line(text):
    _check(_commands, "commands.csv", text.encode("utf-8", "surrogatepass"))

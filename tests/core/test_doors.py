"""The doors every input file comes through (issue 56): the image reader's pixel budget from the header, its
folder and format handling; the JSON reader's nesting bound; the CSV readers' line numbers; text from other
tools (a byte-order mark, Windows line ends, a header line) read as ours."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from kartpilot.core.errors import DataError, PlanningError
from kartpilot.core.files import iter_csv_file, parse_csv, parse_json, read_json_file, read_text_file
from kartpilot.core.images import MAX_IMAGE_PIXELS, image_size_from_header, read_image


def _png_claiming(width: int, height: int) -> bytes:
    """A few hundred bytes of PNG whose header says ``width`` x ``height``: a decompression bomb's shape."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    chunk = lambda kind, data: struct.pack(">I", len(data)) + kind + data + struct.pack(  # noqa: E731
        ">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    rows = zlib.compress(b"\x00" * 64)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")


def test_an_image_larger_than_the_budget_by_its_header_is_refused_before_decoding(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(_png_claiming(60_000, 60_000))
    assert bomb.stat().st_size < 1000
    with pytest.raises(DataError, match=r"60000x60000 px by its header: more than the 50 megapixels"):
        read_image(bomb)
    assert MAX_IMAGE_PIXELS < 60_000 * 60_000


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".bmp"])
def test_the_header_gives_the_size_of_each_common_format(suffix: str) -> None:
    ok, encoded = cv2.imencode(suffix, np.zeros((480, 848, 3), np.uint8))
    assert ok and image_size_from_header(encoded.tobytes()) == (848, 480)


def test_a_folder_a_png_named_jpg_and_a_missing_file(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="is a folder, not an image file"):
        read_image(tmp_path)
    with pytest.raises(DataError, match="image not found"):
        read_image(tmp_path / "none.png")
    named = tmp_path / "really-a-png.jpg"
    named.write_bytes(cv2.imencode(".png", np.full((64, 64, 3), 200, np.uint8))[1].tobytes())
    assert read_image(named).shape == (64, 64, 3)
    with pytest.raises(DataError, match="is a folder, not a file"):
        read_text_file(tmp_path)


def test_json_nested_beyond_the_bound_is_one_clear_error_and_nan_is_read_unless_refused(tmp_path: Path) -> None:
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(DataError, match=r"deep.json: nested more than 100 deep"):
        read_json_file(deep)
    assert parse_json('{"a": NaN}', "x")["a"] != parse_json('{"a": NaN}', "x")["a"]  # NaN, as Python wrote it
    with pytest.raises(DataError, match="NaN is not a JSON number"):
        parse_json('{"a": NaN}', "x", allow_nan=False)
    with pytest.raises(DataError, match=r"x: not valid JSON \(line 2, column 1"):
        parse_json('{"a": 1,\n}', "x")


def test_csv_rows_of_another_width_are_named_by_line(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    path.write_bytes(b"\xef\xbb\xbfstamp_ns,x\r\n1,2\r\n3,4,5\r\n")
    rows = iter_csv_file(path)
    assert next(iter(rows)) == {"stamp_ns": "1", "x": "2"}  # the byte-order mark is not part of the first name
    with pytest.raises(DataError, match=r"log.csv, line 3: not the header's 2 fields"):
        list(iter_csv_file(path))
    assert [r["x"] for r in iter_csv_file(path, skip_torn=True)] == ["2"]
    with pytest.raises(DataError, match=r"t.csv: no column y in its header \(a, b\)"):
        parse_csv("a,b\n1,2\n", "t.csv", required=["y"])


def test_kitti_times_with_a_header_line_and_a_bad_line(tmp_path: Path) -> None:
    from kartpilot.sensors.kitti import read_times

    times = tmp_path / "times.txt"
    times.write_text("time_s\n0.0\n0.1\n\n0.2\n")
    assert read_times(times).tolist() == [0.0, 0.1, 0.2]
    times.write_text("0.0\n0.1\nabc\n")
    with pytest.raises(DataError, match=r"times.txt, line 3: 'abc' is not a time in seconds"):
        read_times(times)


def test_a_reference_path_csv_from_a_spreadsheet_reads_as_ours(tmp_path: Path) -> None:
    """A byte-order mark and Windows line ends (a spreadsheet's export); a short row is named by its line."""
    from kartpilot.planning.reference_path import COLUMNS, load_reference_path

    rows = ["0,0,0,0,0,1", "1,1,0,0,0,1", "2,2,0,0,0,1"]
    path = tmp_path / "ref.csv"
    path.write_bytes(("\ufeff" + ",".join(COLUMNS) + "\r\n" + "\r\n".join(rows) + "\r\n").encode("utf-8"))
    assert len(load_reference_path(path).x_m) == 3
    path.write_text(",".join(COLUMNS) + "\n" + rows[0] + "\n1,1\n")
    with pytest.raises(PlanningError, match=r"ref.csv, line 3: not the header's 6 fields"):
        load_reference_path(path)

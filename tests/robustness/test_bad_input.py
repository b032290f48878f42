"""Bad input through the real CLI: each case exits non-zero with one line starting with ``kartpilot:``, no
traceback, and leaves every file that was there before byte-identical.

The cases fail before any work is done (a usage error: exit 2) or on the input itself (exit 1), so the whole
module runs in seconds."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from kartpilot.cli.main import main

# {d}: a scratch folder holding files a user already had; see _workspace
CASES: list[tuple[str, list[str], int]] = [
    # numbers: finite, in range, refused by name
    ("speed NaN", ["sim", "--speed", "nan"], 2),
    ("speed infinite", ["sim", "--speed", "inf"], 2),
    ("speed negative", ["sim", "--speed", "-1"], 2),
    ("speed not a number", ["sim", "--speed", "fast"], 2),
    ("speed above the kart's top speed", ["sim", "--vehicle", "sdc-kart", "--speed", "1000"], 1),
    ("rate zero", ["sim", "--rate", "0"], 2),
    ("laps zero", ["sim", "--laps", "0"], 2),
    ("seed negative", ["sim", "--seed", "-3"], 2),
    ("seed not an integer", ["sim", "--seed", "1.5"], 2),
    ("weave negative", ["sim", "--weave", "-0.1"], 2),
    ("speed mode negative", ["sim", "--speed-mode", "-15"], 2),
    ("duration zero", ["drive", "--sim", "sdc-assen", "--duration", "0"], 2),
    ("duration negative", ["drive", "--sim", "sdc-assen", "--duration", "-5"], 2),
    ("duration NaN", ["drive", "--sim", "sdc-assen", "--duration", "nan"], 2),
    ("web port out of range", ["drive", "--live", "{d}/rig.yaml", "--web", "70000"], 2),
    ("drive rate NaN", ["drive", "--sim", "sdc-assen", "--rate", "nan"], 2),
    ("drive speed infinite", ["drive", "--sim", "sdc-assen", "--speed", "inf"], 2),
    ("disparity threshold negative", ["disparity", "{d}/pair", "--threshold", "-1"], 2),
    ("frames as a float", ["odometry", "synthetic", "--frames", "1e99", "--out", "{d}/t.txt"], 2),
    ("frames huge", ["odometry", "synthetic", "--frames", "10000000", "--out", "{d}/t.txt"], 2),
    ("odometry camera height zero", ["odometry", "kitti", "{d}", "--mono", "--camera-height", "0", "--out",
                                     "{d}/t.txt"], 2),
    ("odometry pitch NaN", ["odometry", "kitti", "{d}", "--mono", "--camera-height", "1.6", "--camera-pitch-down",
                            "nan", "--out", "{d}/t.txt"], 2),
    ("pitch beyond a right angle", ["recordings", "import-kitti", "{d}", "--sequence", "06", "--out", "{d}/new",
                                    "--camera-height", "1.6", "--camera-pitch-down", "100"], 2),
    ("kitti camera height zero", ["recordings", "import-kitti", "{d}", "--sequence", "06", "--out", "{d}/new",
                                  "--camera-height", "0"], 2),
    ("tub field of view beyond 179", ["recordings", "import-tub", "{d}", "--out", "{d}/new", "--fov-deg", "180"], 2),
    ("board square zero", ["calibrate", "mono", "{d}/keep.txt", "--square", "0", "--out", "{d}/rig.yaml"], 2),
    ("can monitor every zero", ["can", "monitor", "--recording", "{d}", "--every", "0"], 2),
    ("places radius zero", ["places", "query", "{d}/keep.txt", "{d}/keep.txt", "--radius", "0"], 2),
    ("experiment speed zero", ["experiment", "teach-repeat", "--speed", "0", "--out", "{d}/exp"], 2),
    # outputs: checked before the work, never over a folder, a device or a user's files
    ("out is a folder", ["odometry", "synthetic", "--out", "{d}"], 2),
    ("out in a missing folder", ["odometry", "synthetic", "--out", "{d}/missing/t.txt"], 2),
    ("json in a missing folder", ["odometry", "synthetic", "--out", "{d}/t.txt", "--json", "{d}/missing/s.json"], 2),
    ("plot is a folder", ["odometry", "synthetic", "--out", "{d}/t.txt", "--plot", "{d}/full"], 2),
    ("json is a device", ["odometry", "synthetic", "--out", "{d}/t.txt", "--json", "/dev/full"], 2),
    ("empty out", ["odometry", "synthetic", "--out", ""], 2),
    ("eval plot in a missing folder", ["eval", "trajectory", "--gt", "{d}/gt.txt", "--est", "{d}/gt.txt", "--plot",
                                       "{d}/missing/p.png"], 2),
    ("sim record into a user's folder", ["sim", "--record", "{d}/full"], 2),
    ("sim record onto a file", ["sim", "--record", "{d}/keep.txt"], 2),
    ("sim video is a folder", ["sim", "--video", "{d}/full"], 2),
    ("drive record into a user's folder", ["drive", "--sim", "sdc-assen", "--record", "{d}/full"], 2),
    ("drive result in a missing folder", ["drive", "--sim", "sdc-assen", "--result", "{d}/missing/r.json"], 2),
    ("replay out into a user's folder", ["replay", "{d}", "--out", "{d}/full"], 2),
    ("export onto a file", ["recordings", "export", "{d}", "--out", "{d}/keep.txt"], 2),
    ("export into a user's folder", ["recordings", "export", "{d}", "--out", "{d}/full"], 2),
    ("tub import into a user's folder", ["recordings", "import-tub", "{d}", "--out", "{d}/full"], 2),
    ("lanes overlay into a user's folder", ["lanes", "{d}/keep.png", "--out", "{d}/l.csv", "--overlay",
                                            "{d}/full"], 2),
    ("lanes csv is a folder", ["lanes", "{d}/keep.png", "--out", "{d}/full"], 2),
    ("places database in a missing folder", ["places", "build", "{d}", "--out", "{d}/missing/p.npz"], 2),
    ("places fixes csv is a folder", ["places", "query", "{d}/keep.txt", "{d}/keep.txt", "--out", "{d}/full"], 2),
    ("rig file is a folder", ["calibrate", "mono", "{d}/keep.txt", "--out", "{d}/full"], 2),
    ("reference path in a missing folder", ["reference", "{d}", "--out", "{d}/missing/path.csv"], 2),
    # inputs and configs: one line naming the problem
    ("kitti root missing", ["odometry", "kitti", "{d}/missing", "--out", "{d}/t.txt"], 1),
    ("recording missing", ["odometry", "recording", "{d}/missing", "--out", "{d}/t.txt"], 1),
    ("config not UTF-8", ["odometry", "synthetic", "--out", "{d}/t.txt", "--config", "{d}/latin1.yaml"], 1),
    ("config NaN", ["odometry", "synthetic", "--out", "{d}/t.txt", "--config", "{d}/nan.yaml"], 1),
    ("config infinity", ["odometry", "synthetic", "--out", "{d}/t.txt", "--config", "{d}/inf.yaml"], 1),
    ("config huge integer", ["odometry", "synthetic", "--out", "{d}/t.txt", "--config", "{d}/huge.yaml"], 1),
    ("config unknown key", ["odometry", "synthetic", "--out", "{d}/t.txt", "--config", "{d}/typo.yaml"], 1),
    ("config wrong type", ["odometry", "synthetic", "--out", "{d}/t.txt", "--config", "{d}/type.yaml"], 1),
    ("config not YAML", ["odometry", "synthetic", "--out", "{d}/t.txt", "--config", "{d}/keep.png"], 1),
    ("eval length mismatch without timestamps",
     ["eval", "trajectory", "--gt", "{d}/gt.txt", "--est", "{d}/short.txt"], 1),
    ("eval trajectory not UTF-8", ["eval", "trajectory", "--gt", "{d}/gt.txt", "--est", "{d}/latin1.yaml"], 1),
    ("eval trajectory with NaN", ["eval", "trajectory", "--gt", "{d}/gt.txt", "--est", "{d}/nan.txt"], 1),
    ("places database missing", ["places", "query", "{d}/missing.npz", "{d}/keep.png"], 1),
    ("places database not one", ["places", "query", "{d}/keep.txt", "{d}/keep.png"], 1),
    ("fault after the drive's end", ["drive", "--sim", "sdc-assen", "--pipeline", "lanes", "--duration", "5",
                                     "--inject", "camera-freeze@30"], 1),
    ("fault injected into a replay", ["drive", "--replay", "{d}", "--pipeline", "lanes", "--inject",
                                      "camera-freeze@3"], 1),
    ("track with a negative width", ["sim", "--track", "{d}/track.yaml", "--no-render"], 1),
    ("unknown subcommand", ["fly"], 2),
    ("unknown option", ["sim", "--warp", "9"], 2),
]
def _workspace(folder: Path) -> None:
    (folder / "keep.txt").write_text("a user's notes\n")
    (folder / "keep.png").write_bytes(b"\x89PNG\r\n\x1a\n not really an image")
    (folder / "full").mkdir()
    (folder / "full" / "mine.png").write_bytes(b"a user's image")
    (folder / "latin1.yaml").write_bytes("stereo_vo:\n  # caf\xe9\n".encode("latin-1"))
    (folder / "nan.yaml").write_text("stereo_vo:\n  motion_limits: {max_speed_mps: .nan}\n")
    (folder / "inf.yaml").write_text("stereo_vo:\n  motion_limits: {max_speed_mps: .inf}\n")
    (folder / "huge.yaml").write_text("stereo_vo:\n  features:\n    max_features: 99999999999999999999\n")
    (folder / "track.yaml").write_text("name: bad\nwidth_m: -3\n")
    (folder / "typo.yaml").write_text("stereo_vo:\n  max_sped_mps: 3\n")
    (folder / "type.yaml").write_text("stereo_vo:\n  motion_limits: {max_speed_mps: fast}\n")
    row = " ".join(f"{v:g}" for v in np.eye(4)[:3].ravel())
    (folder / "gt.txt").write_text((row + "\n") * 51)
    (folder / "short.txt").write_text((row + "\n") * 10)
    (folder / "nan.txt").write_text((row + "\n") * 50 + row.replace("1", "nan", 1) + "\n")


def _snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize(("name", "argv", "code"), CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_and_loses_nothing(tmp_path, capsys, name, argv, code):
    _workspace(tmp_path)
    before = _snapshot(tmp_path)
    returned = main([a.replace("{d}", str(tmp_path)) for a in argv])
    out, err = capsys.readouterr()
    print(f"{name}: exit {returned}: {err.strip()}")
    assert returned == code, (out, err)
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("kartpilot:"), err
    assert "Traceback" not in out + err
    after = _snapshot(tmp_path)
    assert {k: v for k, v in after.items() if k in before} == before  # what the user had is untouched
    assert not [k for k in after if k not in before and (k.endswith(".partial") or "missing" in k)]

"""Record the figures the real-accuracy guard holds VO to (``tests/odometry/test_real_vo_guard.py``).

Run it on purpose only, when a change to VO makes a real clip better (or, with a reason, worse), and say why in
the commit: the guard then holds VO to the new figures.

    python benchmarks/real_vo_figures.py --data ../shared/data --out tests/data/real_vo_figures.json
"""

from __future__ import annotations

import argparse
import datetime
from pathlib import Path

import cv2

from common import write_json
from kartpilot.eval.vo_clips import guard_figures

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--out", type=Path, default=ROOT / "tests" / "data" / "real_vo_figures.json")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    write_json(args.out, {"date": datetime.date.today().isoformat(), "opencv": cv2.__version__,
                          "figures": guard_figures(args.data)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

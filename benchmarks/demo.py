"""What ``make demo`` costs after the install: ``kartpilot demo`` as a whole process, its wall time, what it wrote
(megabytes, files) and its verdicts.

    python benchmarks/demo.py --out docs/results/demo.json
    python benchmarks/demo.py --docs     # the sentence in README.md and docs/getting-started.md, from that JSON
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from common import write_json
from vo_table import put_at_marker

ROOT = Path(__file__).resolve().parents[1]
PAGES = (ROOT / "README.md", ROOT / "docs" / "getting-started.md")
MARKER = "demo-cost"


def render(results: dict[str, Any]) -> str:
    """One sentence for the README and the getting-started page, from the JSON :func:`main` writes."""
    minutes, seconds = divmod(round(results["wall_s"]), 60)
    return (f"On {results['machine']}, after the install, `kartpilot demo` took {minutes} min {seconds:02d} s on "
            f"{results['date']} and left {results['megabytes']:.0f} MB in {results['files']} files in `demo_out/`; "
            f"{results['passed']} of {results['scenarios']} scenarios passed, and the small kart's repeat "
            f"{'finished' if results['repeat_finished'] else 'did not finish'} (`benchmarks/demo.py`).\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/results/demo.json")
    parser.add_argument("--docs", action="store_true", help="only put the sentence from --out into the docs")
    args = parser.parse_args()
    if args.docs:
        results = json.loads(Path(args.out).read_text(encoding="utf-8"))
        for page in PAGES:
            put_at_marker(page, render(results), MARKER)
        return 0
    exe = shutil.which("kartpilot", path=str(Path(sys.executable).parent)) or "kartpilot"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "demo_out"
        start = time.perf_counter()
        done = subprocess.run([exe, "demo", "--out", str(out)], capture_output=True, text=True)
        wall_s = time.perf_counter() - start
        print(done.stdout[-3000:], done.stderr[-2000:])
        sizes = {str(p.relative_to(out)): p.stat().st_size / 1e6 for p in out.rglob("*") if p.is_file()}
        verdicts = [json.loads(p.read_text())["scenarios"][0] for p in out.glob("*.json")]
        repeat = json.loads(next(out.glob("*-vo/result.json")).read_text())
    result = {"machine": f"{os.cpu_count()} cores, {sys.platform}, Python {sys.version.split()[0]}",
              "date": time.strftime("%Y-%m-%d"), "exit_code": done.returncode, "wall_s": wall_s,
              "megabytes": sum(sizes.values()), "files": len(sizes),
              "scenarios": len(verdicts), "passed": sum(v["passed"] for v in verdicts),
              "repeat_finished": bool(repeat["finished"]),
              "sizes_mb": {name: round(size, 2) for name, size in sorted(sizes.items())}}
    write_json(args.out, result)
    return 0 if done.returncode == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())

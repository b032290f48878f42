"""Regenerate the stored process-replay references after an intended change (see common.py)."""

from __future__ import annotations

import tempfile
from pathlib import Path

from tests.process_replay.common import COLUMNS, REFS, record_drive, replay, result_rows, write_rows


def main() -> None:
    REFS.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as temporary:
        for pipeline in COLUMNS:
            recording = record_drive(pipeline, Path(temporary) / f"{pipeline}-drive")
            out = Path(temporary) / f"{pipeline}-replay"
            replay(pipeline, recording, out)
            target = REFS / f"{pipeline}.csv"
            write_rows(result_rows(out), pipeline, target)
            print(f"wrote {target}")


if __name__ == "__main__":
    main()

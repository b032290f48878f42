"""Process replay: each pipeline's commands and outputs on a fixed recording, against stored ones."""

import pytest

from tests.process_replay.common import COLUMNS, REFS, differences, read_rows, record_drive, replay, result_rows


@pytest.mark.parametrize("pipeline", list(COLUMNS))
def test_the_pipeline_s_outputs_match_the_stored_ones(pipeline, tmp_path):
    recording = record_drive(pipeline, tmp_path / "drive")
    result = replay(pipeline, recording, tmp_path / "replay")
    rows = result_rows(tmp_path / "replay")
    stored = read_rows(REFS / f"{pipeline}.csv")
    found = differences(pipeline, stored, rows)
    print(f"{pipeline}: {len(rows)} sets replayed, {len(found)} values outside the tolerances")
    assert result.steps == len(rows) >= 30
    assert not found, "\n".join(found[:20]) + "\n(intended? regenerate: python -m tests.process_replay.update_refs)"

import json

import pytest
from tests.conftest import data_path

from kartpilot.core.errors import DataError
from kartpilot.sensors.donkeycar import DonkeyTub, is_donkey_tub


def test_the_shared_tub_reads_in_order_with_the_human_labels():
    tub = DonkeyTub(data_path("donkeycar-tub-track"))
    assert len(tub) == 3000
    indexes = [r.index for r in tub.records]
    assert indexes == sorted(indexes)
    assert all(-1.0 <= r.angle <= 1.0 for r in tub.records)
    assert any(r.angle != 0.0 for r in tub.records)
    first = next(tub.frames())
    assert first.images["center"].shape == (120, 160, 3)


def write_tub(folder, lines: list[str], deleted=()) -> None:
    (folder / "images").mkdir(parents=True)
    manifest = [["cam/image_array", "user/angle"], ["image_array", "float"], {}, {},
                {"paths": ["catalog_0.catalog"], "deleted_indexes": list(deleted)}]
    (folder / "manifest.json").write_text("\n".join(json.dumps(m) for m in manifest))
    (folder / "catalog_0.catalog").write_text("\n".join(lines))


def test_deleted_records_are_skipped_and_broken_ones_are_named(tmp_path):
    good = [json.dumps({"_index": i, "_timestamp_ms": 1000 + i, "cam/image_array": f"{i}.jpg", "user/angle": 0.1})
            for i in range(3)]
    write_tub(tmp_path / "ok", good, deleted=[1])
    assert is_donkey_tub(tmp_path / "ok")
    assert [r.index for r in DonkeyTub(tmp_path / "ok").records] == [0, 2]
    write_tub(tmp_path / "bad", [*good, "{not json"])
    with pytest.raises(DataError, match="line 4"):
        DonkeyTub(tmp_path / "bad")
    with pytest.raises(DataError, match="no manifest"):
        DonkeyTub(tmp_path / "nothing")


@pytest.mark.parametrize(("stamps", "word"), [((1000, 1050, 1050), "repeats"), ((1000, 1050, 990), "goes back")])
def test_a_tub_whose_time_does_not_follow_its_records_is_refused(tmp_path, stamps, word):
    lines = [json.dumps({"_index": i, "_timestamp_ms": t, "cam/image_array": f"{i}.jpg"}) for i, t in enumerate(stamps)]
    write_tub(tmp_path / "tub", lines)
    with pytest.raises(DataError, match=f"record 2's time stamp .* {word}"):
        DonkeyTub(tmp_path / "tub")

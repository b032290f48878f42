"""A study's parts without Ray: specs and their cells, jobs on the synthetic road, statistics and reports."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from kartpilot.core.errors import ConfigError
from kartpilot.odometry.two_view import rotation_angle_deg, two_view_motion
from kartpilot.perception.features import FeatureConfig
from kartpilot.perception.matching import MatchConfig
from kartpilot.perception.tracking import KltConfig
from kartpilot.sim.synthetic_stereo import SyntheticStereoConfig, SyntheticStereoSource
from kartpilot.study.jobs import JobContext, run_cell
from kartpilot.study.report import estimate, paired_effects, write_report
from kartpilot.study.spec import BUILT_IN, expand_cells, load_spec, parse_spec

PART = {"name": "p", "job": "stereo_vo", "sources": ["synthetic", "kitti-06"], "seeds": [1, 2, 3],
        "params": {"frames": 8},
        "variants": [{"name": "defaults"},
                     {"name": "band 2 px", "overrides": {"stereo_vo": {"stereo": {"epipolar_band_px": 2.0}}}},
                     {"name": "band 1 px", "overrides": {"stereo_vo": {"stereo": {"epipolar_band_px": 1.0}}}}],
        "quick": {"sources": ["synthetic"], "seeds": [1]}}


def _spec(**changes):
    return parse_spec({"name": "s", "parts": [{**PART, **changes}]}, "test")


def test_a_spec_expands_to_cells_and_equal_configurations_share_a_key():
    cells = expand_cells(_spec(), quick=False)
    # 3 variants x (3 synthetic seeds + one cell of the real dataset)
    assert len(cells) == 12
    assert {c.seed for c in cells if c.source == "kitti-06"} == {0}
    by_variant = {v: {c.key for c in cells if c.variant == v} for v in ("defaults", "band 2 px", "band 1 px")}
    assert by_variant["defaults"] == by_variant["band 2 px"]  # 2 px is the default: computed once
    assert not by_variant["defaults"] & by_variant["band 1 px"]
    assert len(expand_cells(_spec(), quick=True)) == 3


def test_a_sweep_is_a_cartesian_product_over_dotted_keys():
    spec = _spec(variants=None, sweep={"stereo_vo.matching.ratio": [0.6, 0.7], "stereo_vo.features.detector":
                                       ["orb", "sift", "akaze"]})
    cells = expand_cells(spec, quick=True)
    assert len(cells) == 6 and len({c.key for c in cells}) == 6
    assert {c.stack["stereo_vo"]["features"]["detector"] for c in cells} == {"orb", "sift", "akaze"}


@pytest.mark.parametrize(("change", "named"), [
    ({"variants": [{"name": "x", "overrides": {"stereo_vo": {"stereo": {"epipolar_px": 1}}}}]},
     "stereo_vo.stereo.epipolar_px"),
    ({"job": "no_such_job"}, "parts[0].job"),
    ({"seed": [1]}, "parts[0].seed"),
    ({"params": {"frames": -1}}, "params"),
    ({"sweep": {"stereo_vo.pnp.reprojection_px": []}}, "sweep.stereo_vo.pnp.reprojection_px"),
    ({"variants": [{"name": "x", "overrides": {"stereo_vo": {"matching": {"ratio": "high"}}}}]},
     "stereo_vo.matching.ratio"),
])
def test_a_mistake_in_a_spec_is_an_error_naming_the_key(change, named):
    with pytest.raises(ConfigError, match=named.replace(".", r"\.").replace("[", r"\[").replace("]", r"\]")):
        _spec(**change)


def test_every_built_in_study_loads_and_has_a_quick_size():
    for name in BUILT_IN:
        spec = load_spec(name)
        quick, full = (len({c.key for c in expand_cells(spec, q)}) for q in (True, False))
        assert 0 < quick < full, name
    with pytest.raises(ConfigError, match="unknown study"):
        load_spec("featurez")


def test_the_interval_is_students_t_over_the_seeds():
    values = [1.0, 2.0, 4.0, 3.5]
    e = estimate(values)
    low, high = stats.t.interval(0.95, 3, loc=np.mean(values), scale=stats.sem(values))
    assert e.n == 4 and e.mean == pytest.approx(np.mean(values)) and e.half_width == pytest.approx((high - low) / 2)
    assert math.isnan(estimate([2.0]).half_width) and estimate([math.nan]).n == 0


def test_effects_are_paired_by_source_and_seed():
    rows = [{"status": "ok", "variant": v, "source": "a", "seed": s, "drift_percent": d}
            for v, s, d in [("defaults", 1, 1.0), ("defaults", 2, 5.0), ("off", 1, 2.0), ("off", 2, 6.1)]]
    effect = paired_effects(rows, "drift_percent", "defaults")["off"]
    # the seeds differ by 4 points, the pairs by 1.0 and 1.1: a clear effect only when paired
    assert effect.mean == pytest.approx(1.05) and effect.half_width < 1.0


def _context(tmp_path: Path) -> JobContext:
    return JobContext(tmp_path / "data", tmp_path / "cache")


def test_stereo_vo_cell_on_the_synthetic_road_counts_where_its_points_are(tmp_path):
    cell = expand_cells(_spec(), quick=True)[0]
    row = run_cell(cell, _context(tmp_path))
    assert row["status"] == "ok", row["error"]
    assert row["frames"] == 8 and row["drift_percent"] < 5.0
    assert sum(map(sum, row["grid_counts"])) == row["final_points"] > 0
    assert sum(row["depth_counts"]) <= row["final_points"]  # points beyond 45 m are outside the histogram
    assert 0.0 <= row["near_share"] <= 1.0
    assert row["config_hash"] == cell.key and row["variant"] == "defaults"
    json.dumps(row)  # a row is plain data


def test_a_failing_cell_is_a_row_with_its_error(tmp_path):
    cells = expand_cells(_spec(sources=["kitti-06"]), quick=False)
    row = run_cell(cells[0], _context(tmp_path))
    assert row["status"] == "failed" and "data folder" in row["error"] and row["source"] == "kitti-06"


def test_two_view_motion_finds_the_synthetic_roads_motion():
    source = SyntheticStereoSource(SyntheticStereoConfig(frames=3, seed=2))
    truth = source.ground_truth().poses
    step = np.linalg.inv(truth[0]) @ truth[1]
    direction = step[:3, 3] / np.linalg.norm(step[:3, 3])
    for correspondence in ("descriptor", "klt"):
        motion = two_view_motion(source.frame(0).left, source.frame(1).left, source.rig.camera.matrix,
                                 FeatureConfig(), MatchConfig(), correspondence, KltConfig())
        assert motion.rotation is not None and motion.direction is not None
        assert motion.inliers > 100
        # recoverPose maps points of the first camera into the second: the motion is its inverse
        assert rotation_angle_deg(motion.rotation @ step[:3, :3]) < 0.2
        assert float(-motion.rotation.T @ motion.direction @ direction) > math.cos(math.radians(3))


def _rows(tmp_path: Path, rows: list[dict], report: str, questions: dict) -> Path:
    out = tmp_path / "study"
    out.mkdir()
    (out / "study.json").write_text(json.dumps({"name": "s", "title": "T", "report": report, "quick": True,
                                                "questions": questions}))
    (out / "rows.json").write_text(json.dumps({"rows": rows}))
    return out


def test_the_filters_report_ranks_a_clear_effect_and_leaves_noise_alone(tmp_path):
    rng = np.random.default_rng(0)
    rows = []
    for seed in range(1, 6):
        base = rng.normal(2.0, 1.0)
        for variant, group, effect in [("defaults", "defaults", 0.0), ("band off", "epipolar band", 3.0),
                                       ("bucketing off", "bucketing", 0.0)]:
            rows.append({"status": "ok", "variant": variant, "group": group, "source": "straight20", "seed": seed,
                         "part": "p", "drift_percent": base + effect + rng.normal(0, 0.1), "ate_m": 0.1})
    rows.append({"status": "failed", "variant": "band off", "group": "epipolar band", "source": "utrack",
                 "seed": 1, "part": "p", "error": "DataError: gone"})
    out = _rows(tmp_path, rows, "filters", {"RQ3": "Which filters matter?"})
    files = write_report(out)
    text = (out / "report.md").read_text()
    answer = text.split("**RQ3: Which filters matter?**")[1].split("##")[0]
    assert "worse, beyond the 95 % interval, with band off (3.0" in answer
    assert "No setting of bucketing moves the drift" in answer
    assert "DataError: gone" in text  # the failed cell is listed
    assert {f.name for f in files} >= {"report.md", "rows.csv", "filters_ranking.png"}


def test_the_command_refuses_an_unknown_study_or_a_typo_on_one_line_and_writes_nothing(tmp_path, capsys):
    from kartpilot.cli.main import main

    out = tmp_path / "out"
    assert main(["study", "run", "featurez", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("kartpilot: ") and "unknown study 'featurez'" in err and "\n" not in err
    spec = tmp_path / "typo.yaml"
    spec.write_text("name: t\nparts:\n  - {job: stereo_vo, sources: [synthetic], "
                    "variants: [{name: x, overrides: {stereo_vo: {pnp: {reprojection: 2}}}}]}\n")
    assert main(["study", "run", str(spec), "--out", str(out)]) == 1
    assert "stereo_vo.pnp.reprojection" in capsys.readouterr().err
    assert not out.exists()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    assert main(["study", "run", "features", "--out", str(tmp_path / "other")]) == 2  # not a study's folder
    assert "holds other files" in capsys.readouterr().err


def test_a_wobbled_reference_moves_sideways_smoothly_by_its_sigma():
    from kartpilot.study.jobs import wobbled

    xy = np.column_stack([np.arange(0.0, 400.0, 0.05), np.zeros(8000)])
    normals = np.tile([0.0, 1.0], (8000, 1))
    rng = np.random.default_rng(0)
    assert wobbled(xy, normals, 0.0, 1.0, rng) is xy
    moved = wobbled(xy, normals, 0.03, 1.0, rng)
    assert np.allclose(moved[:, 0], xy[:, 0])  # sideways only
    # sigma at the knots, a metre apart; linear in between, the spread along the path is sqrt(2/3) of it
    assert 0.7 * 0.03 < moved[:, 1].std() < 0.03
    assert np.abs(np.diff(moved[:, 1])).max() < 0.05 * 0.15  # no jumps between samples 5 cm apart

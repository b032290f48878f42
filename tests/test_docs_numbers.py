"""The numbers the README shows are the measured ones: each generated section equals what its script renders
from the committed JSON."""

import importlib.util
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):
    """A script of benchmarks/ as a module (its folder on the path, as when it runs)."""
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return module


def _vo_table():
    return _script("vo_table")


@pytest.mark.parametrize("page", ["README.md", "docs/results.md"])
def test_the_vo_accuracy_table_shown_is_the_measured_one(page: str) -> None:
    vo_table = _vo_table()
    results = json.loads((ROOT / "docs" / "results" / "vo_accuracy.json").read_text(encoding="utf-8"))
    text = (ROOT / page).read_text(encoding="utf-8")
    section = text[text.index(vo_table.START) + len(vo_table.START):text.index(vo_table.END)]
    assert section.strip() == vo_table.render(results).strip(), (
        f"{page}'s VO accuracy table differs from docs/results/vo_accuracy.json: run benchmarks/vo_table.py "
        "docs/results/vo_accuracy.json --out docs/results/vo_accuracy.md --into README.md docs/results.md")
    held_out = [row for row in results["rows"] if not row["tuned_on"]]
    assert held_out and any(row["kind"] == "simulated" for row in held_out)


def test_a_table_goes_between_the_markers_and_nowhere_else(tmp_path: Path) -> None:
    vo_table = _vo_table()
    page = tmp_path / "page.md"
    page.write_text(f"before\n{vo_table.START}\nold numbers\n{vo_table.END}\nafter\n")
    vo_table.put_between_markers(page, "| new |\n")
    assert page.read_text() == f"before\n{vo_table.START}\n| new |\n{vo_table.END}\nafter\n"
    (tmp_path / "bare.md").write_text("no markers\n")
    with pytest.raises(SystemExit, match="markers"):
        vo_table.put_between_markers(tmp_path / "bare.md", "| new |\n")


def test_every_stack_config_example_in_the_docs_is_valid() -> None:
    """A reader copies these: each YAML example that configures the stack must load, key for key."""
    import yaml

    from kartpilot.core.config import merge_config
    from kartpilot.runtime.config import StackConfig

    checked = 0
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for block in re.findall(r"```yaml\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S):
            data = yaml.safe_load(block)
            if isinstance(data, dict) and set(data) & {"stereo_vo", "drive", "lane_policy", "sim", "mono_vo"}:
                merge_config(StackConfig(), data)
                checked += 1
    assert checked >= 1


def _study_docs():
    return _script("study_docs")


STUDY_RESULTS = sorted((ROOT / "docs" / "results" / "study").glob("*.json"))


@pytest.mark.parametrize("results", STUDY_RESULTS, ids=[p.stem for p in STUDY_RESULTS])
def test_each_study_page_is_what_its_committed_rows_give(results: Path) -> None:
    data = json.loads(results.read_text(encoding="utf-8"))
    shown = (ROOT / "docs" / "study" / f"{results.stem}.md").read_text(encoding="utf-8")
    docs = _study_docs()
    assert shown == (docs.tune_page(data) if "trials" in data else docs.page(data)), (
        f"docs/study/{results.stem}.md differs from its rows: run benchmarks/study_docs.py on the study's folder")
    for figure in re.findall(r"\]\(\.\./figures/(study/[^)]+\.png)\)", shown):
        assert (ROOT / "docs" / "figures" / figure).is_file(), figure


def test_every_study_spec_in_the_docs_is_valid() -> None:
    import yaml

    from kartpilot.study.spec import parse_spec

    checked = 0
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        for block in re.findall(r"```yaml\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S):
            data = yaml.safe_load(block)
            if isinstance(data, dict) and "parts" in data:
                parse_spec(data, str(page))
                checked += 1
    assert checked >= 1


@pytest.mark.parametrize("page", ["README.md", "docs/study/index.md"])
def test_the_scaling_shown_is_the_measured_one(page: str) -> None:
    scaling = _script("study_scaling")
    results = json.loads((ROOT / "docs" / "results" / "study_scaling.json").read_text(encoding="utf-8"))
    text = (ROOT / page).read_text(encoding="utf-8")
    section = text[text.index(scaling.START) + len(scaling.START):text.index(scaling.END)]
    assert section.strip() == scaling.render(results).strip()


@pytest.mark.parametrize("marker", ["lane-ablation", "lane-race", "lane-speed", "tape-tracks"])
def test_the_lane_results_shown_are_the_measured_ones(marker: str) -> None:
    lane_docs = _script("lane_docs")
    name, render = lane_docs.SECTIONS[marker]
    results = json.loads((ROOT / "docs" / "results" / f"{name}.json").read_text(encoding="utf-8"))
    text = (ROOT / "docs" / "lanes.md").read_text(encoding="utf-8")
    start, end = f"<!-- {marker} -->", f"<!-- /{marker} -->"
    section = text[text.index(start) + len(start):text.index(end)]
    assert section.strip() == render(results).strip(), (
        f"docs/lanes.md's {marker} section differs from docs/results/{name}.json: run benchmarks/lane_docs.py")


def test_the_view_cost_shown_is_the_measured_one() -> None:
    view_cost = _script("view_cost")
    results = json.loads((ROOT / "docs" / "results" / "view_cost.json").read_text(encoding="utf-8"))
    text = view_cost.PAGE.read_text(encoding="utf-8")
    start, end = f"<!-- {view_cost.MARKER} -->", f"<!-- /{view_cost.MARKER} -->"
    assert text[text.index(start) + len(start):text.index(end)].strip() == view_cost.render(results).strip(), (
        "docs/viewing.md's view-cost table differs from docs/results/view_cost.json: run "
        "benchmarks/view_cost.py --docs")


@pytest.mark.parametrize(("script", "marker"), [("detect", "detection"), ("mono_drive", "mono-drive")])
def test_the_detection_and_one_camera_drive_tables_shown_are_the_measured_ones(script: str, marker: str) -> None:
    module = _script(script)
    results = json.loads((ROOT / "docs" / "results" / f"{script}.json").read_text(encoding="utf-8"))
    text = module.PAGE.read_text(encoding="utf-8")
    start, end = f"<!-- {marker} -->", f"<!-- /{marker} -->"
    assert text[text.index(start) + len(start):text.index(end)].strip() == module.render(results).strip(), (
        f"{module.PAGE.name}'s {marker} section differs from docs/results/{script}.json: run benchmarks/{script}.py "
        "--render")


def _section(page: Path, marker: str) -> str:
    text = page.read_text(encoding="utf-8")
    start, end = f"<!-- {marker} -->", f"<!-- /{marker} -->"
    return text[text.index(start) + len(start):text.index(end)].strip()


@pytest.mark.parametrize(("script", "result", "pages"), [
    ("startup", "startup", [("docs/contributing.md", "startup", "render")]),
    ("demo", "demo", [("README.md", "demo-cost", "render"), ("docs/getting-started.md", "demo-cost", "render")]),
    ("suite_profile", "suite_profile", [("docs/contributing.md", "suite-profile", "render"),
                                        ("README.md", "suite-time", "render_readme")]),
    ("web_crowd", "web_crowd", [("docs/real-kart.md", "web-crowd", "render")]),
    ("lidar", "lidar", [("docs/lidar.md", "lidar-cost", "render")]),
])
def test_the_start_up_demo_and_suite_times_shown_are_the_measured_ones(script: str, result: str,
                                                                       pages: list[tuple[str, str, str]]) -> None:
    """The README's and the docs' times of start-up, the demo and the test suite: each rendered by its script from
    its committed JSON (`python benchmarks/SCRIPT.py --docs`)."""
    module = _script(script)
    results = json.loads((ROOT / "docs" / "results" / f"{result}.json").read_text(encoding="utf-8"))
    for page, marker, render in pages:
        assert _section(ROOT / page, marker) == getattr(module, render)(results).strip(), (
            f"{page}'s {marker} section differs from docs/results/{result}.json: run benchmarks/{script}.py --docs")

"""The numbers the README shows are the measured ones: each generated section equals what its script renders
from the committed JSON."""

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _vo_table():
    spec = importlib.util.spec_from_file_location("vo_table", ROOT / "benchmarks" / "vo_table.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_readme_s_vo_accuracy_table_is_the_measured_one() -> None:
    vo_table = _vo_table()
    results = json.loads((ROOT / "docs" / "results" / "vo_accuracy.json").read_text(encoding="utf-8"))
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = readme[readme.index(vo_table.START) + len(vo_table.START):readme.index(vo_table.END)]
    assert section.strip() == vo_table.render(results).strip(), (
        "README.md's VO accuracy table differs from docs/results/vo_accuracy.json: run "
        "benchmarks/vo_table.py docs/results/vo_accuracy.json --out docs/results/vo_accuracy.md --into README.md")
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

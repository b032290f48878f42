"""Put studies' results into the docs: each study's rows (JSON), its figures, and its page, all from its folder.

    kartpilot study run features --quick --out runs/features
    python benchmarks/study_docs.py runs/features runs/filters ...

For a ``study tune`` folder: ``docs/results/study/NAME-tune.json`` and its page ``docs/study/NAME-tune.md``.
For each study folder: ``docs/results/study/NAME.json`` (the study's description and every row, what the
page is made from), ``docs/figures/study/NAME/*.png`` and ``docs/study/NAME.md`` (the report, without its
every-metric table, with the figures' paths into ``docs/figures``). ``tests/test_docs_numbers.py`` checks
that each page is what ``page`` renders from the committed JSON.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

from kartpilot.core.files import write_json_atomic, write_text_atomic
from kartpilot.study.report import write_report
from kartpilot.study.tune import tune_page

ROOT = Path(__file__).resolve().parents[1]


def page(results: dict[str, Any], figures: Path | None = None) -> str:
    """The docs page of a study from its committed results (``study`` and ``rows``); the figures are written
    into ``figures`` when given."""
    name = results["study"]["name"]
    with tempfile.TemporaryDirectory() as folder:
        study = Path(folder)
        (study / "study.json").write_text(json.dumps(results["study"]))
        (study / "rows.json").write_text(json.dumps({"rows": results["rows"]}))
        write_report(study)
        text = (study / "report.md").read_text(encoding="utf-8")
        if figures is not None:
            figures.mkdir(parents=True, exist_ok=True)
            for picture in sorted((study / "figures").glob("*.png")):
                shutil.copyfile(picture, figures / picture.name)
    text = text.split("\n## Every metric")[0].rstrip() + "\n"
    text = text.replace("](figures/", f"](../figures/study/{name}/")
    return (text + f"\nEvery row, with every metric: `docs/results/study/{name}.json`. "
            f"Made again with `kartpilot study run {name}{' --quick' if results['study'].get('quick') else ''}` "
            "and `python benchmarks/study_docs.py`.\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--docs", type=Path, default=ROOT / "docs")
    args = parser.parse_args()
    for folder in args.folders:
        if (folder / "tune.json").is_file():  # a `study tune` folder
            data = json.loads((folder / "tune.json").read_text(encoding="utf-8"))
            name = f"{data['study']}-tune"
            write_json_atomic(args.docs / "results" / "study" / f"{name}.json", data)
            write_text_atomic(args.docs / "study" / f"{name}.md", tune_page(data))
            print(f"{name}: {len(data['trials'])} trials -> docs/study/{name}.md")
            continue
        study = json.loads((folder / "study.json").read_text(encoding="utf-8"))
        rows = json.loads((folder / "rows.json").read_text(encoding="utf-8"))["rows"]
        results = {"study": study, "rows": rows}
        name = study["name"]
        write_json_atomic(args.docs / "results" / "study" / f"{name}.json", results)
        write_text_atomic(args.docs / "study" / f"{name}.md", page(results, args.docs / "figures" / "study" / name))
        print(f"{name}: {len(rows)} rows -> docs/study/{name}.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

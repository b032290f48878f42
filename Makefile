# kartpilot developer entry points. Everything runs inside .venv/ at the repo root.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DATA ?= ../shared/data

.PHONY: install test lint docs bench accuracy demo clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(BIN)/pytest -q

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy
	$(BIN)/mkdocs build --strict --quiet --site-dir $$(mktemp -d)

# the documentation as a static site in site/ (open site/index.html)
docs: $(STAMP)
	$(BIN)/mkdocs build --strict

bench: $(STAMP)
	$(BIN)/python benchmarks/stereo_vo.py --data $(DATA) --out benchmarks/results/stereo_vo.json
	$(BIN)/python benchmarks/sim_render.py --out benchmarks/results/sim_render.json
	$(BIN)/python benchmarks/lanes.py --data $(DATA) --out benchmarks/results/lanes.json
	$(BIN)/python benchmarks/drive.py --out benchmarks/results/drive.json
	$(BIN)/python benchmarks/record.py --out benchmarks/results/record.json
	$(BIN)/python benchmarks/places.py --out benchmarks/results/places.json
	$(BIN)/python benchmarks/mono_drive.py --out benchmarks/results/mono_drive.json

# VO accuracy on every real and simulated sequence (records the simulated drives once), into the docs
accuracy: $(STAMP)
	$(BIN)/python benchmarks/vo_accuracy.py --data $(DATA) --out docs/results/vo_accuracy.json
	$(BIN)/python benchmarks/vo_table.py docs/results/vo_accuracy.json --out docs/results/vo_accuracy.md --into README.md docs/results.md

demo: $(STAMP)
	$(BIN)/kartpilot demo --out demo_out

clean:
	rm -rf $(VENV) demo_out site .pytest_cache .mypy_cache .ruff_cache

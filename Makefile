# kartpilot developer entry points. Everything runs inside .venv/ at the repo root.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DATA ?= ../shared/data

.PHONY: install test lint docs bench accuracy studies demo clean

# uv installs the same versions as pip, 4x faster (11 s against 50 s for kartpilot and its test tools on 2 cores, a
# clean machine); where uv cannot be had, pip does it. Both compile the libraries' bytecode as they install (pip does
# by default, uv when asked): where PYTHONDONTWRITEBYTECODE is set, as on CI machines, a library never compiled is
# compiled again by every process that imports it (scipy, scikit-learn and OpenCV 9 s of each test worker's, Ray
# worker's and command's start on a 2-core machine, against 3 s compiled)
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	if $(BIN)/pip install --quiet uv 2>/dev/null; then \
		$(BIN)/uv pip install --quiet --compile-bytecode --python $(BIN)/python -e ".[test]"; \
	else \
		$(BIN)/pip install --quiet --upgrade pip && $(BIN)/pip install --quiet -e ".[test]"; \
	fi
	touch $(STAMP)

install: $(STAMP)

# the test modules spread over the machine's cores (at most 4; each holds a simulator), one module per worker, in the
# order tests/conftest.py gives them (the longest first; xdist's own reordering by test count would undo it)
# kartpilot's own modules compiled first, for the same reason (they change, so not at install)
test: $(STAMP)
	$(BIN)/python -m compileall -q src > /dev/null
	$(BIN)/pytest -q -n auto --maxprocesses 4 --dist loadscope --no-loadscope-reorder

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
	$(BIN)/python benchmarks/startup.py --data $(DATA) --out benchmarks/results/startup.json

# VO accuracy on every real and simulated sequence (records the simulated drives once), into the docs
accuracy: $(STAMP)
	$(BIN)/python benchmarks/vo_accuracy.py --data $(DATA) --out docs/results/vo_accuracy.json
	$(BIN)/python benchmarks/vo_table.py docs/results/vo_accuracy.json --out docs/results/vo_accuracy.md --into README.md docs/results.md

# every built-in study at its quick size (a few minutes each on 2 cores), the tuning, and the scaling, into the docs
STUDIES := features filters detectors robustness lanes controllers
studies: $(STAMP)
	for s in $(STUDIES); do $(BIN)/kartpilot study run $$s --quick --out runs/$$s --data $(DATA) || exit 1; done
	$(BIN)/kartpilot study tune controllers --quick --out runs/controllers-tune --data $(DATA)
	$(BIN)/python benchmarks/study_docs.py $(addprefix runs/,$(STUDIES)) runs/controllers-tune
	$(BIN)/python benchmarks/study_scaling.py --study features --data $(DATA) --out docs/results/study_scaling.json
	$(BIN)/python benchmarks/study_scaling.py --render docs/results/study_scaling.json --into README.md docs/study/index.md

demo: $(STAMP)
	$(BIN)/kartpilot demo --out demo_out

clean:
	rm -rf $(VENV) demo_out runs site .pytest_cache .mypy_cache .ruff_cache

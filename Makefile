# Quick start: `make demo` runs the main job on the built-in demo; `make test` runs the tests.
# Both create .venv with the pinned dependencies on first use.

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-$(shell cat pyproject.toml requirements.lock | sha256sum | cut -c1-12)

.PHONY: demo test bench clean

$(STAMP): pyproject.toml requirements.lock
	rm -f $(VENV)/.installed-*
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c requirements.lock -e '.[test]'
	touch $@

demo: $(STAMP)
	$(BIN)/gyrocal simulate --out demo/logs --preset quick --unit seed000 --seed 1 \
		--temperatures=-40,-30,-20,-10,0,10,20,30,40,50
	$(BIN)/gyrocal calibrate demo/logs/U001.parquet --device U001 --batch B1 \
		--session 2026-01-01 -o demo/U001.calibration.json --report demo/U001.html \
		--tables demo/tables
	@echo "demo done: calibration demo/U001.calibration.json, report demo/U001.html"

test: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python benchmarks/pipeline.py

clean:
	rm -rf $(VENV) demo .pytest_cache .hypothesis

# Quick start: `make demo` runs the main job on the built-in demo; `make test` runs the tests.
# Both create .venv with the pinned dependencies on first use.

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
# The C kernels are built on install: a change to one reinstalls, as a change of dependencies does.
KERNELS := gyrocal/io/_blockstats.c gyrocal/fit/_kernels.c
STAMP  := $(VENV)/.installed-$(shell cat pyproject.toml setup.py requirements.lock $(KERNELS) | sha256sum | cut -c1-12)

.PHONY: demo test lint bench system-packages clean

$(STAMP): pyproject.toml setup.py requirements.lock $(KERNELS)
	rm -f $(VENV)/.installed-*
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c requirements.lock -e '.[test]'
	touch $@

# The demo fleet (config/devices.tsv: 7 turntable units in 2 batches, one twice; a servo, a
# sweep and a real hand-rotation session), simulated
# and calibrated by the workflow.
demo: $(STAMP)
	$(BIN)/snakemake --cores all
	@echo "demo done: fleet summary reports/index.html, unit reports reports/<batch>/<device>/<session>.html,"
	@echo "           calibrations results/<batch>/<device>/<session>/calibration.json,"
	@echo "           indexed in results/registry.sqlite (gyrocal lookup results DEVICE)"

test: system-packages $(STAMP) lint
	$(BIN)/python -m pytest -n auto --dist loadfile

# The lint gate ([tool.ruff] in pyproject.toml): rules that catch bugs, and one layout; and
# the type check of the layers [tool.mypy] holds to their types.
lint: $(STAMP)
	$(BIN)/ruff check gyrocal tests benchmarks
	$(BIN)/ruff format --check gyrocal tests benchmarks
	$(BIN)/mypy gyrocal/terms gyrocal/fit gyrocal/calibration gyrocal/pipeline gyrocal/__init__.py gyrocal/run/api.py

# Debian packages the tests use, installed when missing and possible: Chromium for the
# browser test, gcc for the firmware export test (and the C kernels, built on install),
# rsync for the object-storage test (Snakemake's fs storage plugin copies with it),
# SLURM and munge for the scheduler tests (tests/workflow/slurm.py starts its own one-node cluster),
# PostgreSQL for the registry's tests (tests/pg.py starts its own server; Debian keeps the
# server's programs off PATH, in /usr/lib/postgresql/<version>/bin).
system-packages:
	@missing=""; \
	command -v chromium >/dev/null 2>&1 || missing="$$missing chromium"; \
	command -v gcc >/dev/null 2>&1 || missing="$$missing gcc libc6-dev"; \
	command -v rsync >/dev/null 2>&1 || missing="$$missing rsync"; \
	for tool in sbatch slurmctld slurmd munged; do \
	  command -v $$tool >/dev/null 2>&1 || test -x /usr/sbin/$$tool || { missing="$$missing slurm-wlm munge"; break; }; \
	done; \
	{ command -v initdb && command -v postgres; } >/dev/null 2>&1 \
	  || ls /usr/lib/postgresql/*/bin/initdb /usr/lib/postgresql/*/bin/postgres >/dev/null 2>&1 \
	  || missing="$$missing postgresql"; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing Debian's$$missing for the tests"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else \
	    echo "$$missing: not installed and cannot be installed here; the tests that need them are skipped (CI fails them)"; \
	  fi; \
	fi

bench: $(STAMP)
	$(BIN)/python benchmarks/pipeline.py

clean:
	rm -rf $(VENV) demo results reports logs .snakemake .pytest_cache .hypothesis

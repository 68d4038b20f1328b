# Two commands for a new user: `make run` and `make test`. Both install on first use.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.install-stamp

.PHONY: run test lint bench install sample clean

$(BIN)/python:
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "Python 3.11 is needed (set PYTHON=...)"; exit 1; }
	$(PYTHON) -m venv $(VENV)

# torch is pinned first and on its own: an unpinned torch pulls several GB of CUDA wheels.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --disable-pip-version-check -q "torch==2.13.0"
	$(BIN)/pip install --disable-pip-version-check -q -e ".[dev]"
	$(BIN)/python -m sandtrack_tui.tracking.kernels  # compile the tracker's kernels once (cached)
	$(BIN)/python -m sandtrack_tui.triangulation  # and the triangulation's
	@touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/sandtrack tui

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks

test: lint
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

sample: $(STAMP)
	$(BIN)/sandtrack sample sample_data --preset small

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache

# Two commands for a new user: `make run` and `make test`. Both install on first use.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.install-stamp

.PHONY: run test lint fuzz bench figures install sample sample-model clean

$(BIN)/python:
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "Python 3.11 is needed (set PYTHON=...)"; exit 1; }
	$(PYTHON) -m venv $(VENV)

# torch is pinned (an unpinned torch pulls several GB of CUDA wheels); pyproject.toml pins it too.
# pip byte-compiles the installed packages on one core: compileall does it on all of them (and on our own
# sources, which an editable install leaves to each process), at the same time as the compiled kernels of
# the tracker, the sixel encoder, the triangulation, its sd and the calibrated-region test are built (cached on disk).
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --disable-pip-version-check -q --no-compile "torch==2.13.0" -e ".[dev]"
	$(BIN)/python -m compileall -q -j 0 $(VENV)/lib src >/dev/null & c=$$!; \
		$(BIN)/python -m sandtrack_tui.tracking.warmup & k=$$!; $(BIN)/python -m sandtrack_tui.tui.sixel & s=$$!; \
		$(BIN)/python -m sandtrack_tui.triangulation && $(BIN)/python -m sandtrack_tui.triangulation_sd && \
		$(BIN)/python -m sandtrack_tui.calibration.region; t=$$?; \
		wait $$c; wait $$k && wait $$s && test $$t -eq 0
	@touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/sandtrack tui

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks

# Two workers: the suite is mostly single-threaded Python (TEST_WORKERS=0 runs it in one process).
TEST_WORKERS ?= 2
test: lint
	$(BIN)/python -m pytest -n $(TEST_WORKERS)

# The deep property-test run: fresh random examples (not the fixed ones of `make test`), 30 times as many.
FUZZ_TESTS := tests/test_fuzz_readers.py tests/test_dem_readers.py tests/test_export_import.py tests/test_regression_fuzz.py
fuzz: $(STAMP)
	SANDTRACK_FUZZ=deep $(BIN)/python -m pytest -p no:cacheprovider $(FUZZ_TESTS)

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py
	$(MAKE) fuzz

# The figures of the last `make bench` (benchmarks/out/results.json) into benchmarks/results.json, the others
# kept, and README's performance table written from it.
figures: $(STAMP)
	$(BIN)/python benchmarks/render_table.py --update

sample: $(STAMP)
	$(BIN)/sandtrack sample sample_data --preset small
	$(MAKE) sample-model

# The sample project's calibration, calibration points and network, from the sample's calibration
# videos. Reproducible: one training thread and seed 0; a re-run gives the same figures (the
# calibration agrees to ~1e-9, floating-point summation order), only the reports' timings differ.
sample-model: $(STAMP)
	$(BIN)/sandtrack calibrate --board sample_data/board.toml --side sample_data/calibration/side.mp4 \
		--front sample_data/calibration/front.mp4 --reference sample_data/calibration/reference.toml \
		--points sample_data/calibration/points.csv -o sample_data/calibration.toml
	$(BIN)/sandtrack train sample_data/calibration/points.csv -o sample_data/model.pt \
		--calibration sample_data/calibration.toml --seed 0 --threads 1 --epochs 60

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache

# Quick start: `make demo` and `make test`. Both bootstrap .venv from pyproject.toml, at the exact versions of
# constraints.txt (what the suite and BENCHMARKS.md last ran with; `make lock` takes the newest within the ranges).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck bench clean lock

$(STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip >/dev/null
	$(BIN)/pip install -c constraints.txt -e '.[dev,bench]'
	touch $(STAMP)

# the newest versions pyproject.toml's ranges allow, resolved in a throwaway venv and written to constraints.txt:
# then `make test` (it reinstalls) and record the figures that move
LOCK_VENV := .lock-venv
lock:
	rm -rf $(LOCK_VENV) && $(PY) -m venv $(LOCK_VENV)
	$(LOCK_VENV)/bin/pip install -q --upgrade pip
	$(LOCK_VENV)/bin/pip install -q -e '.[dev,bench]'
	head -n 3 constraints.txt > constraints.new
	$(LOCK_VENV)/bin/pip freeze --exclude-editable >> constraints.new
	mv constraints.new constraints.txt && rm -rf $(LOCK_VENV)

# the simulated air-float scan of the four-tumour phantom: calibrate the simulated probe on the reference samples
# (as on the bench), scan with that calibration, then score the map against the phantom's truth
demo: $(STAMP)
	@run=runs/demo-$$(date +%Y%m%d-%H%M%S); mkdir -p $$run && \
	$(BIN)/python -m tools.calibrate_airfloat -o $$run/calibration.yaml && \
	$(BIN)/palpa launch launch/scan_sim.yaml --run-dir $$run calibration:=$$run/calibration.yaml $(DEMO_ARGS) && \
	$(BIN)/python -m tools.scan_report $$run --phantom phantoms/airfloat_tumours.yaml

# three workers (pytest-xdist): the process tests spend much of their time waiting on wall-clock motion. The UR
# emulator's tests (xdist_group "ur-emulator") run one at a time on one worker (--dist loadgroup; pytest < 9.2, see
# pyproject.toml): they move in real time and starve each other under load. 2.7 min on two idle cores in session 13,
# 3.5-4 min on the same machine slower since; 5.3 min with both cores kept busy by two other CPU-bound processes
# (BENCHMARKS.md, "The test suite"). `make test TEST_JOBS=0`
# runs serially.
TEST_JOBS ?= 3
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_JOBS) --dist loadgroup

lint: $(STAMP)
	$(BIN)/ruff check palpa messages devices models nodes emulators tests
	$(BIN)/mypy

typecheck: $(STAMP)
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/python bench/bus.py
	$(BIN)/python bench/estimator.py
	$(BIN)/python bench/tracker.py
	$(BIN)/python bench/record.py

clean:
	rm -rf $(VENV) $(LOCK_VENV) runs out .pytest_cache .mypy_cache

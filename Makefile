# Quick start: `make demo` and `make test`. Both bootstrap .venv from pyproject.toml, at the exact versions of
# constraints.txt (what the suite and BENCHMARKS.md last ran with; `make lock` takes the newest within the ranges).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-system lint typecheck bench clean lock conformance-js

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

# Two tiers (tests/conftest.py): `make test` is the in-process tier (pure, harness, composition): no process, socket,
# pty or namespace (a guard stops an unmarked test that reaches for one), nothing that waits on the wall clock, so a
# busy machine slows it but cannot fail it. `make test-system` runs the tests marked `system`: processes, sockets,
# ur_rtde and its emulator, ptys, network namespaces. There the UR emulator's tests (xdist_group "ur-emulator") run
# one at a time on one worker (--dist loadgroup; pytest < 9.2, see pyproject.toml): they move in real time.
# TEST_JOBS=0 runs serially.
TEST_JOBS ?= 2
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_JOBS) -m "not system"

SYSTEM_JOBS ?= 3
test-system: $(STAMP) conformance-js
	$(BIN)/python -m pytest -q -n $(SYSTEM_JOBS) --dist loadgroup -m system

# the Node.js conformance client (conformance/js, tests/test_conformance_js.py): its packages from the npm registry at
# the versions of its package-lock.json. --ignore-scripts: zeromq's install script would build or download a binary;
# zeromq 6 ships its prebuilt addon (linux/darwin/win32, glibc and musl) inside the npm package itself
JS_CLIENT := conformance/js
$(JS_CLIENT)/node_modules/.installed: $(JS_CLIENT)/package.json $(JS_CLIENT)/package-lock.json
	cd $(JS_CLIENT) && npm ci --ignore-scripts --no-audit --no-fund
	touch $@
conformance-js: $(JS_CLIENT)/node_modules/.installed

lint: $(STAMP)
	$(BIN)/ruff check palpa messages devices models nodes emulators tools tests
	$(BIN)/mypy

typecheck: $(STAMP)
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/python bench/bus.py
	$(BIN)/python bench/estimator.py
	$(BIN)/python bench/tracker.py
	$(BIN)/python bench/record.py

clean:
	rm -rf $(VENV) $(LOCK_VENV) runs out .pytest_cache .mypy_cache $(JS_CLIENT)/node_modules

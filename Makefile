# Two commands do all the set-up: `make demo` (the main job) and `make test` (the suite).
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.requirements-installed

.PHONY: demo test lint package venv clean gpu-check gpu-benchmark

venv: $(STAMP)

$(STAMP): requirements.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found (bpy 4.5 needs Python 3.11)"; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	touch $(STAMP)

demo: $(STAMP)
	$(PY) vdnif_addon/batch.py -- demo --out out/demo

# Two worker processes (pytest-xdist): most tests run one thread each (a batch.py
# subprocess, a one-thread kernel), so one process leaves a core idle.
TEST_WORKERS ?= 2

test: $(STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS)

lint: $(STAMP)
	$(PY) -m ruff check .

# Trains and renders on the GPU against the CPU (tools/gpu_check.py); refused without CUDA.
gpu-check: $(STAMP)
	$(PY) tools/gpu_check.py

# The check, then the GPU benchmark of the trained ball into out/gpu-benchmark.json.
gpu-benchmark: $(STAMP)
	$(PY) tools/gpu_check.py --benchmark out/gpu-benchmark.json

# The standard library only (tools/package.py): zipping the files needs no venv.
package:
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found (tomllib needs Python 3.11)"; exit 1; }
	$(PYTHON) tools/package.py --out build

clean:
	rm -rf build out .pytest_cache .ruff_cache

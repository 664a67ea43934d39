# Two entry points: `make run` (the daemon on the demo config) and `make test` (lint, types, tests).
# Both create the virtual environment under .venv on first use and reinstall when pyproject.toml changes.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
CONFIG ?= config/demo.yaml

.PHONY: run test sim sim-random lint typecheck pytest format clean config-reference bench-bad-input

run: $(VENV)/.stamp-run
	$(BIN)/avoidd run --config $(CONFIG)

test: $(VENV)/.stamp-test
	$(BIN)/ruff check avoidd tests
	$(BIN)/ruff format --check avoidd tests
	$(BIN)/mypy --strict avoidd
	$(BIN)/pytest

# Every built-in scenario (sitl/scenarios) in the simulator, with the table of results.
SEEDS ?= 1
sim: $(VENV)/.stamp-run
	$(BIN)/avoidd sim batch sitl/scenarios/*.yaml --seeds $(SEEDS) --json sim-batch.json

# The randomized set (sitl/scenarios/random): 20 scenarios x 5 seeds = 100 flights at 3 m/s;
# MAX_SPEED=5 flies the same worlds at 5 m/s.
sim-random: $(VENV)/.stamp-run
	$(BIN)/avoidd sim batch sitl/scenarios/random/*.yaml --seeds 5 --workers 2 \
		$(if $(MAX_SPEED),--max-speed $(MAX_SPEED)) --json sim-random.json

# docs/config-reference.md from the config models (tests/test_config_reference.py checks it).
config-reference: $(VENV)/.stamp-run
	$(BIN)/python -m avoidd.config.reference > docs/config-reference.md

# How long check-config takes to refuse each bad input, as separate processes (target: 1 s).
bench-bad-input: $(VENV)/.stamp-test
	$(BIN)/python -m tests.bench_bad_input

format: $(VENV)/.stamp-test
	$(BIN)/ruff format avoidd tests
	$(BIN)/ruff check --fix avoidd tests

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(VENV)/.stamp-run: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.stamp-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@ $(VENV)/.stamp-run

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache

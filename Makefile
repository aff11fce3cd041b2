# Everything runs inside .venv, created on first use from pyproject.toml.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	$(BIN)/python -m codev_engine.kernels --prepare
	touch $(STAMP)

## demo: set everything up (the solver kernels compiled once, announced) and replay the
##       bundled session (synthesis, verification, recording)
demo: $(STAMP)
	$(BIN)/codev replay sessions/double-integrator

## test: the whole test suite (what CI runs), on TEST_WORKERS processes (pytest-xdist)
TEST_WORKERS ?= 2
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --durations=15

## lint: ruff, and the import contracts of pyproject.toml (also run by make test)
lint: $(STAMP)
	$(BIN)/ruff check codev_engine workbench tests benchmarks
	$(BIN)/lint-imports --no-logo

## bench: synthesis benchmark against PPOPT (installs the peer into .venv)
bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -r benchmarks/requirements.txt
	$(BIN)/python benchmarks/synth.py

clean:
	rm -rf $(VENV) out .pytest_cache build dist .import_linter_cache .grimp_cache

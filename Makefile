# The README's two commands: `make demo` and `make test`. Both build .venv when it is missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck layers bench soak docs clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade "pip>=25.1"

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[jupyter]" --group dev --group docs
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/galil demo

lint: $(STAMP)
	$(BIN)/ruff check galil tests benchmarks examples
	$(BIN)/ruff format --check galil tests benchmarks examples

typecheck: $(STAMP)
	$(BIN)/mypy --strict galil tests/typing

layers: $(STAMP)
	$(BIN)/lint-imports

# The tests run on every core (at most 4 workers; each test is independent of the others'
# order and process): about 75 s on 2 cores, 130 s in one process (`$(BIN)/pytest -q`).
test: lint typecheck layers
	$(BIN)/pytest -q -n auto --maxprocesses 4

# The documentation site (MkDocs, Material, mkdocstrings) in site/; a warning fails the build.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

# Every benchmark, each figure against its target and its anchor, a one-line summary and
# benchmarks/results/bench.json (about 3 minutes; BENCH="--quick" for a shorter, noisier run);
# it exits non-zero while a target is missed.
bench: $(STAMP)
	$(BIN)/python benchmarks/run.py $(BENCH)

soak: $(STAMP)
	$(BIN)/python benchmarks/soak.py

clean:
	rm -rf $(VENV) build dist site .mypy_cache .pytest_cache .ruff_cache

# img2dmp: two commands on a fresh machine.
#   make demo   set everything up, then run the main job end to end on a small default
#   make test   set everything up, then run the test suite (exactly what .ci/run runs)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)
OUT    ?= out/demo

.PHONY: setup demo test lint bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,robot]'
	rm -f $(VENV)/.installed-* && touch $@

demo: setup
	$(BIN)/img2dmp demo --out $(OUT)

test: setup
	$(BIN)/python -m pytest -q -m "not slow"

lint: setup
	$(BIN)/ruff check src tests benchmarks experiments examples
	$(BIN)/ruff format --check src tests benchmarks experiments examples

bench: setup
	$(BIN)/python benchmarks/bench_rollout.py

clean:
	rm -rf $(VENV) out runs

# img2dmp: two commands on a fresh machine.
#   make demo   set everything up, then run the main job end to end on a small default
#   make test   set everything up, then run the test suite (exactly what .ci/run runs)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)
OUT    ?= out/demo
# make model-real: the recommended real-handwriting model, from the data in ../shared/data.
DATA   ?= ../shared/data
REAL   ?= runs/real
# make model-omniglot: the recommended stroke model of Omniglot's characters (issue 32).
OMNI   ?= runs/omniglot
# ... from this Omniglot folder (the images_NAME and strokes_NAME zips or folders of any
# alphabets: docs/DATASET.md), e.g. make model-omniglot OMNIGLOT=~/omniglot OMNI=runs/mine
OMNIGLOT ?= $(DATA)/omniglot
# ... its stroke count read from this many views of each image (chosen on the validation
# drawers for --config omniglot: RESULTS 8.3).
OMNI_VIEWS ?= 1
# ... trained with this many torch threads: 1 trains the shipped weights to the last bit
# on a CPU with AVX-512 (on one with AVX2 alone, other weights: RESULTS 8.21);
# 2 trains about 1.8 times as fast on a 2-core machine nothing else uses, as
# deterministically, to other weights (RESULTS 8.15): for more alphabets than ../shared's.
OMNI_THREADS ?= 1
# ... with these settings besides --config omniglot, each passed as --set KEY=VALUE, e.g.
# OMNI_SET="strokes.slots=12 optim.max_samples=0" for a script of more than 8 strokes a
# character, trained the full 120 epochs whatever its size (docs/TRAINING.md).
OMNI_SET ?=
# ... imported with these options of img2dmp import besides --n-times 300, e.g.
# OMNI_IMPORT="--skip-bad" for a tree with drawings that cannot be read (each named), or
# OMNI_IMPORT="--split-by character" to test on characters never seen (docs/DATASET.md).
OMNI_IMPORT ?=
# make test: the suite in this many worker processes (pytest-xdist; 0 = in pytest's own
# process, as before).
# On a 2-core AMD EPYC without AVX-512, 2 took 376 s against 635 s for one (RESULTS 5.9).
TEST_WORKERS ?= 2
# Refinement steps of the images each model finds unfamiliar (below its familiarity line;
# chosen on validation drawings: RESULTS 8.14), beside the 30 and 60 steps of the others.
REAL_UNFAMILIAR ?= 60
OMNI_UNFAMILIAR ?= 150
# The recipe evaluates on the test drawers: a data set without them stops before training.
HAS_TEST = $(BIN)/python -c "import sys; from img2dmp.data.store import load_dataset; \
  sys.exit(None if (load_dataset(sys.argv[1]).split == 2).any() else f'error: {sys.argv[1]} \
  has no test drawings (drawers 18-20) to evaluate on: see the import note above')"
# A run trained before img2dmp train wrote its familiarity gets one here.
RUN_FAMILIAR = $(BIN)/python -c "import sys; from img2dmp.familiar import write_run_familiar as w; w(*sys.argv[1:])"
# A recipe's folder remembers what made it (its recipe.txt): asked for again with another
# source or other settings, the recipe stops, naming both, rather than keep the old files
# and say "Nothing to be done". $(call SAME_RECIPE,FOLDER,WHAT,VARIABLE)
define SAME_RECIPE
@mkdir -p $(1) && made="$(2)" && if [ -f $(1)/recipe.txt ] && [ "$$(cat $(1)/recipe.txt)" != "$$made" ]; \
  then echo "error: $(1) was made by $$(cat $(1)/recipe.txt), not by $$made: give another \
folder ($(3)=...), or remove $(1) to make it anew"; exit 1; fi; printf '%s\n' "$$made" > $(1)/recipe.txt
endef
# A path as the recipe records it: absolute, so ../shared/data and its full path agree.
ABS = $$(realpath -m '$(1)')
# ... and rewrites a file only when its text changes (a step's settings that do not
# remake what came before it, such as the reading settings of an evaluation).
define SETTINGS
@mkdir -p $(dir $(1)) && printf '%s\n' '$(2)' | cmp -s - $(1) || printf '%s\n' '$(2)' > $(1)
endef
REAL_RECIPE = DATA=$(call ABS,$(DATA))
OMNI_RECIPE = OMNIGLOT=$(call ABS,$(OMNIGLOT)) OMNI_IMPORT=$(OMNI_IMPORT) OMNI_SET=$(OMNI_SET) OMNI_THREADS=$(OMNI_THREADS)
# The torch build the set-up installs (the CPU build).
TORCH  ?= 2.13.0

.PHONY: setup browser demo test lint bench clean model-real ship-real model-omniglot ship-omniglot \
  real-recipe omni-recipe FORCE

setup: $(STAMP)

# torch first, pinned to the CPU build (on local disk; an unpinned torch would pull a
# multi-GB CUDA build): the package itself declares only a range (torch>=2.1,<3), which
# the installed build satisfies, so the second install keeps it. interop and bench: the
# peer DMP libraries, so that the bridges' tests and the peers' benchmark smoke test run
# (movement-primitives builds from source with gcc: about 20 s).
$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==$(TORCH)
	$(BIN)/python -m pip install --quiet -e '.[dev,robot,export,web,interop,bench]'
	rm -f $(VENV)/.installed-* && touch $@

demo: setup
	$(BIN)/img2dmp demo --out $(OUT) --force

test: setup browser
	$(BIN)/python -m pytest -q -m "not slow" -n $(TEST_WORKERS) --durations=15

# The browser tests (tests/test_web_browser.py) drive Debian's Chromium with Playwright
# (no `playwright install`): installed here when missing, which needs root (or sudo
# without a password); otherwise those tests skip (and fail with IMG2DMP_REQUIRE_BROWSER=1).
browser:
	@if [ -x /usr/bin/chromium ]; then :; \
	elif ! command -v apt-get >/dev/null; then \
	  echo "note: no /usr/bin/chromium and no apt-get: the browser tests will skip"; \
	elif [ "$$(id -u)" = 0 ]; then \
	  apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends chromium; \
	elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then \
	  sudo apt-get update && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends chromium; \
	else echo "note: no /usr/bin/chromium and no root to install it: the browser tests will skip"; fi

# Prepare MNIST with the recorded pen paths (durations normalised to 1 s; half of the ten
# affine copies photographed on generated paper and read back as photos are), train the
# recommended network (the shipped configuration real: src/img2dmp/configs/real.yaml),
# evaluate it on the test part with refinement.
# Each step is skipped when its result exists; an interrupted training resumes.
model-real: $(REAL)/evaluation/evaluation.json

real-recipe:
	$(call SAME_RECIPE,$(REAL),$(REAL_RECIPE),REAL)

$(REAL)/data.safetensors: | setup real-recipe
	$(BIN)/img2dmp prepare --data '$(DATA)' --augment 10 --paper 0.5 --scaling none --duration 1 --out $@

$(REAL)/run/checkpoints/best.safetensors: $(REAL)/data.safetensors src/img2dmp/configs/real.yaml | setup real-recipe
	if [ -f $(REAL)/run/checkpoints/last.safetensors ]; then \
	  $(BIN)/img2dmp train --run-dir $(REAL)/run --resume; else \
	  $(BIN)/img2dmp train --config real --data $< --run-dir $(REAL)/run; fi

$(REAL)/evaluation/settings.txt: FORCE
	$(call SETTINGS,$@,REAL_UNFAMILIAR=$(REAL_UNFAMILIAR))

$(REAL)/evaluation/evaluation.json: $(REAL)/run/checkpoints/best.safetensors $(REAL)/evaluation/settings.txt
	test -f $(REAL)/run/familiar.safetensors || $(RUN_FAMILIAR) $(REAL)/run $(REAL)/data.safetensors
	$(BIN)/img2dmp evaluate --model $(REAL)/run --data $(REAL)/data.safetensors --split test \
	  --refine 30 --refine-unfamiliar $(REAL_UNFAMILIAR) --out $(REAL)/evaluation --force

# The recommended stroke model (each character up to 8 strokes, each its own DMP) from
# $(OMNIGLOT) (../shared/data/omniglot): import (every stroke kept, 300 instants), train
# (--config omniglot, 120 epochs), evaluate on the test drawers refined and counted as
# recommended; about 17 minutes on 2 cores.
model-omniglot: $(OMNI)/evaluation/evaluation.json

omni-recipe:
	$(call SAME_RECIPE,$(OMNI),$(OMNI_RECIPE),OMNI)

$(OMNI)/data.safetensors: | setup omni-recipe
	$(BIN)/img2dmp import '$(OMNIGLOT)' --n-times 300 $(OMNI_IMPORT) --out $@ --force --no-progress

$(OMNI)/run/checkpoints/best.safetensors: $(OMNI)/data.safetensors src/img2dmp/configs/omniglot.yaml | setup omni-recipe
	$(HAS_TEST) $<
	if [ -f $(OMNI)/run/checkpoints/last.safetensors ]; then \
	  $(BIN)/img2dmp train --run-dir $(OMNI)/run --resume; else \
	  $(BIN)/img2dmp train --config omniglot --data $< --run-dir $(OMNI)/run \
	    --set threads=$(OMNI_THREADS) $(foreach s,$(OMNI_SET),--set $(s)); fi

$(OMNI)/evaluation/settings.txt: FORCE
	$(call SETTINGS,$@,OMNI_VIEWS=$(OMNI_VIEWS) OMNI_UNFAMILIAR=$(OMNI_UNFAMILIAR))

$(OMNI)/evaluation/evaluation.json: $(OMNI)/run/checkpoints/best.safetensors $(OMNI)/evaluation/settings.txt
	test -f $(OMNI)/run/familiar.safetensors || $(RUN_FAMILIAR) $(OMNI)/run $(OMNI)/data.safetensors
	$(BIN)/img2dmp evaluate --model $(OMNI)/run --data $(OMNI)/data.safetensors --split test \
	  --refine 60 --refine-unfamiliar $(OMNI_UNFAMILIAR) --count-views $(OMNI_VIEWS) \
	  --out $(OMNI)/evaluation --force

# Put the model-real run into the package as the shipped model digits-real
# (src/img2dmp/models/digits-real: the checkpoint, model.json with its SHA-256 and test
# figures); its CARD.md is then brought up to date by hand (tests/test_models.py checks
# it against model.json).
ship-real: $(REAL)/evaluation/evaluation.json
	$(BIN)/python experiments/ship_model.py --run $(REAL)/run --evaluation $< --name digits-real \
	  --refine-unfamiliar $(REAL_UNFAMILIAR) --familiar $(REAL)/data.safetensors

# Put the model-omniglot run into the package as the shipped model omniglot-strokes, with
# its familiarity drawn on the data set's validation drawers (its CARD.md is then brought
# up to date by hand).
ship-omniglot: $(OMNI)/evaluation/evaluation.json
	$(BIN)/python experiments/ship_model.py --run $(OMNI)/run --evaluation $< --name omniglot-strokes \
	  --count-views $(OMNI_VIEWS) --refine-unfamiliar $(OMNI_UNFAMILIAR) \
	  --familiar $(OMNI)/data.safetensors

lint: setup
	$(BIN)/ruff check src tests benchmarks experiments examples
	$(BIN)/ruff format --check src tests benchmarks experiments examples

bench: setup
	$(BIN)/python benchmarks/bench_rollout.py

FORCE:

clean:
	rm -rf $(VENV) out runs

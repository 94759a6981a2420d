# ncs-lite: `make reproduce` (main job) and `make test`; both set up .venv first if needed.
VENV     ?= .venv
PY       := $(VENV)/bin/python
STAMP    := $(VENV)/.installed
PRESET   ?= reduced
NOTEBOOKS := $(sort $(wildcard notebooks/[0-9][0-9]_*.ipynb))
# notebooks with an `env` parameter, run on robogym-rearrange and block-stacking too (`reproduce`;
# tests/test_notebooks_envs.py at ci)
ENV_NOTEBOOKS := notebooks/04_dslate_training.ipynb notebooks/05_graph_construction.ipynb notebooks/06_action_selection.ipynb \
  notebooks/07_baselines.ipynb
BUILD    := build

SEEDS    ?= 0 1 2
# notebooks run on one thread: their numbers are then bit-identical on any machine and load
# (another thread count changes torch's floating-point order, and with it a result or two)
THREADS  ?= 1

.PHONY: setup reproduce test bench seeds clusters baselines fig9 fig10 fig11 baseline-assets clean exercises docs \
  book book-check classroom-check

setup: $(STAMP)

# Re-run the install whenever the requirements change.
$(STAMP): environment.txt pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r environment.txt
	# the optional `sweeps` extra (submitit, pinned in pyproject.toml: `--executor submitit`, and
	# tests/test_sweeps.py runs it); environment.txt's torch pin goes along, so pip keeps that torch
	$(PY) -m pip install --quiet -e '.[sweeps]' "$$(grep '^torch==' environment.txt)"
	# a `python3` kernel inside the venv, found by papermill and nbmake
	$(PY) -m ipykernel install --sys-prefix --name python3 --display-name "Python 3 (ncs-lite)"
	touch $@

# Main job: every notebook through papermill at the `reduced` preset; figures -> figures/.
# Committed figures name a clean commit, so a tree with uncommitted changes is refused
# (ALLOW_DIRTY=1 writes anyway and records "dirty": true in each figure's JSON). The changes are
# those `ncs_lite.utils.dirty_files` sees: generated text aside, and a notebook only when its
# cells changed (a notebook run and saved in JupyterLab has new outputs, not new code).
# make's start, before .venv is built, and whether .cache/ was there: `reproduce` records its
# whole run (figures/notebook_times.json, "run"; the README quotes it)
MAKE_START := $(shell date +%s.%N)
CACHE_AT_START := $(shell test -d .cache && echo 1 || echo 0)
reproduce: $(STAMP)
	@if [ "$(ALLOW_DIRTY)" != 1 ] && ! $(PY) -c "import sys; from ncs_lite.utils import dirty_files; \
	  d = dirty_files(); d and print('make reproduce: uncommitted changes in', ', '.join(d)); sys.exit(bool(d))"; then \
	  echo "make reproduce: commit first (figures record their commit) or pass ALLOW_DIRTY=1"; \
	  exit 2; fi
	mkdir -p $(BUILD)/notebooks
	for nb in $(NOTEBOOKS); do \
	  echo "== $$nb (preset=$(PRESET))"; start=$$(date +%s.%N); \
	  OMP_NUM_THREADS=$(THREADS) NCS_LITE_ALLOW_DIRTY=$(ALLOW_DIRTY) $(PY) -m papermill --kernel python3 --cwd notebooks -p preset $(PRESET) \
	    $$nb $(BUILD)/notebooks/$$(basename $$nb) || exit 1; \
	  $(PY) -c "import sys; from ncs_lite.experiments.reproduce import record_notebook_time as r; r(sys.argv[1], float(sys.argv[2]) - float(sys.argv[3]), sys.argv[4])" \
	    $$(basename $$nb .ipynb) $$(date +%s.%N) $$start $(PRESET) || exit 1; \
	done
	# notebooks 04-07 once more on each other env: same parameters but `env`; executed copies
	# <name>_<suffix>.ipynb, figures in figures/<name>/<env>/, times as <name>_<suffix> (the
	# suffixes: utils.NOTEBOOK_ENV_SUFFIX)
	for pair in robogym-rearrange:robogym block-stacking:stacking; do env=$${pair%%:*}; suffix=$${pair##*:}; \
	  for nb in $(ENV_NOTEBOOKS); do \
	    name=$$(basename $$nb .ipynb); echo "== $$nb (preset=$(PRESET), env=$$env)"; start=$$(date +%s.%N); \
	    OMP_NUM_THREADS=$(THREADS) NCS_LITE_ALLOW_DIRTY=$(ALLOW_DIRTY) $(PY) -m papermill --kernel python3 --cwd notebooks -p preset $(PRESET) \
	      -p env $$env $$nb $(BUILD)/notebooks/$${name}_$$suffix.ipynb || exit 1; \
	    $(PY) -c "import sys; from ncs_lite.experiments.reproduce import record_notebook_time as r; r(sys.argv[1], float(sys.argv[2]) - float(sys.argv[3]), sys.argv[4])" \
	      $${name}_$$suffix $$(date +%s.%N) $$start $(PRESET) || exit 1; \
	  done; \
	done
	# the whole run's time, when it ran every notebook (not NOTEBOOKS=... from the command line)
	if [ "$(origin NOTEBOOKS)$(origin ENV_NOTEBOOKS)" = "filefile" ]; then \
	  $(PY) -c "import os, sys; from ncs_lite.experiments.reproduce import record_run_time as r; now, start = map(float, sys.argv[1:3]); \
	    r(now - start, os.path.getmtime(sys.argv[3]) >= start, sys.argv[4] == '0', sys.argv[5])" \
	    $$(date +%s.%N) $(MAKE_START) $(STAMP) $(CACHE_AT_START) $(PRESET) || exit 1; fi
	@echo "figures written to figures/; executed notebooks in $(BUILD)/notebooks/"

# Unit tests + every notebook under nbmake at the `ci` preset (tests/test_notebooks_envs.py runs
# ENV_NOTEBOOKS once more with env=robogym-rearrange and once with env=block-stacking through
# papermill). Figures of the test run go
# to build/ so the committed `reduced` figures stay as they are. pytest-xdist runs the tests in
# TEST_WORKERS processes, each test and notebook on one thread (THREADS), so the slow notebook
# runs share the cores instead of queueing; TEST_WORKERS=0 runs them in this process.
TEST_WORKERS ?= 2
test: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) NCS_LITE_PRESET=ci NCS_LITE_PROGRESS=0 NCS_LITE_FIGURES=$(BUILD)/test-figures \
	  $(PY) -m pytest -q -p no:cacheprovider -n $(TEST_WORKERS) --dist worksteal --durations=12 \
	  --nbmake --nbmake-timeout=900 tests notebooks

bench: $(STAMP)
	mkdir -p $(BUILD)/bench
	for b in envs train kmeans ncs; do \
	  $(PY) -m ncs_lite bench $$b --out $(BUILD)/bench/$$b.json || exit 1; \
	done

# README tables that need more than the notebooks (hours on a CPU; resumable).
seeds: $(STAMP)
	$(PY) -m ncs_lite reproduce seeds --preset $(PRESET) --seeds $(SEEDS)

clusters: $(STAMP)
	$(PY) -m ncs_lite reproduce clusters

# The main comparison (notebook 07's table): every method at 4..7 objects, both goal kinds, on each
# environment; on the notebooks' thread count, so after `make reproduce` it reloads notebook 07's rows.
baselines: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) $(PY) -m ncs_lite reproduce baselines
	OMP_NUM_THREADS=$(THREADS) $(PY) -m ncs_lite reproduce baselines --env robogym-rearrange
	OMP_NUM_THREADS=$(THREADS) $(PY) -m ncs_lite reproduce baselines --env block-stacking --episodes 50 --mpc-episodes 25

# Appendix D's Figs. 9 (NCS against its hyperparameters), 10 (success against the interaction horizon) and 11 (against action noise) on
# robogym-rearrange's shipped assets; fig11 reuses fig10's cached cells. EXECUTOR=submitit runs the
# cells as a submitit job array (Slurm when found, else local processes).
EXECUTOR ?= local
fig9: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) $(PY) -m ncs_lite reproduce fig9 --preset $(PRESET) --executor $(EXECUTOR)
fig10: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) $(PY) -m ncs_lite reproduce fig10 --preset $(PRESET) --executor $(EXECUTOR)
fig11: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) $(PY) -m ncs_lite reproduce fig11 --preset $(PRESET) --executor $(EXECUTOR)

# An env's shipped dSLATE is the training seed its seeds table's shipping rule picked
# (`shipped_seed` in figures/tables/seeds_*.json: the lowest held-out reconstruction error):
# that table's own run of the seed (same command, recipe and buffer) when it is there, else the
# seed trained anew. $(call ship_dslate,SEED,RUN,TABLE,TRAIN_ARGS,VAR): RUN is the run's path
# without its suffix, TABLE the seeds table's file, TRAIN_ARGS `train`'s env and buffer, VAR
# the variable that names the seed.
shipped_seed = $(shell python3 -c "import json; print(json.load(open('figures/tables/$(1)'))['shipped_seed'])" 2>/dev/null)
define ship_dslate
@test -n "$(1)" || { echo "make: figures/tables/$(3) names no shipped_seed; run its 'python -m ncs_lite reproduce seeds' (docs/results.md) or pass $(5)=N"; exit 2; }
@if [ -f $(2).pt ]; then \
  echo "make: shipping the seeds table's run of seed $(1) ($(2).pt)"; \
  cp $(2).csv $(basename $@).csv.tmp && mv $(basename $@).csv.tmp $(basename $@).csv && \
  cp $(2).pt $@.tmp && mv $@.tmp $@; \
else $(PY) -m ncs_lite train $(4) --preset reduced --out $@ --seed $(1); fi
endef

# The shipped assets of block-rearrange: the dSLATE (`BR_SEED` of the seeds table, whose runs
# `BR_RUNS` holds), its graphs, the baselines and oracles, each made by one command from the
# buffer the shipped dSLATE was trained on (5000 episodes); only missing files are made.
ASSETS      := ncs_lite/assets
TRAIN_DATA  := .cache/buffers/block-rearrange-k4-e5000-s0-v1
GRAPH_DATA  := $(TRAIN_DATA)
BR_SEED     ?= $(call shipped_seed,seeds_reduced.json)
BR_RUNS     ?= .cache/seeds
$(ASSETS)/dslate_block_rearrange_reduced.pt: | $(TRAIN_DATA)/manifest.json
	$(call ship_dslate,$(BR_SEED),$(BR_RUNS)/reduced-seed-$(BR_SEED)/dslate,seeds_reduced.json,--data $(TRAIN_DATA),BR_SEED)
BASELINE_ASSETS := $(ASSETS)/graph_block_rearrange_oracle.pt $(ASSETS)/graph_block_rearrange_oracle_position.pt \
  $(ASSETS)/nf_graph_block_rearrange_reduced.pt $(ASSETS)/nf_graph_block_rearrange_oracle.pt \
  $(ASSETS)/bc_block_rearrange_reduced.pt $(ASSETS)/iql_block_rearrange_reduced.pt
BLOCK_GRAPHS := $(ASSETS)/graph_block_rearrange_reduced.pt $(ASSETS)/graph_block_rearrange_reduced_slot.pt
.PHONY: block-graphs
block-graphs: $(BLOCK_GRAPHS)
baseline-assets: $(BASELINE_ASSETS)
$(ASSETS)/graph_block_rearrange_reduced.pt: | $(ASSETS)/dslate_block_rearrange_reduced.pt $(GRAPH_DATA)/manifest.json
	$(PY) -m ncs_lite graph --checkpoint $(ASSETS)/dslate_block_rearrange_reduced.pt --data $(GRAPH_DATA) --clusters 30 --out $@
$(ASSETS)/graph_block_rearrange_reduced_slot.pt: | $(ASSETS)/dslate_block_rearrange_reduced.pt $(GRAPH_DATA)/manifest.json
	$(PY) -m ncs_lite graph --checkpoint $(ASSETS)/dslate_block_rearrange_reduced.pt --data $(GRAPH_DATA) --clusters 30 \
	  --state slot --out $@
$(TRAIN_DATA)/manifest.json: | $(STAMP)
	$(PY) -m ncs_lite collect --episodes 5000 --seed 0 --out $(TRAIN_DATA)
$(ASSETS)/graph_block_rearrange_oracle.pt: | $(GRAPH_DATA)/manifest.json
	$(PY) -m ncs_lite graph --oracle --data $(GRAPH_DATA) --clusters 30 --out $@
$(ASSETS)/graph_block_rearrange_oracle_position.pt: | $(GRAPH_DATA)/manifest.json
	$(PY) -m ncs_lite graph --oracle --state slot --data $(GRAPH_DATA) --clusters 30 --out $@
$(ASSETS)/nf_graph_block_rearrange_reduced.pt: | $(ASSETS)/graph_block_rearrange_reduced.pt
	$(PY) -m ncs_lite graph-nf --checkpoint $(ASSETS)/dslate_block_rearrange_reduced.pt --data $(GRAPH_DATA) \
	  --bind-graph $(ASSETS)/graph_block_rearrange_reduced.pt --out $@
$(ASSETS)/nf_graph_block_rearrange_oracle.pt: | $(ASSETS)/graph_block_rearrange_oracle.pt
	$(PY) -m ncs_lite graph-nf --oracle --data $(GRAPH_DATA) --bind-graph $(ASSETS)/graph_block_rearrange_oracle.pt --out $@
$(ASSETS)/bc_block_rearrange_reduced.pt: | $(TRAIN_DATA)/manifest.json
	$(PY) -m ncs_lite train-baseline --method bc --preset reduced --data $(TRAIN_DATA) --out $@
$(ASSETS)/iql_block_rearrange_reduced.pt: | $(TRAIN_DATA)/manifest.json
	$(PY) -m ncs_lite train-baseline --method iql --preset reduced --data $(TRAIN_DATA) --out $@

# robogym-rearrange's shipped assets: the buffers (5,000 episodes for training, 20,000 for the
# graphs: continuous positions need more exemplars per node than grid cells), the `reduced`
# dSLATE of the training seed the seeds table ships (`reproduce seeds --env robogym-rearrange`
# picks it by its held-out reconstruction error, `shipped_seed` in its JSON), its graph on slot
# states and the position oracle's graph (Tables 3-4 defaults: 45 nodes, slot metrics).
# Training is about 25 min on 2 cores; only missing files are made.
RG_DATA  := .cache/buffers/robogym-rearrange-k4-e5000-s0-v1
RG_GRAPH_DATA := .cache/buffers/robogym-rearrange-k4-e20000-s0-v1
RG_SEED  ?= $(call shipped_seed,seeds_robogym_reduced.json)
RG_SEED_RUN = .cache/seeds-robogym-rearrange/reduced-seed-$(RG_SEED)/dslate
RG_ASSETS := $(ASSETS)/dslate_robogym_rearrange_reduced.pt $(ASSETS)/graph_robogym_rearrange_reduced_slot.pt \
  $(ASSETS)/graph_robogym_rearrange_oracle_position.pt
.PHONY: robogym-assets
robogym-assets: $(RG_ASSETS)
$(RG_DATA)/manifest.json: | $(STAMP)
	$(PY) -m ncs_lite collect --env robogym-rearrange --episodes 5000 --seed 0 --out $(RG_DATA)
$(ASSETS)/dslate_robogym_rearrange_reduced.pt: | $(RG_DATA)/manifest.json
	$(call ship_dslate,$(RG_SEED),$(RG_SEED_RUN),seeds_robogym_reduced.json,--env robogym-rearrange --data $(RG_DATA),RG_SEED)
$(RG_GRAPH_DATA)/manifest.json: | $(STAMP)
	$(PY) -m ncs_lite collect --env robogym-rearrange --episodes 20000 --seed 0 --out $(RG_GRAPH_DATA)
# fig9 rebuilds the shipped graph's variants from this buffer (`data.find_buffer`: by manifest hash)
fig9: | $(RG_GRAPH_DATA)/manifest.json
$(ASSETS)/graph_robogym_rearrange_reduced_slot.pt: | $(ASSETS)/dslate_robogym_rearrange_reduced.pt $(RG_GRAPH_DATA)/manifest.json
	$(PY) -m ncs_lite graph --checkpoint $(ASSETS)/dslate_robogym_rearrange_reduced.pt --data $(RG_GRAPH_DATA) --out $@
$(ASSETS)/graph_robogym_rearrange_oracle_position.pt: | $(RG_GRAPH_DATA)/manifest.json
	$(PY) -m ncs_lite graph --oracle --data $(RG_GRAPH_DATA) --out $@

# robogym-rearrange's baselines (notebook 07's robogym columns): BC and IQL on the
# training buffer, NF bound by the shipped graphs' nodes on the graph buffer; only missing files
RG_BASELINE_ASSETS := $(ASSETS)/bc_robogym_rearrange_reduced.pt $(ASSETS)/iql_robogym_rearrange_reduced.pt \
  $(ASSETS)/nf_graph_robogym_rearrange_reduced.pt $(ASSETS)/nf_graph_robogym_rearrange_oracle.pt
.PHONY: robogym-baseline-assets
robogym-baseline-assets: $(RG_BASELINE_ASSETS)
$(ASSETS)/bc_robogym_rearrange_reduced.pt: | $(RG_DATA)/manifest.json
	$(PY) -m ncs_lite train-baseline --method bc --env robogym-rearrange --preset reduced --data $(RG_DATA) --out $@
$(ASSETS)/iql_robogym_rearrange_reduced.pt: | $(RG_DATA)/manifest.json
	$(PY) -m ncs_lite train-baseline --method iql --env robogym-rearrange --preset reduced --data $(RG_DATA) --out $@
$(ASSETS)/nf_graph_robogym_rearrange_reduced.pt: | $(RG_GRAPH_DATA)/manifest.json
	$(PY) -m ncs_lite graph-nf --checkpoint $(ASSETS)/dslate_robogym_rearrange_reduced.pt --data $(RG_GRAPH_DATA) \
	  --bind-graph $(ASSETS)/graph_robogym_rearrange_reduced_slot.pt --out $@
$(ASSETS)/nf_graph_robogym_rearrange_oracle.pt: | $(RG_GRAPH_DATA)/manifest.json
	$(PY) -m ncs_lite graph-nf --oracle --data $(RG_GRAPH_DATA) \
	  --bind-graph $(ASSETS)/graph_robogym_rearrange_oracle_position.pt --out $@

# block-stacking's shipped assets: the training buffer (5,000 episodes), the `reduced` dSLATE of
# seed 0 (about 30 min on 2 cores), its graph on slot states and the position oracle's, both
# with dependencies (Table 4's 47 nodes), and the baselines; only missing files are made.
BS_DATA := .cache/buffers/block-stacking-k4-e5000-s0-v1
BS_ASSETS := $(ASSETS)/dslate_block_stacking_reduced.pt $(ASSETS)/graph_block_stacking_reduced_slot.pt \
  $(ASSETS)/graph_block_stacking_oracle_position.pt $(ASSETS)/bc_block_stacking_reduced.pt \
  $(ASSETS)/iql_block_stacking_reduced.pt $(ASSETS)/nf_graph_block_stacking_reduced.pt \
  $(ASSETS)/nf_graph_block_stacking_oracle.pt
.PHONY: stacking-assets
stacking-assets: $(BS_ASSETS)
$(BS_DATA)/manifest.json: | $(STAMP)
	$(PY) -m ncs_lite collect --env block-stacking --episodes 5000 --seed 0 --out $(BS_DATA)
$(ASSETS)/dslate_block_stacking_reduced.pt: | $(BS_DATA)/manifest.json
	$(PY) -m ncs_lite train --env block-stacking --preset reduced --data $(BS_DATA) --out $@ --seed 0
$(ASSETS)/graph_block_stacking_reduced_slot.pt: | $(ASSETS)/dslate_block_stacking_reduced.pt $(BS_DATA)/manifest.json
	$(PY) -m ncs_lite graph --checkpoint $(ASSETS)/dslate_block_stacking_reduced.pt --data $(BS_DATA) --out $@
$(ASSETS)/graph_block_stacking_oracle_position.pt: | $(BS_DATA)/manifest.json
	$(PY) -m ncs_lite graph --oracle --data $(BS_DATA) --out $@
$(ASSETS)/bc_block_stacking_reduced.pt: | $(BS_DATA)/manifest.json
	$(PY) -m ncs_lite train-baseline --method bc --env block-stacking --preset reduced --data $(BS_DATA) --out $@
$(ASSETS)/iql_block_stacking_reduced.pt: | $(BS_DATA)/manifest.json
	$(PY) -m ncs_lite train-baseline --method iql --env block-stacking --preset reduced --data $(BS_DATA) --out $@
$(ASSETS)/nf_graph_block_stacking_reduced.pt: | $(ASSETS)/graph_block_stacking_reduced_slot.pt
	$(PY) -m ncs_lite graph-nf --checkpoint $(ASSETS)/dslate_block_stacking_reduced.pt --data $(BS_DATA) \
	  --bind-graph $(ASSETS)/graph_block_stacking_reduced_slot.pt --out $@
$(ASSETS)/nf_graph_block_stacking_oracle.pt: | $(ASSETS)/graph_block_stacking_oracle_position.pt
	$(PY) -m ncs_lite graph-nf --oracle --data $(BS_DATA) \
	  --bind-graph $(ASSETS)/graph_block_stacking_oracle_position.pt --out $@

# The README's result blocks and docs/results.md from figures/tables/*.json and the notebook
# times (the table commands and `make reproduce` rewrite them too; tests/test_docs.py checks them).
docs: $(STAMP)
	$(PY) -m ncs_lite.docs

# Student copies (stubs that raise NotImplementedError) and solutions from the masters in
# notebooks/; deterministic, so a rerun changes nothing (tests/test_exercises.py checks it).
exercises: $(STAMP)
	$(PY) -m ncs_lite.exercises --out exercises

# A static site of the README, docs/ and the notebooks that `make reproduce` executed
# ($(BUILD)/notebooks/), figures inline: $(BUILD)/book/index.html. Without executed notebooks it
# says which command makes them; a notebook not executed yet is shown without outputs.
book: $(STAMP)
	$(PY) -m ncs_lite.book --notebooks $(BUILD)/notebooks --out $(BUILD)/book

# Browser checks in headless Chromium, not part of `make test` (they need selenium and Chromium:
# scripts/browser.py says how to install them). book-check: every page of the book loads, every
# image is drawn, no broken internal link, no console error. classroom-check: a student's
# JupyterLab session (run all, solve an exercise, save, reopen) leaves the kit clean.
book-check: $(STAMP)
	$(PY) scripts/check_book.py $(BUILD)/book

classroom-check: $(STAMP)
	$(PY) scripts/check_classroom.py

clean:
	rm -rf $(BUILD)

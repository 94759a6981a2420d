# ncs-lite: `make reproduce` (main job) and `make test`; both set up .venv first if needed.
VENV     ?= .venv
PY       := $(VENV)/bin/python
STAMP    := $(VENV)/.installed
PRESET   ?= reduced
NOTEBOOKS := $(sort $(wildcard notebooks/[0-9][0-9]_*.ipynb))
BUILD    := build

.PHONY: setup reproduce test bench clean

setup: $(STAMP)

# Re-run the install whenever the requirements change.
$(STAMP): environment.txt pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r environment.txt
	# a `python3` kernel inside the venv, found by papermill and nbmake
	$(PY) -m ipykernel install --sys-prefix --name python3 --display-name "Python 3 (ncs-lite)"
	touch $@

# Main job: every notebook through papermill at the `reduced` preset; figures -> figures/.
reproduce: $(STAMP)
	mkdir -p $(BUILD)/notebooks
	for nb in $(NOTEBOOKS); do \
	  echo "== $$nb (preset=$(PRESET))"; \
	  $(PY) -m papermill --kernel python3 --cwd notebooks -p preset $(PRESET) \
	    $$nb $(BUILD)/notebooks/$$(basename $$nb) || exit 1; \
	done
	@echo "figures written to figures/; executed notebooks in $(BUILD)/notebooks/"

# Unit tests + every notebook under nbmake at the `ci` preset. Figures of the test run go
# to build/ so the committed `reduced` figures stay as they are.
test: $(STAMP)
	NCS_LITE_PRESET=ci NCS_LITE_PROGRESS=0 NCS_LITE_FIGURES=$(BUILD)/test-figures \
	  $(PY) -m pytest -q -p no:cacheprovider --nbmake --nbmake-timeout=900 tests notebooks

bench: $(STAMP)
	mkdir -p $(BUILD)/bench
	for b in envs train kmeans ncs; do \
	  $(PY) -m ncs_lite bench $$b --out $(BUILD)/bench/$$b.json || exit 1; \
	done

clean:
	rm -rf $(BUILD)

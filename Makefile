# Two commands do all set-up on a fresh machine: `make reproduce-figures` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
WARM := $(VENV)/.warmed-up

.PHONY: test test-all test-numba reproduce-figures warm-up bench stress gallery studies notebook clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# rbx's modules compiled to bytecode once: where PYTHONDONTWRITEBYTECODE is set, Python would otherwise compile
# every module from its source again in each of the hundreds of processes the tests and the figures start
# (0.08 s of the 0.6 s a short `rbx simulate` takes)
BYTECODE := $(VENV)/.bytecode
$(BYTECODE): $(wildcard rbx/*.py rbx/cli/*.py) | $(STAMP)
	$(PY) -m compileall -q rbx
	touch $@

# the tests that take seconds each (fault reproductions and end-to-end runs of the command line, marked `long`) and
# minutes each (the bench, accuracy and stress documents, marked `heavy`) run with `make stress`; `make test-all`
# runs every test
test: $(STAMP) $(BYTECODE)
	$(PY) -m pytest -q -n 2 -m "not heavy and not long" tests

test-all: $(STAMP) $(BYTECODE)
	$(PY) -m pytest -q -n 2 tests

# make test's suite with the oldest and the newest Numba that pyproject.toml declares (a venv each), and with
# kernels compiled for a generic CPU (NUMBA_CPU_NAME=generic): scripts/test_numba.sh (MARKS="not heavy" adds the
# long tier)
test-numba:
	PYTHON=$(PYTHON) scripts/test_numba.sh

# ---- the paper's figures (docs/reference.md §6) ----------------------------------------------------------------------------
# data/<x>.h5 is one `rbx simulate` run of configs/experiments/<x>.yaml; a figure with several scenes has a folder
# configs/experiments/<label>/ of configs.  figures/<label>.png depends on its script and its data only, so
# re-plotting never re-simulates.  A figure script exits 1 when the paper's property does not hold.
RBX := $(VENV)/bin/rbx
FIGURES := caustics circle periodic graph graphRandom plate roughrank histogram
fig_data = $(if $(wildcard configs/experiments/$(1)/*.yaml),$(patsubst configs/experiments/%.yaml,data/%.h5,$(sort $(wildcard configs/experiments/$(1)/*.yaml))),data/$(1).h5)

reproduce-figures: figures/README.md $(WARM)

# the kernels of every example compiled ahead into the kernel cache (scripts/warm_up.py), so that the first run of an
# example loads them instead of compiling for 10-40 s; done again when rbx's source or an example changes
warm-up: $(WARM)
$(WARM): scripts/warm_up.py $(wildcard configs/examples/*.yaml) $(wildcard rbx/*.py) | $(STAMP) $(BYTECODE)
	$(PY) scripts/warm_up.py
	touch $@

figures/README.md: $(FIGURES:%=figures/%.png) scripts/figures_readme.py
	$(PY) scripts/figures_readme.py

# keep the runs: they are the expensive part. (Not `.SECONDARY:` for all targets: that made the pictures
# intermediate too, and a deleted figures/<x>.png was then not drawn again while figures/README.md existed.)
.PRECIOUS: data/%.h5
.SECONDEXPANSION:
figures/%.png: scripts/fig_%.py scripts/figlib.py $$(call fig_data,$$*) | $(STAMP)
	MPLBACKEND=Agg $(PY) $< $(call fig_data,$*) -o $@

data/%.h5: configs/experiments/%.yaml | $(STAMP) $(BYTECODE)
	@mkdir -p $(dir $@)
	$(RBX) simulate $< -o $@ --force --quiet

# the return-angle experiment writes its own file (output.path in the config points here)
data/histogram.h5: configs/experiments/histogram.yaml | $(STAMP) $(BYTECODE)
	@mkdir -p data
	$(RBX) histogram $< -o data/histogram-cli.png --force --quiet

# the public peer that scripts/bench.py times (billiards, PyPI) comes with the bench extra
BENCH_STAMP := $(VENV)/.installed-bench
$(BENCH_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,bench]'
	touch $(BENCH_STAMP)

bench: $(BENCH_STAMP)
	$(PY) scripts/bench.py
	$(PY) scripts/accuracy.py
	$(PY) scripts/bench_cluster.py --collisions 40000000 --output docs/benchmarks-cluster.md

stress: $(STAMP) $(BYTECODE)
	$(PY) -m pytest -q -n 2 -m "heavy or long" tests
	$(PY) scripts/stress.py

# the plot kinds each example lists (its first line, `# plots: …`), from the example as it ships cut to 2000
# collisions: docs/gallery/*.png, docs/gallery.md and the README's docs/quickstart.png
gallery: $(STAMP)
	MPLBACKEND=Agg $(PY) scripts/gallery.py

# three parameter studies (configs/studies/, rbx sweep): data/studies/*.nc, figures/studies/*.png, docs/studies.md
studies: $(STAMP)
	MPLBACKEND=Agg $(PY) scripts/studies.py

# examples/api.ipynb in Jupyter (the notebook extra: pip install -e '.[notebook]')
NOTEBOOK_STAMP := $(VENV)/.installed-notebook
$(NOTEBOOK_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,notebook]'
	touch $(NOTEBOOK_STAMP)

notebook: $(NOTEBOOK_STAMP)
	$(VENV)/bin/jupyter notebook examples/api.ipynb

clean:
	rm -rf data runs figures/*.png figures/*.json

# Two commands do all set-up on a fresh machine: `make reproduce-figures` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: test reproduce-figures bench stress clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q -n 2 tests

# Until the figure scripts land (issue 5) this runs every example experiment into runs/.
EXAMPLES := $(wildcard configs/examples/*.yaml)
RUNS := $(patsubst configs/examples/%.yaml,runs/%.h5,$(EXAMPLES))

reproduce-figures: $(RUNS)

runs/%.h5: configs/examples/%.yaml $(STAMP)
	$(VENV)/bin/rbx simulate $< -o $@ --force --quiet

bench: $(STAMP)
	$(PY) scripts/bench.py

clean:
	rm -rf data figures runs

# houghloc: `make demo` and `make test` do all the set-up from a fresh clone (python3 + make).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: setup demo test test-all bench bench-real lint clean

setup: $(STAMP)

# Re-install only when the package metadata changes: `make setup` is quick when nothing did.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,peers]'
	touch $(STAMP)

demo: setup
	$(BIN)/houghloc demo

test: setup
	$(BIN)/python -m pytest -q -m "not slow"

test-all: setup
	$(BIN)/python -m pytest -q

bench: setup
	$(BIN)/python -m benchmarks.run_all

# the real-world benchmark: six buildings × protocols × houghloc and its peers, on Dask.
# MRPT's pf-localization is a Debian package: installed here when apt-get can, else its rows
# are errors that say so.
bench-real: setup
	command -v pf-localization >/dev/null || (apt-get update -qq && apt-get install -y -qq \
	    mrpt-apps) >/dev/null 2>&1 || echo "mrpt-apps not installed: the mrpt rows will say so"
	$(BIN)/houghloc sweep --spec benchmarks/real.yaml --out runs/bench-real

lint: setup
	$(BIN)/ruff check houghloc fusion tests benchmarks notebooks

clean:
	rm -rf $(VENV) runs .pytest_cache

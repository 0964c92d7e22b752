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

# the real-world benchmark: six buildings × protocols × houghloc and its peers, on Dask
bench-real: setup
	$(BIN)/houghloc sweep --spec benchmarks/real.yaml --out runs/bench-real

lint: setup
	$(BIN)/ruff check houghloc fusion tests benchmarks notebooks

clean:
	rm -rf $(VENV) runs .pytest_cache

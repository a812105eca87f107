# make run   - set up what the planner needs, start the planning service and plan the femur-like
#              reference scan through it over HTTP
# make test  - set up what the tests need too, then run the test suite in two processes (TEST_WORKERS;
#              slow tests: make test-slow)
VENV ?= .venv
BIN := $(VENV)/bin
OUT ?= scanmill-out

# Two set-up levels (scripts/setup.sh run|test), so that `make run` does not install the servers, LinuxCNC
# and the browser that only the tests use. Each level has its own stamp in the venv, written by setup.sh;
# the test level includes the run level and writes both stamps, so `make run` after `make test` installs
# nothing. A stamp is remade when the dependencies or the set-up itself change. With
# SCANMILL_SKIP_SERVERS=1 (kept for compatibility: no Redis, PostgreSQL or LinuxCNC at the test level)
# the test level has a stamp of its own, so a later plain `make test` still installs them.
SETUP_DEPS := pyproject.toml scripts/setup.sh scripts/vendor_three.py
RUN_STAMP := $(VENV)/.installed-run
TEST_STAMP := $(VENV)/.installed-test$(if $(filter 1,$(SCANMILL_SKIP_SERVERS)),-noservers)
# three.js for the viewer is not in git (setup.sh vendors it): fetch it again if the vendor directory was
# removed (git clean -X) while the stamps stayed, without redoing the whole set-up.
THREE_VERSION := scanmill/viewer/static/vendor/three/VERSION
PYTHON ?= python3

.PHONY: setup setup-run setup-test setup-dry-run run serve test test-slow bench bench-service bench-distributed

# `setup` keeps its old meaning: everything, tests included.
setup: setup-test
setup-run: $(RUN_STAMP) $(THREE_VERSION)
setup-test: $(TEST_STAMP) $(THREE_VERSION)

# What each level would install on this machine (apt packages, venv, pip, three.js), changing nothing.
setup-dry-run:
	VENV=$(VENV) bash scripts/setup.sh run --dry-run
	VENV=$(VENV) bash scripts/setup.sh test --dry-run

$(RUN_STAMP): $(SETUP_DEPS)
	VENV=$(VENV) bash scripts/setup.sh run

$(TEST_STAMP): $(SETUP_DEPS)
	VENV=$(VENV) bash scripts/setup.sh test

# A no-op when the pinned release is there; touch keeps make from asking again after the script changed.
$(THREE_VERSION): scripts/vendor_three.py
	$(PYTHON) scripts/vendor_three.py $(if $(SCANMILL_THREE_TARBALL),--from-tarball '$(SCANMILL_THREE_TARBALL)') && touch $@

run: setup-run
	$(BIN)/python scripts/demo_service.py --sample femur_like --data-dir scanmill-data --out $(OUT)

serve: setup-run
	$(BIN)/scanmill serve

# The test files are shared among TEST_WORKERS pytest processes (pytest-xdist), a file's tests kept in one
# process so that its module fixtures (a plan, a simulated program) are made once. Many tests wait on a
# server, a worker or a subprocess, so two processes finish the suite sooner even on two cores.
# TEST_WORKERS=0: one process, in file order.
TEST_WORKERS ?= 2

test: setup-test
	$(BIN)/python -m pytest -q --durations=40 $(if $(filter-out 0,$(TEST_WORKERS)),-n $(TEST_WORKERS) --dist loadfile)

test-slow: setup-test
	$(BIN)/python -m pytest -q -m slow

bench: setup-test
	$(BIN)/python bench/bench_plan.py --repeat 3
	$(BIN)/python bench/bench_setups.py

bench-service: setup-test
	$(BIN)/python bench/bench_service_load.py --jobs 20 --pollers 50 --interval-s 0.5
	$(BIN)/python bench/bench_service_load.py --jobs 20 --pollers 50 --interval-s 0.05

bench-distributed: setup-test
	$(BIN)/python bench/bench_distributed.py --jobs 16 --workers 1 2

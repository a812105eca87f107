# make run   - set up, start the planning service and plan the femur-like reference scan through it over HTTP
# make test  - set up, then run the test suite (slow tests: make test-slow)
VENV ?= .venv
BIN := $(VENV)/bin
OUT ?= scanmill-out

.PHONY: setup run serve test test-slow bench bench-service bench-distributed

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml scripts/setup.sh
	VENV=$(VENV) bash scripts/setup.sh

run: setup
	$(BIN)/python scripts/demo_service.py --sample femur_like --data-dir scanmill-data --out $(OUT)

serve: setup
	$(BIN)/scanmill serve

test: setup
	$(BIN)/python -m pytest -q --durations=15

test-slow: setup
	$(BIN)/python -m pytest -q -m slow

bench: setup
	$(BIN)/python bench/bench_plan.py --repeat 3
	$(BIN)/python bench/bench_setups.py

bench-service: setup
	$(BIN)/python bench/bench_service_load.py --jobs 20 --pollers 50 --interval-s 0.5
	$(BIN)/python bench/bench_service_load.py --jobs 20 --pollers 50 --interval-s 0.05

bench-distributed: setup
	$(BIN)/python bench/bench_distributed.py --jobs 16 --workers 1 2

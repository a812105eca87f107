# make run   - set up, then plan the bundled femur-like reference scan with the CLI
# make test  - set up, then run the test suite (slow tests: make test-slow)
VENV ?= .venv
BIN := $(VENV)/bin
OUT ?= scanmill-out

.PHONY: setup run test test-slow bench

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml scripts/setup.sh
	VENV=$(VENV) bash scripts/setup.sh

run: setup
	$(BIN)/scanmill sample femur_like --out $(OUT)/femur_like.ply
	$(BIN)/scanmill plan $(OUT)/femur_like.ply --out $(OUT)/femur_like
	@echo "results: $(OUT)/femur_like/ (plan.json, plan.npz, segmentation.ply, preview.png)"

test: setup
	$(BIN)/python -m pytest -q

test-slow: setup
	$(BIN)/python -m pytest -q -m slow

bench: setup
	$(BIN)/python bench/bench_plan.py

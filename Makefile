# GL-DT: the two commands of the README. Each one does all set-up first (idempotent, seconds on
# a set-up machine) via scripts/setup.sh.
SHELL := /bin/bash
.DEFAULT_GOAL := help
VENV_PY := .venv/bin/python
PYTEST_ARGS ?=

.PHONY: help setup demo test lint test-slow test-all docs bench-peers clean

help:
	@echo "make demo       set up, then replay the bundled sample through GL-DT and print what it saw"
	@echo "make test       set up, then lint, type-check and run the default test suite (excludes slow suites)"
	@echo "make lint       set up, then run ruff (lint, format) and mypy only"
	@echo "make test-slow  set up, then run only the slow suites (training, soak, big benchmarks)"

setup:
	@bash scripts/setup.sh

demo: setup
	@bash scripts/with_ros_env.sh $(VENV_PY) -m gldt_core demo

# Lint and type checks first (their report stays short), then the tests, which run whatever the
# checks said; the target fails when either does.
test: setup
	@lint_status=0; $(MAKE) --no-print-directory lint || lint_status=1; \
	bash scripts/with_ros_env.sh $(VENV_PY) -m pytest -m "not slow" $(PYTEST_ARGS); test_status=$$?; \
	exit $$(( test_status != 0 ? test_status : lint_status ))

# ruff (lint and format) and mypy, as configured in pyproject.toml.
lint: setup
	@.venv/bin/ruff check --quiet && .venv/bin/ruff format --check --quiet && .venv/bin/mypy --no-error-summary

test-slow: setup
	@bash scripts/with_ros_env.sh $(VENV_PY) -m pytest -m "slow" $(PYTEST_ARGS)

test-all: setup
	@bash scripts/with_ros_env.sh $(VENV_PY) -m pytest $(PYTEST_ARGS)

# boxmot (the reference ByteTrack of the tests, the peers of `gldt bench tracking`) is installed by
# scripts/setup.sh with the test extra: without its declared torch/torchvision dependencies (they
# would pull a CUDA torch), plus the two it really imports. Kept as a name for that step.
bench-peers: setup

# Soak of the node graph (issue #9): loop the real sample bag at 30 Hz for SOAK_MINUTES, report
# each node's RSS growth, track-table size and dropped frames (a benchmark, minutes long).
SOAK_MINUTES ?= 10
.PHONY: soak-graph
soak-graph: setup
	@bash scripts/with_ros_env.sh $(VENV_PY) -m gldt_ros.bench.soak --minutes $(SOAK_MINUTES) --json out/soak_graph.json

docs: setup
	@$(VENV_PY) scripts/generate_param_docs.py

clean:
	rm -rf build install log .setup-stamps

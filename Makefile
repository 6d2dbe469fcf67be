# The project's commands. `make setup` builds everything; `make test` runs every test;
# `make demo` runs the main job on the simulated Panda.
SHELL := /bin/bash
ENV := source scripts/env.sh
PYTEST_ARGS ?=
BENCH_BRIEF ?= 0

.PHONY: setup lock test test-fast lint demo experiments bench clean

setup:
	@flock /tmp/vla-setup-$$(id -u).lock bash scripts/setup.sh

# Regenerate the pinned locks from pyproject.toml's direct dependencies (pip-tools), keeping pins.
lock: setup
	@bash scripts/lock.sh $(LOCK_ARGS)

test: setup
	@$(ENV) && python -m pytest $(PYTEST_ARGS)

test-fast: setup
	@$(ENV) && python -m pytest -m "not slow" $(PYTEST_ARGS)

lint: setup
	@$(ENV) && ruff check src test bench && lint-imports

demo: setup
	@$(ENV) && vla_evaluation demo $(DEMO_ARGS)

experiments: setup
	@$(ENV) && vla_evaluation experiments $(EXPERIMENTS_ARGS)

# BENCH_BRIEF=1: every benchmark briefly (bench/brief.py), as CI runs them: a check that each still runs
bench: setup
	@$(ENV) && export VLA_BENCH_BRIEF=$(BENCH_BRIEF) && \
	  for b in bench/bench_*.py; do echo "== $$b"; python "$$b" || exit 1; done

clean:
	rm -rf build install log

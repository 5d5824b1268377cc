# The two commands of the README: `make demo` and `make test` (unit tests and the representative
# integration tests; `make test-all` runs them all). Both set everything up first.
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: setup demo test test-all lint bench wheel-smoke

setup:
	bash scripts/setup.sh

demo: setup
	$(VENV)/bin/ppd demo

test: setup
	$(VENV)/bin/ruff check --no-cache .
	$(VENV)/bin/lint-imports --no-cache
	$(VENV)/bin/mypy poisoner verifier daemon
	$(PY) -m pytest

# Everything: every integration test (the default runs the representative few, tests/conftest.py)
# and the slow ones on the shared datasets.
test-all: setup
	$(PY) -m pytest -m ''

# The installed ppd (what `pipx install` gives a user who does not clone): wheel built and checked,
# installed alone into a fresh venv, every command run from a temporary folder. CI runs it.
wheel-smoke: setup
	PPD_VENV=$(VENV) bash scripts/wheel_smoke.sh

# mypy: every package of the product ([tool.mypy] in pyproject).
lint: setup
	$(VENV)/bin/ruff check --no-cache .
	$(VENV)/bin/lint-imports --no-cache
	$(VENV)/bin/mypy poisoner verifier daemon

bench:
	PPD_SETUP_BENCH=1 bash scripts/setup.sh
	$(PY) -m bench

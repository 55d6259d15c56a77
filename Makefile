# The project's commands, one target each; `make ci` is what CI runs (.ci/run, in a fresh virtual environment after
# `make install`). Run them in the environment you installed into: `python` is its interpreter.
#
#   make install                 the install of README.md's "Run the tests" (agents, zoo, tests, docs, Causal World)
#   make test                    the whole suite, as README.md runs it; PYTEST_ARGS="-n 0 tests/agents" for a part
#   make test-fast               the tests not marked slow: the edit loop's check
#   make lint                    ruff's lint and format checks
#   make type                    mypy on the five packages (Stable-Baselines3's settings, pyproject.toml)
#   make docs                    the documentation site, warnings as errors, into SITE (default: site/)
#   make ci                      lint, type, docs, then test

PYTHON ?= python
PACKAGES := sb3_sgfd sgfd_envs sgfd_zoo sgfd_analysis sgfd_cli
SITE ?= site
PYTEST_ARGS ?=

.PHONY: install test test-fast lint type docs ci

install:
	$(PYTHON) -m pip install -e ./sgfd_envs -e ".[zoo,test,docs,causalworld]" -c constraints.txt

test:
	$(PYTHON) -m pytest $(PYTEST_ARGS)

test-fast:
	$(PYTHON) -m pytest -m "not slow" $(PYTEST_ARGS)

lint:
	$(PYTHON) -m ruff check .
	$(PYTHON) -m ruff format --check .

type:
	$(PYTHON) -m mypy $(PACKAGES)

docs:
	$(PYTHON) -m mkdocs build --strict --site-dir "$(SITE)"

ci: lint type docs test

# softpend: set-up, tests and the executable book.
#
#   make book [PROFILE=full|quick]   train the runs the notebooks read (softpend sweep --book), then execute the
#                                    notebooks and build the HTML book into _build/html (softpend book --html);
#                                    BOOK_ARGS="--set plant=beam" regenerates the figure set on the continuum beam
#   make test [TEST_WORKERS=auto|N]  the static checks of make lint (mypy beside the tests), and the fast test
#                                    suite (pytest -m 'not expensive') on pytest-xdist workers, one per CPU core
#   make test-expensive              only the long checks
#   make lint                        ruff check, ruff format --check (softpend, tests) and mypy (softpend)
#   make format                      ruff format and the safe ruff fixes of softpend and tests
#   make bench                       measured performance figures (softpend bench --json)
#   make lock                        regenerate environment.lock from pyproject.toml (the ONLY way to edit it)
#   make clean                       remove .venv, _build and the generated notebooks
#
# Every target that runs Python first (re)creates .venv from environment.lock when .venv is missing or older than
# environment.lock / pyproject.toml (the stamp file .venv/.softpend-installed records the last install).

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help

PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.softpend-installed
PROFILE ?= full
PYTEST_ARGS ?=
# pytest-xdist workers for `make test` (auto: one per CPU core; 0 runs the tests in this process)
TEST_WORKERS ?= auto
BOOK_ARGS ?=

# pip on these machines prints one "Location ... is ignored" warning per configured index; drop those lines only.
# `|| true` keeps grep's "no lines left" status from failing the recipe; with pipefail pip's own status still does.
PIP_QUIET := 2>&1 | { grep -v -E 'Location .* is ignored' || true; }

.PHONY: bytecode help venv book test test-expensive lint format bench lock clean

help:
	@sed -n '3,13p' Makefile | sed 's/^# \{0,1\}//'

venv: $(STAMP)

$(STAMP): environment.lock pyproject.toml
	@echo "[make] installing .venv from environment.lock (takes about a minute on a fresh machine)"
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --no-compile -r environment.lock $(PIP_QUIET)
	$(VENV)/bin/pip install -q --no-deps -e . $(PIP_QUIET)
	@# the installed packages' bytecode, compiled on every core (pip compiles one file after another), but not of
	@# their own test suites (folders test/ and tests/: a fifth of the files, never imported here); a file that
	@# does not compile on this Python (test data in some packages) is left without, as pip leaves it
	$(VENV)/bin/python -m compileall -q -q -j 0 -x '/tests?/' $(VENV)/lib || true
	@# fails when pyproject.toml names a dependency that environment.lock lacks
	$(VENV)/bin/pip check $(PIP_QUIET) || { echo "[make] .venv does not satisfy pyproject.toml: run 'make lock'" >&2; exit 1; }
	touch $(STAMP)

# softpend's bytecode, written before the book or the tests: the editable install has none, and where
# PYTHONDONTWRITEBYTECODE is set every test process, notebook kernel and spawned worker would compile it again
bytecode: $(STAMP)
	$(VENV)/bin/python -m compileall -q softpend

# Two steps: the training runs first (one pool of workers over every run still missing), then the notebooks
# (which find their runs finished) and the HTML.
book: $(STAMP) bytecode
	$(VENV)/bin/softpend sweep --book --profile $(PROFILE)
	$(VENV)/bin/softpend book --profile $(PROFILE) --html $(BOOK_ARGS)

# The same checks as `make lint`, with mypy running beside the tests (its report is printed after them; either
# failing fails the target).
test: $(STAMP) bytecode
	$(VENV)/bin/ruff check softpend tests
	$(VENV)/bin/ruff format --check softpend tests
	@mypy_log=$$(mktemp /tmp/softpend-mypy.XXXXXX); trap 'rm -f "$$mypy_log"' EXIT; \
	$(VENV)/bin/mypy > "$$mypy_log" 2>&1 & mypy_pid=$$!; \
	$(VENV)/bin/python -m pytest -n $(TEST_WORKERS) -m 'not expensive' $(PYTEST_ARGS) && tests=0 || tests=$$?; \
	wait $$mypy_pid && types=0 || types=$$?; \
	echo "[make] mypy:"; cat "$$mypy_log"; \
	exit $$(( tests != 0 ? tests : types ))

test-expensive: $(STAMP)
	$(VENV)/bin/python -m pytest -m expensive $(PYTEST_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check softpend tests
	$(VENV)/bin/ruff format --check softpend tests
	$(VENV)/bin/mypy

format: $(STAMP)
	$(VENV)/bin/ruff check --fix softpend tests
	$(VENV)/bin/ruff format softpend tests

bench: $(STAMP)
	$(VENV)/bin/softpend bench --json

# A throwaway venv gets pyproject.toml's dependencies plus the `test` extra; `pip freeze --exclude-editable`
# leaves softpend itself out.  The local label of the CPU torch wheel (2.13.0+cpu) is dropped: `torch==2.13.0`
# resolves to that wheel from the machine's wheel directory.  Every line must be pinned with `==`.
lock:
	@tmp=$$(mktemp -d /tmp/softpend-lock.XXXXXX); \
	trap 'rm -rf "$$tmp"' EXIT; \
	echo "[make] resolving pyproject.toml dependencies + [test] in a throwaway venv ($$tmp)"; \
	$(PYTHON) -m venv "$$tmp/venv"; \
	"$$tmp/venv/bin/pip" install -q -e '.[test]' $(PIP_QUIET); \
	{ \
	  echo "# environment.lock: every package of the softpend environment, pinned. Generated by \`make lock\`"; \
	  echo "# (a fresh venv with pyproject.toml's dependencies and the [test] extra, then"; \
	  echo "# \`pip freeze --exclude-editable\` with torch's local label removed); do not edit by hand."; \
	  echo "# Python $$("$$tmp/venv/bin/python" -c 'import platform; print(platform.python_version())')"; \
	  "$$tmp/venv/bin/pip" freeze --exclude-editable | sed -E 's/^(torch==[^+]+)\+.*/\1/' | LC_ALL=C sort -f; \
	} > "$$tmp/environment.lock"; \
	bad=$$(grep -v -E '^(#|[A-Za-z0-9_.-]+==[^ ]+$$)' "$$tmp/environment.lock" || true); \
	if [ -n "$$bad" ]; then echo "[make] lock: unpinned lines:" >&2; echo "$$bad" >&2; exit 1; fi; \
	grep -q -x 'torch==2.13.0' "$$tmp/environment.lock" || { echo "[make] lock: torch==2.13.0 missing" >&2; exit 1; }; \
	mv "$$tmp/environment.lock" environment.lock; \
	echo "[make] wrote environment.lock ($$(grep -c '==' environment.lock) packages)"

clean:
	rm -rf $(VENV) _build book/_generated .pytest_cache

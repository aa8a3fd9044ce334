# The whole setup on a fresh machine: `make demo` and `make test` (see README.md).
VENV   ?= .venv
PYTHON ?= python3
PY      = $(VENV)/bin/python
STAMP   = $(VENV)/.installed
export MUJOCO_GL ?= egl

.PHONY: install system-deps demo test lint format bench clean

# Headless MuJoCo rendering needs EGL + Mesa; installed from Debian only when missing.
system-deps:
	@if ! ldconfig -p | grep -q 'libEGL.so.1'; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    apt-get update -qq && apt-get install -y -qq libegl1 libgl1-mesa-dri libegl-mesa0 >/dev/null; \
	  else echo "warning: libEGL not found; install libegl1 libgl1-mesa-dri for depth rendering"; fi; \
	fi

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

install: system-deps $(STAMP)

demo: install
	$(PY) -m compare.quickstart

lint: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: install
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

test: lint
	$(VENV)/bin/pytest

bench: install
	$(PY) -m compare.bench

clean:
	rm -rf $(VENV) results .pytest_cache .ruff_cache

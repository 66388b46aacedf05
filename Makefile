# The README's commands. Thin wrappers: set up once, then run.
#   make demo   — set up, then run the main job on the shipped sample scenario
#   make test   — set up, build the documentation (executing the notebooks), then run the test suite (what CI runs)
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.factorloc-installed
# mkdocs-typer2 calls the `typer` executable of the virtual environment
DOCS_ENV := PATH="$(abspath $(BIN)):$$PATH" NO_MKDOCS_2_WARNING=1
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: setup demo test docs docs-serve browser lint bench clean

# System libraries Open3D's wheel needs, the virtual environment, the package.
$(STAMP): pyproject.toml
	@missing=""; \
	for pair in libusb-1.0.so.0:libusb-1.0-0 libGL.so.1:libgl1 libgomp.so.1:libgomp1; do \
	  lib=$${pair%%:*}; pkg=$${pair##*:}; \
	  ldconfig -p 2>/dev/null | grep -q "$$lib" || missing="$$missing $$pkg"; \
	done; \
	if ! $(PYTHON) -c "import ensurepip, venv" >/dev/null 2>&1; then missing="$$missing python3-venv"; fi; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; \
	fi
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[dev,docs]"
	@# compile the ICP kernels now (numba caches them): the first `factorloc localize` then starts in seconds
	$(BIN)/python -c "import logging; logging.basicConfig(level=logging.INFO, format='%(message)s'); import factorloc.jit as j; j.warm_up()"
	@touch $(STAMP)

setup: $(STAMP)

demo: setup
	$(BIN)/factorloc demo

# Headless Chromium for the site's smoke check (Debian's package), when it can be installed.
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing chromium for the documentation smoke check"; \
	  ( $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq chromium ) \
	  || echo "chromium could not be installed: the site smoke check will fail under make test"; }

# Build the site into ./site; the notebooks are executed on the way (docs/hooks.py).
docs: setup browser
	$(DOCS_ENV) $(BIN)/mkdocs build --strict -f docs/mkdocs.yml

docs-serve: setup
	$(DOCS_ENV) $(BIN)/mkdocs serve -f docs/mkdocs.yml

test: docs
	FACTORLOC_REQUIRE_SITE=1 $(BIN)/python -m pytest -n 2 -q

lint: setup
	$(BIN)/ruff check factorloc tests benchmarks

bench: setup
	$(BIN)/python benchmarks/bench_fuse.py
	$(BIN)/factorloc bench

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis site factorloc-demo docs/tutorials docs/assets/generated

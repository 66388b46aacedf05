# The README's commands. Thin wrappers: set up once, then run.
#   make demo   — set up, then run the main job on the shipped sample scenario
#   make test   — set up, lint (ruff with the complexity rules), build the documentation (executing the notebooks),
#                 then run the test suite (what CI runs)
# Environment: `make setup` installs the exact versions of requirements/lock.txt (as constraints);
#   make lock        — re-resolve the lock from pyproject.toml's ranges (newest compatible releases)
#   make test-latest — the test suite in a throwaway venv without the lock: a refresh's breakage, before it lands
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.factorloc-installed
LOCK := requirements/lock.txt
LATEST_VENV ?= .venv-latest
# mkdocs-typer2 calls the `typer` executable of the virtual environment
DOCS_ENV := PATH="$(abspath $(BIN)):$$PATH" NO_MKDOCS_2_WARNING=1
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
# name==version pairs of two requirement files, normalized (PEP 503 names), and the ones that differ
define LOCK_DIFF
import re, sys
def pins(path):
    out = {}
    for line in open(path):
        m = re.match(r"([A-Za-z0-9_.-]+)==([^ ;#]+)", line.strip())
        if m:
            out[re.sub(r"[-_.]+", "-", m[1]).lower()] = m[2]
    return out
a, b = pins(sys.argv[1]), pins(sys.argv[2])
diff = [f"  {k}: {a.get(k, '-')} -> {b.get(k, '-')}" for k in sorted(a.keys() | b.keys()) if a.get(k) != b.get(k)]
print("\n".join(diff) or "  none")
endef
export LOCK_DIFF

.PHONY: setup demo test docs docs-serve browser lint bench clean lock test-latest fuzz

# System libraries Open3D's wheel needs, the virtual environment, the package.
$(STAMP): pyproject.toml $(LOCK)
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
	$(BIN)/python -m pip install -q -c $(LOCK) -e ".[dev,docs]"
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

test: lint docs
	FACTORLOC_REQUIRE_SITE=1 $(BIN)/python -m pytest -n 2 -q

# The fuzz suite at length (tests/fuzz, issue #21: >= 10,000 generated cases; `make test` runs a few dozen per
# property): prints the tally of typed errors / escaped exceptions / crashes / silent results / sensible results
fuzz: setup
	HYPOTHESIS_PROFILE=fuzz nice -n 10 $(BIN)/python -m pytest -q -p no:xdist tests/fuzz

# ruff with the complexity limits of pyproject.toml (C901, PLR0912, PLR0915), and the formatting
lint: setup
	$(BIN)/ruff check factorloc tests benchmarks
	$(BIN)/ruff format --check factorloc tests benchmarks

bench: setup
	$(BIN)/python benchmarks/bench_fuse.py
	$(BIN)/factorloc bench

# Re-resolve the pinned environment from pyproject.toml's ranges (pip-tools; no machine-local index lines).
lock: setup
	$(BIN)/pip-compile --quiet --upgrade --strip-extras --no-emit-index-url --no-emit-find-links \
	  --extra dev --extra docs --output-file $(LOCK) pyproject.toml

# The suite against the newest releases the ranges allow, in a throwaway venv (the lock is not used).
test-latest:
	rm -rf $(LATEST_VENV)
	$(PYTHON) -m venv $(LATEST_VENV)
	$(LATEST_VENV)/bin/python -m pip install -q --upgrade pip
	$(LATEST_VENV)/bin/python -m pip install -q -e ".[dev,docs]"
	$(LATEST_VENV)/bin/python -m pip freeze --exclude-editable > $(LATEST_VENV)/versions.txt
	@echo "versions that differ from the lock:"; $(LATEST_VENV)/bin/python -c "$$LOCK_DIFF" $(LOCK) $(LATEST_VENV)/versions.txt
	$(LATEST_VENV)/bin/python -m pytest -n 2 -q -p no:cacheprovider
	rm -rf $(LATEST_VENV)

clean:
	rm -rf $(VENV) $(LATEST_VENV) build *.egg-info .pytest_cache .hypothesis site factorloc-demo factorloc-sweep docs/tutorials docs/assets/generated

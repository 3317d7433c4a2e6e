# Two entry points for a newcomer: `make demo` and `make test`. Both create .venv themselves.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.physar-installed
PYTEST_ARGS ?=

.PHONY: demo test test-slow bench env clean docs

env: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip setuptools wheel
	$(PY) -m pip install -q -e '.[dev]'
	@# CHOLMOD (sparse Cholesky, factor once / re-solve many) needs SuiteSparse headers, and OpenBLAS
	@# (Debian's default reference BLAS makes the factorisation ~5x slower).
	@if [ ! -e /usr/include/suitesparse/cholmod.h ] || [ ! -e /usr/lib/x86_64-linux-gnu/openblas-pthread ] || [ ! -e /usr/lib/x86_64-linux-gnu/libGLU.so.1 ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libsuitesparse-dev libopenblas-dev libglu1-mesa libgl1 libxcursor1 libxft2 libxinerama1 libxrender1 libfontconfig1 libgomp1) >/dev/null \
	      || echo "warning: could not install libsuitesparse-dev; physar will use the slower scipy solver"; \
	  else \
	    echo "note: for the fast CHOLMOD solver run: sudo apt-get install libsuitesparse-dev libopenblas-dev && rm -f $(STAMP) && make env"; \
	  fi; \
	fi
	@# Debian's chromium and its driver: the browser test of `physar ar serve` (tests/ar/test_live_browser.py)
	@if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver) >/dev/null \
	      || echo "warning: could not install chromium; the browser test of physar ar serve will be skipped"; \
	  else \
	    echo "note: for the browser test of physar ar serve run: sudo apt-get install chromium chromium-driver"; \
	  fi; \
	fi
	@if [ -e /usr/include/suitesparse/cholmod.h ]; then \
	  $(PY) -m pip install -q -e '.[cholmod]' \
	    || echo "warning: scikit-sparse did not build; physar will use the slower scipy solver"; \
	fi
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q -m "not slow" $(PYTEST_ARGS)

test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow $(PYTEST_ARGS)

demo: $(STAMP)
	$(VENV)/bin/physar demo --out demo_out

bench: $(STAMP)
	$(PY) benchmarks/bench_fem.py

# the documentation site into docs/_build/html (examples run in quick mode; warnings are errors; -E reads every
# page afresh, so an up-to-date page cannot hide its warnings). tests/test_docs_site.py runs this same build in
# `make test` (about a minute on 2 cores) and screenshots it: docs/_build/screenshots.
DOCS_STAMP := $(VENV)/.physar-docs-installed
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(PY) -m pip install -q -e '.[docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	$(VENV)/bin/sphinx-build -b html -W --keep-going -q -E docs docs/_build/html
	@echo "docs: docs/_build/html/index.html"

clean:
	rm -rf $(VENV) demo_out .pytest_cache

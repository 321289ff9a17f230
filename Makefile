# The whole set-up on a fresh machine is `make demo` and `make test`.
# `make docs` builds the user guide (mkdocs.yml, docs/) into site/ with warnings as errors, runs its
# tutorials and checks screenshots of it (tests marked `docs`; Chromium: apt-get install chromium).
# `make screenshots` (after `make demo`) checks the demo's Rerun recordings in the headless viewer.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
DOCS_STAMP := $(VENV)/.installed-docs

.PHONY: demo test test-fast docs screenshots clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(TEST_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@ $(STAMP)

$(DOCS_STAMP): pyproject.toml $(TEST_STAMP)
	$(BIN)/python -m pip install --quiet -e ".[test,docs]"
	touch $@

demo: $(STAMP)
	$(BIN)/python -m dropvision.app.demo

test: $(TEST_STAMP)
	$(BIN)/python -m pytest -n 2 -q -m "not docs"

docs: $(DOCS_STAMP)
	PYTHONPATH=$(CURDIR) $(BIN)/python -m mkdocs build --strict --quiet --site-dir site
	$(BIN)/python -m pytest -n 2 -q -m docs

# the quick loop while changing code: every test but those marked slow (pyproject.toml), under 60 s on 2 cores
test-fast: $(TEST_STAMP)
	$(BIN)/python -m pytest -n 2 -q -m "not slow and not docs"

# needs the demo's out/*.rrd (the tool says so, exit 2, when there are none) and a Vulkan driver
screenshots: $(STAMP)
	$(BIN)/python tools/rerun_screenshot.py

clean:
	rm -rf $(VENV) out site

# Every target bootstraps .venv idempotently: a stamp file is rebuilt only when
# pyproject.toml changes.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DOCS_STAMP := $(VENV)/.installed-docs

.PHONY: run test test-slow bench lint regress docs clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/agv-mission run missions/patrol.yaml

test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 -m "not slow"

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 -m slow

# Every mission under tests/scenarios (slow/ included): task lists, trees, fleets; an XML
# tree runs through the mission that names it; other YAML files are listed as skipped.
regress: $(STAMP)
	$(BIN)/agv-mission regress tests/scenarios --output runs/regress \
		--junit runs/regress/junit.xml --json runs/regress/summary.json

# The documentation site (MkDocs + Material, plugin reference by mkdocstrings): built
# offline, every warning (a broken link, a page left out of the nav) an error.
$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

clean:
	rm -rf $(VENV) runs site

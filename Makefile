# Two entry points, each sets everything up first (idempotent):
#   make demo   -> create .venv, install torch 2.13.0 (CPU) + hocnet, run the demo
#   make test   -> same set-up, then ruff and the test suite (what CI runs)
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup demo test lint bench experiments clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# torch first and pinned: an unpinned torch would pull the CUDA build.
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[dev,learn,sweep]'
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(BIN)/hocnet demo --out demo-output

lint: $(STAMP)
	$(BIN)/ruff check hocnet tests experiments benchmarks conftest.py
	$(BIN)/ruff format --check hocnet tests experiments benchmarks conftest.py

test: $(STAMP) lint
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python benchmarks/hoc.py

clean:
	rm -rf $(VENV) demo-output

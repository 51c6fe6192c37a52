# ineid: `make demo` and `make test` work on a fresh machine with only Python 3.11.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV ?= .venv
PY := $(VENV)/bin/python
INEID := $(VENV)/bin/ineid
STAMP := $(VENV)/.ineid-installed

.PHONY: setup demo test test-slow generate bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: setup
	$(INEID) --version
	$(INEID) robot show sweaty-arm
	$(INEID) generate sweaty-arm --out $(VENV)/demo-generated
	$(PY) -m ineid.demo
	$(INEID) data generate --factorial 10 --frames 100 --seed 1 --out $(VENV)/demo-data.h5 --overwrite
	$(INEID) data info $(VENV)/demo-data.h5

test: setup
	$(PY) -m pytest -q

test-slow: setup
	$(PY) -m pytest -q -m slow

generate: setup
	$(INEID) generate --builtin

bench: setup
	$(PY) benchmarks/regressor.py
	$(PY) benchmarks/data.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis

# ineid: `make demo` and `make test` work on a fresh machine with only Python 3.11.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV ?= .venv
PY := $(VENV)/bin/python
INEID := $(VENV)/bin/ineid
STAMP := $(VENV)/.ineid-installed
DEV_STAMP := $(VENV)/.ineid-dev-installed

.PHONY: setup setup-dev demo test lint test-slow generate bench clean

# `setup`: what the main job needs; `setup-dev`: plus the test-only reference engines
# (Pinocchio, MuJoCo, example-robot-data: several hundred MB the demo does not need).
setup: $(STAMP)

setup-dev: $(DEV_STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $(STAMP)

$(DEV_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(DEV_STAMP)

demo: setup
	$(INEID) --version
	$(INEID) robot show sweaty-arm
	$(INEID) generate sweaty-arm --out $(VENV)/demo-generated
	$(PY) -m ineid.demo
	$(INEID) -q data generate sweaty-arm --factorial 10 --n-frames 100 --seed 1 --noise force=0.5,moment=0.05 \
		--out $(VENV)/demo-data.h5 --overwrite
	$(INEID) -q solve $(VENV)/demo-data.h5 --method consistent --weights estimate --select 0:20 \
		--out $(VENV)/demo-results.h5 --report $(VENV)/demo-report.html --overwrite
	$(INEID) export-urdf $(VENV)/demo-results.h5 --config 0 --out $(VENV)/demo-identified.urdf --overwrite
	$(INEID) -q train $(VENV)/demo-data.h5 --arch net2 --sample-frames 10 --siamese --loss physics --beta 10 \
		--epochs 30 --batch 32 --lr 3e-3 --out $(VENV)/demo-run --overwrite

test: setup-dev lint
	$(PY) -m pytest -q -n 2 --durations=25

# The linter and the formatter (ruff; the rules in pyproject.toml): part of `make test`.
lint: setup-dev
	$(VENV)/bin/ruff check ineid tests benchmarks
	$(VENV)/bin/ruff format --check ineid tests benchmarks

test-slow: setup-dev
	$(PY) -m pytest -q -m slow

generate: setup
	$(INEID) generate --builtin

bench: setup-dev
	$(PY) benchmarks/regressor.py
	$(PY) benchmarks/compile.py
	$(PY) benchmarks/public_api.py
	$(PY) benchmarks/joint_torques.py
	$(PY) benchmarks/data.py
	$(PY) benchmarks/identify.py
	$(PY) benchmarks/learn.py
	$(PY) benchmarks/recordings.py
	$(PY) benchmarks/formulations.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis

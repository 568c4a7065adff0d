# hippo_nav — `make help` lists the targets. Everything installs into ./.venv from the project's own files.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.deps-installed

.PHONY: help setup develop demo test test-rust test-python bench bench-gtsam lint

help: ## list targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed 's/:.*## /\t/'

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip "maturin>=1.7,<2"
	touch $(STAMP)

setup: $(STAMP) ## create .venv and install build tools

develop: setup ## build the Rust engine (release) and install hippo_nav with its test extras into .venv
	$(VENV)/bin/maturin develop --release --quiet --extras test

demo: develop ## the main job: run hippo-nav on the built-in synthetic demo sequence
	$(VENV)/bin/hippo-nav run --out runs/demo --overwrite

test-rust: ## Rust core tests
	cargo test --workspace

test-python: develop ## Python tests (benchmarks skipped)
	$(PY) -m pytest

test: test-rust test-python ## the whole test suite (what CI runs)

bench: develop ## criterion and pytest-benchmark benchmarks
	cargo bench --workspace
	mkdir -p runs
	$(PY) -m pytest --benchmark-only --benchmark-enable --benchmark-json=runs/bench.json tests/benchmarks
	$(PY) tests/benchmarks/table.py runs/bench.json

bench-gtsam: setup ## the pose-graph solver against GTSAM's LM, one table (installs the optional gtsam)
	$(VENV)/bin/maturin develop --release --quiet --extras test,bench
	$(PY) tests/benchmarks/posegraph_vs_gtsam.py

lint: develop ## formatting, lints, type checks and the stub check (CI runs it before the tests)
	cargo fmt --all -- --check
	cargo clippy --workspace --all-targets -- -D warnings
	$(VENV)/bin/ruff check python tests
	$(VENV)/bin/ruff format --check python tests
	$(PY) -m mypy
	$(PY) -m mypy.stubtest hippo_nav._core

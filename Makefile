# hippo_nav — `make help` lists the targets. Everything installs into ./.venv from the project's own files.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.deps-installed

.PHONY: help setup runtime develop demo test test-all test-rust test-python test-python-all
.PHONY: bench bench-gtsam lint
.PHONY: wheel wheel-check

help: ## list targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed 's/:.*## /\t/'

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip "maturin>=1.7,<2"
	touch $(STAMP)

setup: $(STAMP) ## create .venv and install build tools

runtime: setup ## build the Rust engine (release) and install hippo_nav with its runtime dependencies only
	$(VENV)/bin/maturin develop --release --quiet

develop: setup ## build the Rust engine (release) and install hippo_nav with its test extras into .venv
	$(VENV)/bin/maturin develop --release --quiet --extras test

# The demo needs only the runtime dependencies: the test and lint extras (Ray, evo, Rerun, mypy, …) are
# minutes of downloads a first run does not use. A .venv that has them keeps them.
demo: runtime ## the main job: run hippo-nav on the built-in synthetic demo sequence
	$(VENV)/bin/hippo-nav run --out runs/demo --overwrite

test-rust: ## Rust core tests, every crate, debug assertions on (after a Rust change; CI runs it)
	cargo test --workspace

# The fast selection: every area, without the tests marked slow (whole sequences, Ray clusters, the
# long-run equivalences; `pytest --markers` and docs/testing.md say which and why), each test stopped
# after PYTEST_FAST_TIMEOUT_S, spread over one pytest-xdist worker per core (PYTEST_WORKERS): much of a
# test is single-threaded Python, so two workers on two cores took 0.69× the time of one (docs/testing.md).
# `make test-all` keeps one process: the slow tests start Ray clusters and time their own signals.
PYTEST_FAST_TIMEOUT_S ?= 120
PYTEST_WORKERS ?= auto
test-python: develop ## Python tests, the fast selection (not slow; a per-test time limit; a worker per core)
	$(PY) -m pytest -m "not slow" --timeout=$(PYTEST_FAST_TIMEOUT_S) -n $(PYTEST_WORKERS)

test-python-all: develop ## every Python test, slow ones included (benchmarks skipped)
	$(PY) -m pytest

# The Rust core's own tests are not in the fast command: their build reuses little of the engine's
# (criterion, rand and pyo3 turn on different features of serde, syn, either and zerocopy, so faer
# and nalgebra compile again), 3.4 of the 12.5 minutes `make test` took with them on a fresh clone. The
# Python tests drive every crate through the bindings; `make test-rust` is the command after a Rust change.
test: test-python ## the fast test suite: the fast Python selection, every area (minutes)

test-all: test-rust test-python-all ## the whole test suite, slow tests included (what CI runs)

# Real KITTI frames for the per-stage budget (docs/results.md, "Cost"): $(HIPPO_NAV_DATA) or ../shared/data.
KITTI_ROOT ?= $(firstword $(wildcard $(HIPPO_NAV_DATA)/kitti_odometry ../shared/data/kitti_odometry))

bench: develop ## criterion and pytest-benchmark benchmarks, and the per-stage CPU budget on real KITTI 06
	cargo bench --workspace
	mkdir -p runs
	$(PY) -m pytest --benchmark-only --benchmark-enable --benchmark-json=runs/bench.json tests/benchmarks
	$(PY) tests/benchmarks/table.py runs/bench.json
	$(if $(KITTI_ROOT),$(PY) tests/benchmarks/cost_budget.py --kitti $(KITTI_ROOT),@echo "per-stage budget skipped: no KITTI data (set KITTI_ROOT)")

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

# One wheel for CPython 3.10 and later (pyo3's abi3-py310). It is linked with zig (ziglang, from PyPI) against
# glibc 2.28, so it installs on any manylinux_2_28 Linux (RHEL 8, Debian 10, Ubuntu 20.04 and later), not
# only on one as new as the build machine's; maturin refuses the tag if a symbol needs a newer glibc.
# Cargo builds it in target/x86_64-unknown-linux-gnu, beside `make develop`'s target/release.
wheel: setup ## build an abi3 wheel and an sdist into dist/ (maturin build --release)
	$(PY) -m pip install --quiet "ziglang==0.17.1"
	rm -f dist/hippo_nav-*.whl dist/hippo_nav-*.tar.gz
	PATH="$(abspath $(VENV))/bin:$$PATH" $(VENV)/bin/maturin build --release --zig \
		--compatibility manylinux_2_28 --out dist
	$(VENV)/bin/maturin sdist --out dist

wheel-check: ## install dist/'s wheel into a fresh venv (no Rust on PATH); run the CLI, the demo, a README example
	.ci/wheel-check

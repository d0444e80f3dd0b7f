# ciflow: `make demo` runs the main job, `make test` runs every test. Both set up a fresh
# machine on their own (Python venv, libtorch, builds) and skip what is already in place.
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help

VENV := $(CURDIR)/.venv
PYTHON := $(VENV)/bin/python
# One target directory for cargo and maturin so nothing is compiled twice.
export CARGO_TARGET_DIR := $(CURDIR)/target
export LIBTORCH := $(CURDIR)/.libtorch
export LIBTORCH_CXX11_ABI := 1
export LD_LIBRARY_PATH := $(LIBTORCH)/lib:$(LIBTORCH)/cuda-lib$(if $(LD_LIBRARY_PATH),:$(LD_LIBRARY_PATH))
export CIFLOW_PYTHON := $(PYTHON)
export PATH := $(VENV)/bin:$(PATH)
CIFLOW := $(CARGO_TARGET_DIR)/release/ciflow

.PHONY: help setup build python test test-rust test-python demo bench fmt clean

help: ## List the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-12s %s\n", $$1, $$2}'

setup: ## Create .venv and .libtorch (idempotent)
	@scripts/setup-python.sh

build: setup ## Build the CLI (release)
	cargo build --release --locked

python: setup ## Build the Python extension into .venv
	@scripts/build-python.sh

test: build python ## Run all tests (Rust and Python)
	$(MAKE) --no-print-directory test-rust test-python

test-rust:
	cargo test --release --locked --workspace

test-python:
	@scripts/run-pytest.sh

demo: build python ## Run the main job end to end and write out/report.md
	$(PYTHON) scripts/demo.py

bench: build ## Run the benchmarks (ratios measured side by side)
	cargo bench --locked --workspace

fmt:
	cargo fmt --all

clean:
	rm -rf target out

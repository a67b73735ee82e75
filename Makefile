# gs2e: `make demo` and `make test` set everything up on a fresh machine.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
CORES ?= all
# Torch first and pinned: on the project's machines pip takes the local CPU
# wheel for this version; an unpinned torch would pull several GB of CUDA wheels.
TORCH ?= torch==2.13.0
# The demo's report compares its event statistics with this real recording when it exists.
REAL_EVENTS ?= ../shared/data/events/dvxplorer_sample.aedat4
DEMO_CONFIG := $(if $(wildcard $(REAL_EVENTS)),--config 'metrics={real_events: $(abspath $(REAL_EVENTS))}',)

.PHONY: setup demo test test-slow test-all bench dryrun clean-results help

help:
	@echo "make demo      - set up .venv and run the workflow on the built-in demo scene"
	@echo "make test      - set up .venv and run the default test suite"
	@echo "make test-slow - the slow cases (real scenes, long runs)"
	@echo "make bench     - quick benchmarks (benchmarks/*.py --quick)"

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

export PATH := $(abspath $(BIN)):$(PATH)

# PIE-Net (bench.video_learned) without its declared opencv-python and torchvision: the
# model needs torch only, and a second package providing cv2 would break
# opencv-contrib-python-headless. Its weights ship in the wheel (no download at run time).
PIENET ?= event-pienet==1.1.3

$(STAMP): pyproject.toml Makefile | $(BIN)/python
	$(BIN)/pip install -q --upgrade pip setuptools wheel
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -e ".[test]"
	$(BIN)/pip install -q --no-deps "$(PIENET)"
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(BIN)/snakemake --cores $(CORES) --configfile config/config.yaml $(DEMO_CONFIG)
	@echo "demo outputs: results/demo/, report: results/report.html (see README.md, 'What the demo produces')"

# The default tier runs on TEST_WORKERS pytest-xdist workers, one test file per
# worker at a time (cold numba compiles and CLI start-up are single-threaded).
# The slow tier stays serial: its tests share one session-wide pipeline run.
TEST_WORKERS ?= 2

test: $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --durations=30 -m "not slow" tests

test-slow: $(STAMP)
	$(BIN)/python -m pytest -m "slow" tests

test-all: $(STAMP)
	$(BIN)/python -m pytest tests

bench: $(STAMP)
	$(BIN)/pip install -q -e ".[test,bench]"
	set -e; for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b --quick; done

dryrun: $(STAMP)
	$(BIN)/snakemake -n --cores $(CORES)

clean-results:
	rm -rf results logs

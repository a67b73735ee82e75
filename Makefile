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
# ... and runs the video task's methods on these real recordings with APS frames (bench.real_video).
REAL_VIDEO ?= ../shared/data/slider_depth ../shared/data/events/davis346_street_aps.aedat4
comma := ,
empty :=
space := $(empty) $(empty)
REAL_VIDEO_FOUND := $(abspath $(wildcard $(REAL_VIDEO)))
DEMO_CONFIG := $(if $(wildcard $(REAL_EVENTS))$(REAL_VIDEO_FOUND),--config) \
	$(if $(wildcard $(REAL_EVENTS)),'metrics={real_events: $(abspath $(REAL_EVENTS))}',) \
	$(if $(REAL_VIDEO_FOUND),'bench={real_video: [$(subst $(space),$(comma)$(space),$(REAL_VIDEO_FOUND))]}',)

.PHONY: setup demo test test-slow test-all bench dataset finetune sim2real table1 dryrun clean-results help

help:
	@echo "make demo      - set up .venv and run the workflow on the built-in demo scene"
	@echo "make test      - set up .venv and run the default test suite"
	@echo "make test-slow - the slow cases (real scenes, long runs)"
	@echo "make bench     - quick benchmarks (benchmarks/*.py --quick)"
	@echo "make dataset   - every real capture of ../shared/data through the workflow, gated; failed scenes reported"
	@echo "make finetune  - PIE-Net-Lite fine-tuned on gs2e data of every passed capture, scored before and after"
	@echo "make sim2real  - simulated against real events on ECD slider_depth; DAVIS346 background refit"
	@echo "make table1    - the paper's Table 1 (event-based 3DGS by speed) on three real scenes"

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

# Every real capture of ../shared/data (config/dataset.tsv, 15 scenes) at the cost model's
# settings with quality gates (config/dataset.yaml). A scene that fails is reported with
# its reason and the others finish; exit status 3 when some failed (docs/dataset.md).
dataset: $(STAMP)
	$(BIN)/python -m gs2e dataset --configfile config/config.yaml config/dataset.yaml --cores $(CORES)

# The data of every real capture plus the demo scene at the dataset's settings (events
# over 1.5 s), each checked
# against the dataset's gates (config/finetune.yaml, about 130 min on 2 cores; exit
# status 3 of gs2e dataset = some scenes failed their gates, which is expected), then
# gs2e bench-finetune through benchmarks/bench_finetune.py: trained on every scene that
# passed, less llff_fern and demo, which are held out (about 20 CPU-min). FINETUNE_DATA
# is config/finetune.yaml's results_dir.
FINETUNE_DATA := results/finetune_data
finetune: $(STAMP)
	$(BIN)/python -m gs2e dataset --configfile config/config.yaml config/finetune.yaml --cores $(CORES) \
	  || [ $$? -eq 3 ]
	$(BIN)/python benchmarks/bench_finetune.py --root $(FINETUNE_DATA)

# slider_depth rebuilt and trained (config/sim2real.tsv, about 4 min on 2 cores), its
# sim-to-real job, then benchmarks/bench_sim2real.py (the tables, the DAVIS346 refit).
SIM2REAL_DATA ?= results/sim2real_data
sim2real: $(STAMP)
	$(BIN)/snakemake --cores $(CORES) --configfile config/config.yaml --config scenes=config/sim2real.tsv results_dir=$(SIM2REAL_DATA) -- $(SIM2REAL_DATA)/slider_depth/sim2real
	$(BIN)/python benchmarks/bench_sim2real.py --root $(SIM2REAL_DATA)

# temple_ring, llff_fern and mouse_colmap at DAVIS346 with recon3d on each speed
# (config/table1.tsv, about 2 h on 2 cores), then the table from the workflow's own
# recon3d jobs through benchmarks/bench_tasks.py.
TABLE1_DATA ?= results/table1_data
table1: $(STAMP)
	$(BIN)/snakemake --cores $(CORES) --configfile config/config.yaml --config scenes=config/table1.tsv results_dir=$(TABLE1_DATA)
	$(BIN)/python benchmarks/bench_tasks.py --part recon3d --scenes temple_ring,llff_fern,mouse_colmap --results $(TABLE1_DATA)

dryrun: $(STAMP)
	$(BIN)/snakemake -n --cores $(CORES)

clean-results:
	rm -rf results logs

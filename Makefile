# make repro: set up everything and run the whole pipeline on the simulated skin.
# make test:  set up everything and run the tests.
# make bench: bench/dvc.yaml, per scene: variants' run time against error, the Bayes bound;
#             the soak (a whole scene over a faulty link, two SIGKILLs); then the fuzzers
#             (100,000 inputs each), the import's memory, the trained stacks' live
#             latency, and cross-validation on Dask against loky.
# make stress: the numerical stress suite (stress/dvc.yaml), per scene.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(CURDIR)/$(VENV)/bin
export PATH := $(BIN):$(PATH)
export DVC_NO_ANALYTICS := 1
export MLFLOW_ENABLE_TELEMETRY := false
export DO_NOT_TRACK := 1

.PHONY: setup browser avr firmware postgres lab-server repro bench stress test lint clean

setup: $(VENV)/.installed

# The report page is tested in headless Chromium: Debian's, installed where missing.
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
browser:
	@command -v chromium >/dev/null || { \
	  echo "installing Debian's chromium for the report test"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium; }

# The board's firmware (firmware/eskin, issue 19) with Debian's AVR toolchain and Arduino
# core; simavr runs it. Installed where missing, as chromium is.
AVR_PACKAGES := gcc-avr avr-libc arduino-core-avr arduino-mk simavr libsimavr-dev
avr:
	@command -v avr-gcc >/dev/null && command -v simavr >/dev/null && \
	  [ -f /usr/share/arduino/Arduino.mk ] && [ -f /usr/include/simavr/sim_avr.h ] || { \
	  echo "installing Debian's AVR toolchain and simavr for the firmware"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
	    $(AVR_PACKAGES); }

# A lab's tracking server (eskin/lab.py): MLflow on Debian's PostgreSQL, installed where
# missing; its tests start one on 127.0.0.1.
postgres:
	@{ command -v pg_ctl >/dev/null || ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1; } || { \
	  echo "installing Debian's postgresql for the lab tracking server"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
	    postgresql; }

# PostgreSQL and `mlflow server --serve-artifacts` on it, data in .lab/, until Ctrl-C;
# then, in each clone: export MLFLOW_TRACKING_URI=http://127.0.0.1:5000
lab-server: setup postgres
	python -m eskin.lab serve --dir .lab

# firmware/eskin/build/eskin.{hex,elf}, the flash and RAM used in size.txt, and the
# emulation harness that runs it under simavr (firmware/emulator/build/eskin_emulator).
firmware: avr
	$(MAKE) -C firmware/eskin --no-print-directory
	$(MAKE) -C firmware/emulator --no-print-directory
	avr-size -C --mcu=atmega328p firmware/eskin/build/eskin.elf \
	  | tee firmware/eskin/build/size.txt

# Rebuilt whenever the package list or the pinned versions change.
$(VENV)/.installed: pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev]'
	touch $@

repro: setup
	dvc repro
	@dvc status dvc.yaml --quiet && echo "pipeline up to date"

# Outside `make repro`: `dvc repro` reads only the top-level dvc.yaml.
bench: setup
	dvc repro dvc.yaml bench/dvc.yaml
	@cat reports/benchmark/*/summary.md reports/soak/*.md
	@cat reports/fuzz/parser.json reports/fuzz/import.json reports/import_memory.md
	@cat reports/live_latency/*.md reports/dask_scaling/*.md

# Every model under the data real users produce (stress/dvc.yaml): reports/stress.{json,md}.
stress: setup
	dvc repro dvc.yaml stress/dvc.yaml
	@cat reports/stress/*.md

# Two workers, a test file each (its module fixtures, servers and scratch projects stay
# in one process): most of a pipeline test is starting Python processes on one core.
test: setup browser firmware postgres
	pytest -q -n 2 --dist loadfile --durations=15

lint: setup
	ruff check eskin stages tests

clean:
	rm -rf $(VENV) data/raw data/processed

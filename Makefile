# make repro: set up everything and run the whole pipeline on the simulated skin.
# make test:  set up everything and run the tests.
# make bench: bench/dvc.yaml, per scene: variants' run time against error, the Bayes bound;
#             the soak (a whole scene over a faulty link, two SIGKILLs); then the fuzzers
#             (100,000 inputs each), the import's memory, the trained stacks' live
#             latency, cross-validation on Dask against loky, and the harder hour
#             (issue 57: the live stack on harder presses, each part against its targets).
# make stress: the numerical stress suite (stress/dvc.yaml), per scene.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(CURDIR)/$(VENV)/bin
export PATH := $(BIN):$(PATH)
export DVC_NO_ANALYTICS := 1
export MLFLOW_ENABLE_TELEMETRY := false
export DO_NOT_TRACK := 1
# Material for MkDocs prints an end-of-life banner at every build; not a warning.
export NO_MKDOCS_2_WARNING := 1

.PHONY: setup plots-page browser avr firmware postgres sshd lab-server repro bench stress check test docs lint clean FORCE

# `dvc plots show|diff` pages that draw offline (DVC's own page loads vega from a CDN):
# vega, vega-lite and vega-embed, pinned, from npm's registry, checked against the
# sha512 npm publishes, inlined into the page template that .dvc/config.local then names
# (so a checkout without it keeps DVC's own page).
VEGA_BUILDS := \
  vega/5.33.1/build/vega.min.js/1fArfVDUqVbb5z8n+/nVQb+VNBzx8svY6CrsyTK4Ujm4yrd9I1auoKxBAPXLCavY1LcrbHUskQbGUP8gXOzyQw== \
  vega-lite/5.23.0/build/vega-lite.min.js/l4J6+AWE3DIjvovEoHl2LdtCUkfm4zs8Xxx7INwZEAv+XVb6kR6vIN1gt3t2gN2gs/y4DYTs/RPoTeYAuEg6mA== \
  vega-embed/6.29.0/build/vega-embed.min.js/PmlshTLtLFLgWtF/b23T1OwX53AugJ9RZ3qPE2c01VFAbgt3/GSNI/etzA/GzdrkceXFma+FDHNXUppKuM0U6Q==
PLOTS_PAGE := .dvc/plots/offline.html
plots-page: $(PLOTS_PAGE)
$(PLOTS_PAGE): Makefile $(VENV)/.installed
	@set -euo pipefail; work=$$(mktemp -d); trap 'rm -rf "$$work"' EXIT; \
	printf '%s\n' '<!DOCTYPE html>' '<html>' '<head>' '<meta charset="utf-8">' \
	  '<title>eskin: dvc plots</title>' > "$$work/page"; \
	for build in $(VEGA_BUILDS); do \
	  IFS=/ read -r name version dir file sha <<< "$$build"; \
	  curl -fsSL --retry 3 -o "$$work/$$name.tgz" \
	    "https://registry.npmjs.org/$$name/-/$$name-$$version.tgz"; \
	  [ "$$(openssl dgst -sha512 -binary "$$work/$$name.tgz" | base64 -w0)" = "$$sha" ] || \
	    { echo "$$name $$version: the tarball's sha512 is not npm's; not using it" >&2; exit 1; }; \
	  { echo "<script>/* $$name $$version (npm), BSD-3-Clause */"; \
	    tar -xzOf "$$work/$$name.tgz" "package/$$dir/$$file"; echo '</script>'; } >> "$$work/page"; \
	done; \
	printf '%s\n' '<style>body{font-family:sans-serif;margin:1em}' \
	  '.vega-embed{margin:1em 0}</style>' '</head>' '<body>' \
	  '<h1>eskin: dvc plots</h1>' '{plot_divs}' '</body>' '</html>' >> "$$work/page"; \
	mkdir -p $(@D) && mv "$$work/page" $@ && \
	$(BIN)/dvc config --local plots.html_template plots/offline.html && \
	echo "wrote $@ (vega inlined, draws offline), named in .dvc/config.local"

setup: $(VENV)/.installed $(PLOTS_PAGE)

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

# A lab's tracking server (eskin/tracking/lab.py): MLflow on Debian's PostgreSQL, installed where
# missing; its tests start one on 127.0.0.1.
postgres:
	@{ command -v pg_ctl >/dev/null || ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1; } || { \
	  echo "installing Debian's postgresql for the lab tracking server"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
	    postgresql; }

# A lab's DVC remote (eskin/tracking/lab.py): Debian's OpenSSH server, installed where
# missing, run on 127.0.0.1 for the remote only.
sshd:
	@[ -x /usr/sbin/sshd ] || { \
	  echo "installing Debian's openssh-server for the lab's DVC remote"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
	    openssh-server; }

# PostgreSQL and `mlflow server --serve-artifacts` on it, and an SSH server for the DVC
# remote, data in .lab/, until Ctrl-C; it prints what each clone sets
# (MLFLOW_TRACKING_URI=http://127.0.0.1:5000, `dvc remote add`).
lab-server: setup postgres sshd
	python -m eskin.tracking.lab serve --dir .lab

# The paper's skin's firmware/eskin/build/10x10/eskin.{hex,elf}, the flash and RAM used in
# size.txt, and the emulation harness that runs it under simavr
# (firmware/emulator/build/10x10/eskin_emulator). Other sizes: make -C firmware/eskin
# ROWS=R COLUMNS=C (and firmware/emulator); an emulated scene builds its own.
firmware: avr
	$(MAKE) -C firmware/eskin --no-print-directory
	$(MAKE) -C firmware/emulator --no-print-directory
	avr-size -C --mcu=atmega328p firmware/eskin/build/10x10/eskin.elf \
	  | tee firmware/eskin/build/10x10/size.txt

# Rebuilt whenever the package list or the pinned versions change, and where it was made
# for another directory (a project copied or moved with its .venv; venv notes where in
# pyvenv.cfg): its scripts' #! lines run that directory's Python, and its editable install
# imports that directory's eskin.
VENV_MADE_FOR := $(shell sed -n 's/^command = .* //p' $(VENV)/pyvenv.cfg 2>/dev/null)
VENV_ELSEWHERE := $(filter-out $(CURDIR)/$(VENV),$(VENV_MADE_FOR))
$(VENV)/.installed: pyproject.toml constraints.txt $(if $(VENV_ELSEWHERE),FORCE)
ifneq ($(VENV_ELSEWHERE),)
	@echo "$(VENV) was made for $(VENV_ELSEWHERE): rebuilding it here"
	rm -rf $(VENV)
endif
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	# uv (pinned) installs the same pinned packages as pip, in less time. It compiles
	# them to bytecode as pip does: where PYTHONDONTWRITEBYTECODE is set (as on this
	# machine), nothing else writes it, and every process compiled its imports again
	# (2.5 s to import scikit-learn, pandas and MLflow became 6.1 s).
	$(BIN)/python -m pip install --quiet -c constraints.txt uv
	$(BIN)/uv pip install --quiet --compile-bytecode --python $(BIN)/python \
	  -c constraints.txt -e '.[dev]'
	touch $@

# DVC rewrites dvc.lock in place after every stage, and a Ctrl-C in that write cuts it
# short: eskin/lockfile.py runs DVC so that a Ctrl-C stops the running stage instead and
# DVC stops with the lock whole (issue 53; docs/getting-started.md#if-you-pressed-ctrl-c).
DVC_REPRO := python -m eskin.lockfile repro

repro: setup
	$(DVC_REPRO)
	@dvc status dvc.yaml --quiet && echo "pipeline up to date"

# Outside `make repro`: bench/ and stress/ are DVC projects of their own (dvc init
# --subdir), which the project's dvc status, checkout and repro leave out; they read the
# pipeline's outputs, so it runs first.
bench: setup
	$(DVC_REPRO)
	cd bench && $(DVC_REPRO)
	@cat reports/benchmark/*/summary.md reports/soak/*.md
	@cat reports/fuzz/parser.json reports/fuzz/import.json reports/import_memory.md
	@cat reports/live_latency/*.md reports/dask_scaling/*.md reports/lock_interrupts/default.md
	@cat reports/hard_hour/*.md

# Every model under the data real users produce (stress/dvc.yaml): reports/stress.{json,md}.
stress: setup
	$(DVC_REPRO)
	cd stress && $(DVC_REPRO)
	@cat reports/stress/*.md

# The fast tier: the tests that start no pipeline, server, emulator or browser (marked
# `starts`: under ESKIN_CHECK=1 a test that starts one anyway fails and names it) and do
# no heavy training (marked `heavy`: over about 9 s each on this machine, under load).
check: setup
	ESKIN_CHECK=1 pytest -q -n 2 -m "not starts and not heavy and not alone" --durations=10

# Two workers, a test file each (its module fixtures, servers and scratch projects stay
# in one process): most of a pipeline test is starting Python processes on one core.
# Then, on a quiet machine, the tests marked `alone`, which time the machine: a Dask
# worker killed mid-fold (under load the sweep can end before the kill lands; its old
# flake, Dask's memory manager dropping the data the folds share, is survived since
# cd4049e), and live counting on a real-time board.
test: setup browser firmware postgres sshd
	mkdocs build --strict
	pytest -q -n 2 --dist loadfile -m "not alone" --durations=15 --cpu-by-file
	pytest -q -m alone

# The documentation site (mkdocs.yml, docs/) into site/; --strict: a broken link, a missing
# anchor or a page left out of the nav is an error.
docs: setup
	mkdocs build --strict --site-dir site

lint: setup
	ruff check eskin stages tests

clean:
	rm -rf $(VENV) data/raw data/processed

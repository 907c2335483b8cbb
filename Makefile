# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
SHARED ?= ../shared
XSD_SRC := $(SHARED)/qif/xsd
XSD_DST := schemas/qif-3.0
OUT    ?= out/demo

.PHONY: install install-dev system-deps accel accel-if-possible demo test lint bench clean

# Create the venv and install the package (editable) once; re-run when pyproject changes.
# The product's own dependencies only; the test tools come with `make test` (install-dev).
$(VENV)/.installed: pyproject.toml
	@echo "installing qifreport into $(VENV) (the first time: a few minutes)"
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -m pip install -qq -e .
	@if [ -d "$(XSD_SRC)" ]; then rm -rf $(XSD_DST) && mkdir -p $(XSD_DST) && cp -r $(XSD_SRC)/. $(XSD_DST)/ ; \
	  else echo "note: $(XSD_SRC) not found; QIF schemas unavailable (set QIFREPORT_XSD_DIR)"; fi
	@# local copy of the W3C xmldsig schema (QIFDocument.xsd imports it from a remote URL;
	@# there may be no network): xmlschema's bundled copy, beside the official files
	@if [ -d "$(XSD_DST)/QIFLibrary" ]; then \
	  DSIG=$$($(PY) -c "import os, xmlschema; print(os.path.join(os.path.dirname(xmlschema.__file__), 'schemas', 'DSIG', 'xmldsig-core-schema.xsd'))") && \
	  cp "$$DSIG" $(XSD_DST)/QIFLibrary/xmldsig-core-schema.xsd; fi
	@$(MAKE) --no-print-directory accel-if-possible
	@touch $@

# the test tools (pytest, ruff, import-linter and the independent consumers the tests use)
$(VENV)/.dev-installed: $(VENV)/.installed
	@$(PY) -m pip install -qq -e '.[dev]'
	@touch $@

install-dev: install $(VENV)/.dev-installed

# the package's bytecode, written at every install (only what changed): its modules are then
# read, not compiled, by every command, even where the environment forbids writing bytecode
# (PYTHONDONTWRITEBYTECODE, as in many containers)
install: $(VENV)/.installed
	@$(PY) -m compileall -q -j 0 step registration metrology qif qifreport >/dev/null

# Debian packages the tests use: Xerces-C DOMCount (an independent QIF validator),
# poppler-utils (pdftoppm/pdftotext) and chromium (opens the --html viewer headless, WebGL on
# SwiftShader: tests/browser.py). Installed only when the commands are missing; if that is
# impossible (no root/sudo, no apt) print a note and go on: the tests that need them then
# skip, or fail with a clear message under CI=true.
SYSTEM_DEPS := libxerces-c-samples poppler-utils chromium

# how apt-get runs as root here: as is (root), through `sudo -n`, or not at all (`none`)
SUDO = $(shell if [ "$$(id -u)" -eq 0 ]; then echo; \
  elif command -v sudo >/dev/null 2>&1; then echo "sudo -n"; else echo none; fi)

system-deps:
	@if ! { command -v DOMCount && command -v pdftoppm && command -v chromium; } >/dev/null 2>&1; then \
	  if [ "$(SUDO)" != none ] && command -v apt-get >/dev/null 2>&1; then \
	    $(SUDO) apt-get update -qq && \
	    $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(SYSTEM_DEPS) >/dev/null; \
	  fi; \
	  if { command -v DOMCount && command -v pdftoppm && command -v chromium; } >/dev/null 2>&1; then \
	    echo "installed $(SYSTEM_DEPS)"; \
	  else \
	    echo "note: could not install $(SYSTEM_DEPS) (needs apt-get as root or sudo);" \
	         "DOMCount/pdftoppm/chromium tests will skip, or fail under CI=true"; \
	  fi; \
	fi

# Inspect the bundled samples: the STEP panel with semantic PMI (tolerances from the part
# itself, no --tolerance; held at the datum targets its drawing's ISO 10579-NR note names),
# the mesh shell (fallback input, explicit tolerance), a two-scan batch of the panel
# (summary table, QIF Statistics document, trend PDF), and another elastic free state of
# the panel held at the clamps of a file (samples/panel_clamps.csv: the same points).
# Each command's full output goes to $(OUT)/logs/; the demo prints one line per step.
# Nothing here needs a system package: the test tools (Xerces-C, poppler, chromium) are
# installed by `make test`.
demo: install
	@mkdir -p $(OUT)/logs
	@$(VENV)/bin/qifreport pmi samples/panel.step --clamps pmi > $(OUT)/logs/pmi.txt \
	  && echo "pmi:        $$(head -1 $(OUT)/logs/pmi.txt)  [$(OUT)/logs/pmi.txt]"
	@$(VENV)/bin/qifreport samples/panel.step samples/panel_scan.ply --out $(OUT) --json \
	  --force --quiet --html --export-mesh $(OUT)/panel_registered.ply > $(OUT)/logs/panel.txt; \
	  rc=$$?; if [ $$rc -gt 1 ]; then cat $(OUT)/logs/panel.txt; exit $$rc; fi; \
	  echo "panel:      $$(head -1 $(OUT)/logs/panel.txt) -> $(OUT)/panel.{pdf,qif,json,html}"
	@test -s $(OUT)/panel.json && test -s $(OUT)/panel.qif && test -s $(OUT)/panel.pdf \
	  && test -s $(OUT)/panel.html && test -s $(OUT)/panel_registered.ply
	@$(VENV)/bin/qifreport samples/shell_nominal.ply samples/shell_scan.ply --tolerance 0.5 \
	  --out $(OUT) --json --force --quiet --export-mesh $(OUT)/shell_registered.ply \
	  > $(OUT)/logs/shell.txt; rc=$$?; if [ $$rc -gt 1 ]; then cat $(OUT)/logs/shell.txt; \
	  exit $$rc; fi; \
	  echo "shell:      $$(head -1 $(OUT)/logs/shell.txt) -> $(OUT)/shell_nominal.{pdf,qif,json}"
	@test -s $(OUT)/shell_nominal.json && test -s $(OUT)/shell_nominal.pdf \
	  && test -s $(OUT)/shell_registered.ply
	@$(VENV)/bin/qifreport batch samples/panel.step samples/panel_scan.ply \
	  samples/panel_scan_defect.ply --out $(OUT)/batch --force --quiet > $(OUT)/logs/batch.txt; \
	  rc=$$?; if [ $$rc -gt 1 ]; then cat $(OUT)/logs/batch.txt; exit $$rc; fi; \
	  echo "batch:      $$(grep -c . $(OUT)/batch/summary.csv | xargs -I{} expr {} - 1) scans" \
	    "-> $(OUT)/batch/summary.csv, panel_statistics.qif, panel_trend.pdf"
	@test -s $(OUT)/batch/summary.csv && test -s $(OUT)/batch/panel_statistics.qif \
	  && test -s $(OUT)/batch/panel_trend.pdf
	@$(VENV)/bin/qifreport samples/panel.step samples/panel_scan_warped.ply \
	  --clamps samples/panel_clamps.csv --out $(OUT)/restrained --json --html --force \
	  --quiet > $(OUT)/logs/restrained.txt; rc=$$?; if [ $$rc -gt 1 ]; then \
	  cat $(OUT)/logs/restrained.txt; exit $$rc; fi; \
	  echo "restrained: $$(head -1 $(OUT)/logs/restrained.txt) -> $(OUT)/restrained/panel.{pdf,qif,json,html}"
	@test -s $(OUT)/restrained/panel.json && test -s $(OUT)/restrained/panel.qif \
	  && test -s $(OUT)/restrained/panel.pdf && test -s $(OUT)/restrained/panel.html
	@$(VENV)/bin/qifreport validate $(OUT)/panel.qif $(OUT)/shell_nominal.qif \
	  $(OUT)/batch/panel_statistics.qif $(OUT)/restrained/panel.qif > $(OUT)/logs/validate.txt \
	  2>&1 || { cat $(OUT)/logs/validate.txt; exit 2; }; \
	  echo "validate:   4 QIF files valid against the QIF 3.0 schemas [$(OUT)/logs/validate.txt]"
	@echo "outputs in $(OUT)/; open $(OUT)/panel.pdf, or $(OUT)/panel.html in a browser" \
	  "(the deviation map in 3-D); each command's full output in $(OUT)/logs/"

# both cores of the CI machine, a test file per worker (module fixtures stay in one process),
# each worker's BLAS and OpenMP on one thread (two workers on two cores: a second thread per
# worker would only spin against the other worker; the command line sets the same itself)
test: install-dev system-deps
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(PY) -m pytest -q -n 2 --dist loadfile --durations=25

lint: install-dev
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

bench: install
	$(PY) -m pip install -q -e '.[bench]'
	$(PY) bench/compare.py
	$(PY) bench/detectability.py
	$(PY) bench/uncertainty.py

# Optional accelerator: CHOLMOD (scikit-sparse, built against Debian's SuiteSparse, with
# OpenBLAS) for the sparse Cholesky solves of GB-CICP, its bending basis and NICP. `install`
# tries it (Debian packages via apt when root or sudo allows, then the `cholmod` extra) and
# goes on without it: everything runs on scipy's SuperLU then. `make accel` insists.
ACCEL_DEPS := libsuitesparse-dev libopenblas0-pthread

accel-if-possible:
	@if ! $(PY) -c "import sksparse.cholmod" >/dev/null 2>&1; then \
	  if ! dpkg -s $(ACCEL_DEPS) >/dev/null 2>&1 && [ "$(SUDO)" != none ] && \
	     command -v apt-get >/dev/null 2>&1; then \
	    { $(SUDO) apt-get update -qq && $(SUDO) env DEBIAN_FRONTEND=noninteractive \
	      apt-get install -y -qq $(ACCEL_DEPS); } >/dev/null 2>&1 || true; \
	  fi; \
	  if [ -e /usr/include/suitesparse/cholmod.h ] && \
	     $(PY) -m pip install -q -e '.[cholmod]' >/dev/null 2>&1 && \
	     $(PY) -c "import sksparse.cholmod" >/dev/null 2>&1; then \
	    echo "installed the CHOLMOD accelerator (scikit-sparse)"; \
	  else \
	    echo "note: CHOLMOD accelerator not installed (needs $(ACCEL_DEPS) and a C compiler);" \
	         "sparse solves use scipy's SuperLU"; \
	  fi; \
	fi

accel: install
	$(filter-out none,$(SUDO)) env DEBIAN_FRONTEND=noninteractive \
	  apt-get install -y -qq $(ACCEL_DEPS) >/dev/null
	$(PY) -m pip install -q -e '.[cholmod]'
	$(PY) -c "import sksparse.cholmod"

clean:
	rm -rf $(VENV) out .pytest_cache $(XSD_DST)

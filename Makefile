# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
SHARED ?= ../shared
XSD_SRC := $(SHARED)/qif/xsd
XSD_DST := schemas/qif-3.0
OUT    ?= out/demo

.PHONY: install demo test lint bench clean

# Create the venv and install the package (editable) once; re-run when pyproject changes.
$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q -e '.[dev]'
	@if [ -d "$(XSD_SRC)" ]; then rm -rf $(XSD_DST) && mkdir -p $(XSD_DST) && cp -r $(XSD_SRC)/. $(XSD_DST)/ ; \
	  else echo "note: $(XSD_SRC) not found; QIF schemas unavailable (set QIFREPORT_XSD_DIR)"; fi
	touch $@

install: $(VENV)/.installed

# Inspect the bundled samples: the STEP panel with semantic PMI (tolerances from the part
# itself, no --tolerance) and the mesh shell (fallback input, explicit tolerance).
demo: install
	mkdir -p $(OUT)
	$(VENV)/bin/qifreport pmi samples/panel.step
	$(VENV)/bin/qifreport samples/panel.step samples/panel_scan.ply --out $(OUT) --json \
	  --export-mesh $(OUT)/panel_registered.ply; rc=$$?; if [ $$rc -gt 1 ]; then exit $$rc; fi
	test -s $(OUT)/panel.json && test -s $(OUT)/panel_registered.ply
	$(VENV)/bin/qifreport samples/shell_nominal.ply samples/shell_scan.ply --tolerance 0.5 \
	  --out $(OUT) --json --export-mesh $(OUT)/shell_registered.ply; rc=$$?; \
	  if [ $$rc -gt 1 ]; then exit $$rc; fi
	test -s $(OUT)/shell_nominal.json && test -s $(OUT)/shell_registered.ply
	@echo "demo outputs in $(OUT)/"

test: install
	$(PY) -m pytest -q

lint: install
	$(VENV)/bin/ruff check .

bench: install
	$(PY) bench/accuracy.py

clean:
	rm -rf $(VENV) out .pytest_cache $(XSD_DST)

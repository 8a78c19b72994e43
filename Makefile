# facecorr: `make demo` (set up + run the pipeline on bundled defaults), `make test` (set up + all tests).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
export FACECORR_THREADS ?= 2

.PHONY: setup build test test-rust test-py demo bench clean

setup: $(VENV)/.installed

$(VENV)/.installed: requirements-dev.txt pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements-dev.txt
	touch $@

# Release build of the Rust extension, installed (editable) into the venv.
build: setup
	VIRTUAL_ENV=$(abspath $(VENV)) PATH=$(abspath $(VENV))/bin:$$PATH $(VENV)/bin/maturin develop --release --quiet

test-rust:
	cargo test --release --quiet

test-py: build
	$(PY) -m pytest -q tests

test: build test-rust test-py

demo: build
	$(PY) -m facecorr.cli demo --out out/demo

bench: build
	cargo bench
	$(PY) benches/compare_kernels.py

clean:
	rm -rf $(VENV) target out

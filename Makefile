# facecorr: `make demo` (set up + run the pipeline on bundled defaults), `make test` (set up + all tests).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
export FACECORR_THREADS ?= 2

.PHONY: setup build browser test test-rust test-py demo bench clean

setup: $(VENV)/.installed

$(VENV)/.installed: requirements-dev.txt pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements-dev.txt
	touch $@

# Release build of the Rust extension, installed (editable) into the venv.
build: setup
	VIRTUAL_ENV=$(abspath $(VENV)) PATH=$(abspath $(VENV))/bin:$$PATH $(VENV)/bin/maturin develop --release --quiet

# Headless Chromium for the report's browser test (Debian's package; installed when missing and
# run as root, else the test says it is skipped and why).
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) || \
	      echo "make: could not install chromium: the report's browser test will be skipped"; \
	  else echo "make: no chromium (apt-get install chromium): the report's browser test will be skipped"; fi

test-rust:
	cargo test --release --quiet

test-py: build browser
	$(PY) -m pytest -q tests

test: build test-rust test-py

demo: build
	$(PY) -m facecorr.cli demo --out out/demo

bench: build
	cargo bench
	$(PY) benches/compare_kernels.py

clean:
	rm -rf $(VENV) target out

# Set-up and entry points. `make demo` and `make test` each do the whole set-up on a fresh
# Debian machine with Python 3.11, then run.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SYS_STAMP := $(VENV)/.system-packages
DEMO_DRIVE ?= demo_output/sample_drive

BROWSER := /usr/bin/chromium

.PHONY: setup demo serve test lint docs bench clean browser

setup: $(STAMP)

# open3d links against libusb and libgomp at import time; Debian's Python needs its venv package.
$(SYS_STAMP):
	@missing=""; \
	PATH="$$PATH:/sbin:/usr/sbin"; ldconfig -p | grep -q libusb-1.0.so.0 || missing="$$missing libusb-1.0-0"; \
	ldconfig -p | grep -q libgomp.so.1 || missing="$$missing libgomp1"; \
	$(PYTHON) -c 'import ensurepip, venv' 2>/dev/null || missing="$$missing python3-venv"; \
	if [ -n "$$missing" ]; then \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		echo "installing system packages:$$missing"; \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq $$missing; \
	fi
	@mkdir -p $(VENV) && touch $@

$(STAMP): pyproject.toml $(SYS_STAMP)
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	# torch pinned first: an unpinned torch pulls a multi-GB CUDA build.
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e '.[dev]'
	@touch $@

# The demo ends by serving the sample drive in the review app (Ctrl+C stops it).
demo: setup
	$(BIN)/guardrail demo --out $(DEMO_DRIVE)
	$(BIN)/guardrail serve $(DEMO_DRIVE) --run $(dir $(DEMO_DRIVE))run --model $(dir $(DEMO_DRIVE))model

serve: setup
	$(BIN)/guardrail serve $(DEMO_DRIVE) --run $(dir $(DEMO_DRIVE))run --model $(dir $(DEMO_DRIVE))model

# Browser tests drive Debian's Chromium (Playwright's own browser download cannot work offline).
browser:
	@test -x $(BROWSER) || { \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		echo "installing Debian's chromium for the browser tests"; \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq chromium; }

lint: setup
	$(BIN)/ruff check guardrail_core app tests benchmarks docs
	$(BIN)/ruff format --check guardrail_core app tests benchmarks docs
	$(BIN)/mypy

# The documentation site; the tests build it too (tests/test_docs_reference.py).
docs: setup
	$(BIN)/sphinx-build -W --keep-going -q -b html docs docs/_build/html
	@echo "open docs/_build/html/index.html"

test: lint browser
	$(BIN)/pytest -n 2 -q

bench: setup
	$(BIN)/python benchmarks/bench_simulate.py
	@test -f $(DEMO_DRIVE)/drive.json || $(BIN)/guardrail demo --out $(DEMO_DRIVE) --quiet
	$(BIN)/python benchmarks/bench_extract.py --drive $(DEMO_DRIVE)
	$(BIN)/python benchmarks/bench_reconstruct.py --run $(dir $(DEMO_DRIVE))run
	$(BIN)/python benchmarks/bench_app.py --drive $(DEMO_DRIVE) --run $(dir $(DEMO_DRIVE))run

clean:
	rm -rf $(VENV) demo_output .pytest_cache .ruff_cache .mypy_cache docs/_build

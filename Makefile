# kitbench: `make demo` (the main job) and `make test`. Both bootstrap what is missing:
# system packages (Vulkan driver, ffmpeg; via apt when root), uv, and the venv from uv.lock.
SHELL := /bin/bash
.DEFAULT_GOAL := demo
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.kitbench-synced
PYTEST_ARGS ?=

.PHONY: demo test bench doctor bootstrap system clean

system:
	@bash scripts/bootstrap-system.sh

$(STAMP): uv.lock pyproject.toml .python-version
	@UV=$$(bash scripts/ensure-uv.sh) && \
	  echo "kitbench: syncing the environment from uv.lock" && \
	  $$UV sync --frozen --compile-bytecode --quiet || { \
	    echo "kitbench: 'uv sync --frozen' failed: it needs Python 3.12 (see .python-version) and the package index" >&2; exit 1; }
	@touch $@

bootstrap: system $(STAMP)

demo: bootstrap
	@$(PY) -m kitbench.cli demo

test: bootstrap
	@$(PY) -m pytest $(PYTEST_ARGS)

bench: bootstrap
	@$(PY) bench/run.py

doctor: bootstrap
	@$(PY) -m kitbench.cli doctor

clean:
	rm -rf outputs .pytest_cache

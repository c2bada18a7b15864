# Neuro-IK Lab. `make app` and `make test` are the quick start; each creates .venv when missing.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
# one BLAS thread: pycma runs 3x slower when threaded BLAS fights another busy process on 2 cores
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

.PHONY: install app test bench bench-arms browser clean help

help:
	@echo "make app      create .venv if missing, install, start the lab on http://127.0.0.1:8080"
	@echo "make test     create .venv if missing, install, run the test suite"
	@echo "make bench    run the benchmarks (prints ratios measured side by side)"
	@echo "make bench-arms  train every real arm with its defaults and measure it (about 40 minutes)"
	@echo "make clean    remove .venv and caches"

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	$(PY) -m lab.running.warmup
	@touch $(STAMP)

install: $(STAMP)

# Debian's chromium for the browser test (no browser download); installed only where missing
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian's chromium for the browser test"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends chromium >/dev/null; }

app: install
	$(PY) -m app $(ARGS)

test: install browser
	$(PY) -m pytest $(PYTEST_ARGS)

bench: install
	$(PY) benchmarks/bench_fk.py --arms planar,scara,ur5,panda,kinova
	$(PY) benchmarks/bench_speed.py --generations 1000 --rounds 3
	$(PY) benchmarks/bench_recording.py

bench-arms: install
	$(PY) benchmarks/bench_arms.py

clean:
	rm -rf $(VENV) .pytest_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

# Neuro-IK Lab. `make app` and `make test` are the quick start; each creates .venv when missing.
# .venv is made with PYTHON when you set it (make PYTHON=/path/to/python3.13 app), else with the
# first of python3, python3.30 ... python3.6 (newest first) on PATH whose version is within
# requires-python in pyproject.toml: the one place the supported versions are stated.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
WARM   := $(VENV)/.warm-stamp
REQUIRES_PYTHON := $(shell sed -n 's/^requires-python *= *"\([^"]*\)".*/\1/p' pyproject.toml)
# ">=3.11,<3.15" reads "3.11-3.14" in messages; any other form is shown as it is written
PYTHON_RANGE := $(or $(shell echo '$(REQUIRES_PYTHON)' | sed -n 's/^ *>= *3\.\([0-9]*\) *, *< *3\.\([0-9]*\) *$$/\1 \2/p' \
                  | { read lo hi && echo "3.$$lo-3.$$(($$hi - 1))"; }),$(REQUIRES_PYTHON))
# one BLAS thread: pycma runs 3x slower when threaded BLAS fights another busy process on 2 cores
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

# Run by a candidate python with requires-python as argument: prints its version ("3.13.0"), exits 0
# when that is within requires-python (CPython only: the dependencies ship CPython wheels). With a
# second argument "venv" it also checks that the venv's python is still the one it was made with.
define PYCHECK
import os, re, sys
spec = sys.argv[1]
v = tuple(sys.version_info[:3])
print('%d.%d.%d' % v)
def within(clause):
    m = re.match(r'\s*(~=|===|==|!=|<=|>=|<|>)\s*([0-9]+(?:\.[0-9]+)*)(\.\*)?\s*$$', clause)
    if not m:
        sys.exit('cannot read requires-python %r' % spec)
    op, num, star = m.groups()
    want = tuple(int(x) for x in num.split('.'))
    if star:
        return (v[:len(want)] == want) == (op == '==')
    w = (want + (0, 0, 0))[:3]
    if op == '~=':
        return v >= w and v[:len(want) - 1] == want[:-1]
    return {'==': v == w, '===': v == w, '!=': v != w, '<=': v <= w, '>=': v >= w, '<': v < w, '>': v > w}[op]
if sys.implementation.name != 'cpython' or not all(within(c) for c in spec.split(',') if c.strip()):
    sys.exit(1)
if sys.argv[2:] == ['venv']:
    cfg = os.path.join(sys.prefix, 'pyvenv.cfg')
    made = ''
    if os.path.exists(cfg):
        for line in open(cfg):
            key, _, value = line.partition('=')
            if key.strip() in ('version', 'version_info'):
                made = value.strip()
    if made and made.split('.')[:2] != [str(v[0]), str(v[1])]:
        print('made with Python %s' % made)
        sys.exit(1)
endef
export PYCHECK

PYTHON_CANDIDATES = $(if $(filter undefined,$(origin PYTHON)),python3 $$(seq -f 'python3.%g' 30 -1 6),$(PYTHON))

# shell: prints the interpreter to make .venv with, or says why there is none and fails
PICK_PYTHON = ok=; found=; broken=; missing=; \
  for p in $(PYTHON_CANDIDATES); do \
    command -v "$$p" >/dev/null 2>&1 || { $(if $(filter undefined,$(origin PYTHON)),[ "$$p" != python3 ] ||) missing="$$missing $$p"; continue; }; \
    if v=$$("$$p" -c "$$PYCHECK" '$(REQUIRES_PYTHON)' 2>/dev/null); then ok=$$(command -v "$$p"); break; fi; \
    if [ -n "$$v" ]; then found="$$found$${found:+, }$$p $$v"; else broken="$$broken $$p"; fi; \
  done; \
  if [ -n "$$ok" ]; then echo "$$ok"; else \
    echo "Neuro-IK Lab needs Python $(PYTHON_RANGE) (requires-python \"$(REQUIRES_PYTHON)\" in pyproject.toml)," >&2; \
    echo "found: $${found:-no usable python}$${broken:+; on PATH but did not run:$$broken}$${missing:+; not found:$$missing}." >&2; \
    echo "Install one of those versions, or run: make PYTHON=/path/to/python$(or $(lastword $(subst -, ,$(PYTHON_RANGE))),3.X) $(or $(MAKECMDGOALS),install)" >&2; \
    exit 1; fi

# shell: fails, saying why, when .venv exists but its python is not one Neuro-IK Lab can use
CHECK_VENV = if [ -e $(VENV) ]; then \
    if [ ! -x $(PY) ]; then \
      echo "$(VENV) exists but $(PY) is missing or points at a Python that is gone (removed or upgraded?)" >&2; \
      echo "run make clean (it removes $(VENV)), then make again: it makes $(VENV) anew" >&2; exit 1; fi; \
    v=$$($(PY) -c "$$PYCHECK" '$(REQUIRES_PYTHON)' venv 2>/dev/null); rc=$$?; \
    if [ $$rc -ne 0 ]; then \
      case "$$v" in \
        "") echo "$(VENV)'s python does not run (was the Python it was made with removed or upgraded?)" >&2;; \
        *"made with"*) echo "$(VENV) was $$(echo "$$v" | tail -1) but its python is now $$(echo "$$v" | head -1) (the Python it was made with was upgraded)" >&2;; \
        *) echo "$(VENV) was made with Python $$v; Neuro-IK Lab needs Python $(PYTHON_RANGE) (requires-python \"$(REQUIRES_PYTHON)\" in pyproject.toml)" >&2;; \
      esac; \
      echo "run make clean (it removes $(VENV)), then make again: it makes $(VENV) anew with $(if $(filter undefined,$(origin PYTHON)),the first usable python it finds,$(PYTHON))" >&2; exit 1; fi; fi

# shell: pip install $(2) with pip's output in PIP_LOG (the last install's); on a terminal one line that
# says how far it is (the packages found, the last one it works on); the packages installed when done;
# pip's error and the end of its log when it fails
PIP_LOG := $(VENV)/pip.log
define QUIET_PIP
log=$(PIP_LOG); echo '== pip install $(2)' > $$log; \
$(PY) -m pip install --progress-bar off $(2) >> $$log 2>&1 & pid=$$!; \
if [ -t 1 ]; then \
  while kill -0 $$pid 2>/dev/null; do \
    n=$$(grep -c '^Collecting' $$log); \
    last=$$(grep -E '^(Collecting|Downloading|Building|Installing collected)' $$log | tail -n 1 | cut -c1-56); \
    printf '\r  %s: %s packages; %-56s' "$(1)" "$$n" "$$last"; sleep 1; \
  done; printf '\r%90s\r' ''; \
fi; \
wait $$pid; rc=$$?; \
if [ $$rc -ne 0 ]; then \
  echo "installing $(1) failed (pip's exit status $$rc); the end of $$log:" >&2; tail -n 40 $$log >&2; exit $$rc; \
fi; \
done=$$(sed -n 's/^Successfully installed //p' $$log | wc -w); \
echo "  $(1): $$done packages installed or upgraded"
endef

.PHONY: install app test bench bench-arms browser clean help python notebook

help:
	@echo "make app      create .venv if missing, install, start the lab on http://127.0.0.1:8080"
	@echo "make test     create .venv if missing, install, run the test suite"
	@echo "make notebook open the students' notebook (examples/evolve_an_arm.ipynb) in Jupyter (installs it the first time)"
	@echo "make bench    run the benchmarks (prints ratios measured side by side)"
	@echo "make bench-arms  train every real arm with its defaults and measure it (about 40 minutes)"
	@echo "make clean    remove .venv and caches"
	@echo "make python   say which python .venv is (or will be) made with"

$(STAMP): pyproject.toml
	@$(CHECK_VENV)
	@test -e $(VENV) || { py=$$($(PICK_PYTHON)) && echo "making $(VENV) with $$py ($$($$py -c 'import platform; print(platform.python_version())'))" \
	  && { $$py -m venv $(VENV) || { rm -rf $(VENV); exit 1; }; }; }
	@echo "installing Neuro-IK Lab and its dependencies into $(VENV): about 1 GB the first time (Pinocchio and"
	@echo "the robots' meshes, Rerun, numba, playwright for the browser tests): a few minutes; pip's log: $(PIP_LOG)"
	@$(call QUIET_PIP,pip,--upgrade pip)
	@$(call QUIET_PIP,Neuro-IK Lab,-e ".[dev]")
	@touch $(STAMP)

# numba's kernels compiled once: make test compiles them all first, with a line per step; make app only
# those of the first Start (the default method on the planar arm: about 20 s on 2 quiet cores, once),
# so a fresh clone's first Start trains at once; the app compiles the rest in the background
# (lab/running/warmup.py, docs/app.md). numba's cache is for this machine's CPU, where it was built.
APPWARM := $(VENV)/.app-warm-stamp
$(WARM): $(STAMP)
	$(PY) -m lab.running.warmup
	@touch $(WARM) $(APPWARM)

$(APPWARM): $(STAMP)
	@echo "compiling the training kernels of a first Start (once: later starts load them from numba's cache)"
	$(PY) -m lab.running.warmup --first
	@touch $(APPWARM)

install: $(STAMP)
	@$(CHECK_VENV)

# which python .venv is made with (or was): make python, make PYTHON=/path/to/python3.12 python
python:
	@$(CHECK_VENV)
	@if [ -e $(VENV) ]; then echo "$(PY): Python $$($(PY) -c 'import platform; print(platform.python_version())'), within $(PYTHON_RANGE)"; \
	else py=$$($(PICK_PYTHON)) && echo "$$py: Python $$($$py -c 'import platform; print(platform.python_version())'), within $(PYTHON_RANGE); make install makes $(VENV) with it"; fi

# Debian's chromium for the browser test (no browser download); installed only where missing
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian's chromium for the browser test"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends chromium >/dev/null; }

app: install $(APPWARM)
	$(PY) -m app $(ARGS)

test: install browser $(WARM)
	$(PY) -m pytest $(PYTEST_ARGS)

# the students' notebook in Jupyter; Jupyter (the notebook extra in pyproject.toml) is installed the first time
notebook: install
	@$(PY) -c "import notebook" 2>/dev/null || { $(call QUIET_PIP,Jupyter,-e ".[notebook]"); }
	$(VENV)/bin/jupyter notebook $$( [ "$$(id -u)" = 0 ] && echo --allow-root ) examples/evolve_an_arm.ipynb

bench: install
	$(PY) benchmarks/bench_fk.py --arms planar,scara,ur5,panda,kinova
	$(PY) benchmarks/bench_speed.py --generations 1000 --rounds 3
	$(PY) benchmarks/bench_recording.py

bench-arms: install
	$(PY) benchmarks/bench_arms.py

clean:
	rm -rf $(VENV) .pytest_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

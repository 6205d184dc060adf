# viewfuse — see README.md. Every target creates .venv and installs the project on first use.
SHELL   := /bin/bash
PYTHON  ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
CONFIG  ?= configs/synthetic.toml
# Extra flags for viewfuse, e.g. make evaluate ARGS="--force --device cpu"
ARGS    ?=
, := ,
STAGES  := data classifier features models evaluate report simulate

.PHONY: help venv venv-ray $(STAGES) study test test-fast test-install bench calibrate clean distclean

help:
	@echo "make features models evaluate   run the main job on CONFIG (default $(CONFIG))"
	@echo "make <stage>                    one stage (+ stale upstream): $(STAGES)"
	@echo "make study                      seed study: the chain once per study.seeds classifier seed"
	@echo "make venv-ray                   add the optional Ray extra (run.executor = \"ray\" / --executor ray)"
	@echo "make test                       every test (real stages included; CI runs this)"
	@echo "make test-fast                  the unit tests only (no test marked slow), about 2-3 min"
	@echo "make test-install               pip install . (no extras) into a fresh venv, then the smoke chain"
	@echo "make calibrate                  the statistics engine's calibration suite: docs/calibration.md"
	@echo "make bench | clean | distclean"

# Installs go through uv where it can be had (pip install uv, then uv pip install: it unpacks
# torch's ~6 GB of wheels in parallel, several times faster than pip: docs/benchmarks.md), with pip's
# own indexes, find-links and constraints (tools/uv_flags.py); pip installs when uv cannot.
# --compile-bytecode writes the .pyc files at install, as pip does: uv leaves them to the first
# import, and where PYTHONDONTWRITEBYTECODE is set (CI, many containers) every process compiled
# torch's sources again (27 s to import the stack against 10 s: docs/benchmarks.md).
PIP     := $(BIN)/python -m pip install --quiet --disable-pip-version-check
define install
	@if $(PIP) uv >/dev/null 2>&1 && $(BIN)/uv pip install --quiet --compile-bytecode --python $(BIN)/python \
	    $$($(BIN)/python tools/uv_flags.py) -e '$(1)'; then echo "installed $(1) with uv"; \
	else echo "uv not available: installing $(1) with pip"; $(PIP) -e '$(1)'; fi
endef

# A venv that no longer runs (moved: its entry points name the old interpreter path; or its base
# Python gone) is removed here, so the rule below builds it again.
VENV_RUNS = $(shell $(BIN)/python -c 1 >/dev/null 2>&1 && test -x "$$(sed -n '1s/^\#!//p' $(BIN)/viewfuse)" && echo yes)
# A venv copied with its project (cp -a) still runs, but the original's code: its entry points'
# shebang names the original's interpreter and its editable install imports the original's
# modules, so `make evaluate` would run them (and call stages up to date against them). Both are
# compared with this checkout (the import from outside any checkout, PYTHONPATH unset), and a venv
# of another checkout is rebuilt here like a moved one.
# (A long venv path gets a /bin/sh trampoline that finds python beside the script: nothing to compare.)
VENV_SHEBANG = $(firstword $(shell sed -n '1s/^\#!//p' $(BIN)/viewfuse))
VENV_SHEBANG_BIN = $(realpath $(if $(filter /bin/sh,$(VENV_SHEBANG)),$(BIN),$(dir $(VENV_SHEBANG))))
VENV_IMPORTS = $(shell cd / && env -u PYTHONPATH "$(CURDIR)/$(BIN)/python" -c 'import os, stages; \
  print(os.path.dirname(os.path.dirname(os.path.realpath(stages.__file__))))' 2>/dev/null)
ifneq ($(wildcard $(BIN)/viewfuse),)
ifneq ($(VENV_RUNS),yes)
$(info $(VENV) no longer runs (moved, or its Python is gone): rebuilding it)
$(shell rm -rf $(VENV))
else ifneq ($(VENV_SHEBANG_BIN),$(realpath $(BIN)))
$(info $(VENV) belongs to another checkout (its entry points run $(VENV_SHEBANG_BIN)/python, not this \
  checkout's $(realpath $(BIN))/python; copied with cp -a?): rebuilding it)
$(shell rm -rf $(VENV))
else ifneq ($(VENV_IMPORTS),$(realpath $(CURDIR)))
$(info $(VENV) belongs to another checkout (its editable install imports stages from \
  $(or $(VENV_IMPORTS),nowhere), not from this checkout $(realpath $(CURDIR)); copied with cp -a?): rebuilding it)
$(shell rm -rf $(VENV))
endif
endif

$(VENV)/.installed: pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(call install,.[test])
	@touch $@

venv: $(VENV)/.installed

# The optional Ray extra into the same .venv (the default install does not need it).
$(VENV)/.installed-ray: $(VENV)/.installed
	$(call install,.[test$(,)ray])
	@touch $@

venv-ray: $(VENV)/.installed-ray

$(STAGES): $(VENV)/.installed
	$(BIN)/viewfuse $@ --config $(CONFIG) $(ARGS)

study: $(VENV)/.installed
	$(BIN)/viewfuse study --config $(CONFIG) $(ARGS)

# one pytest worker per core (pytest-xdist); a test file stays on one worker, so a module's
# expensive fixture (a finished chain) runs once; files go out in tests/conftest.py's order (the
# chains first). TEST_JOBS=0 runs everything in one process.
TEST_JOBS ?= 2
XDIST = $(if $(filter 0,$(TEST_JOBS)),,-n $(TEST_JOBS) --dist loadfile --no-loadscope-reorder)

test: $(VENV)/.installed
	$(BIN)/python -m pytest -q $(XDIST) $(PYTEST_ARGS)

test-fast: $(VENV)/.installed
	$(BIN)/python -m pytest -q -m 'not slow' $(XDIST) $(PYTEST_ARGS)

# Not in `make test`: it downloads and unpacks torch into a fresh venv (minutes, GB).
test-install: $(VENV)/.installed
	VIEWFUSE_TEST_INSTALL=1 $(BIN)/python -m pytest -q -s tests/test_runtime_dependencies.py $(PYTEST_ARGS)

bench: $(VENV)/.installed
	$(BIN)/python tests/bench/run_all.py $(BENCH_ARGS)

# The whole calibration suite (about 5 min on one core): its table replaces the one in docs/calibration.md.
calibrate: $(VENV)/.installed
	$(BIN)/python tools/calibrate.py $(ARGS)

# clean removes the runs and keeps the stage cache shared across run names (artifacts/.stage-cache:
# run.stage_cache_gb, docs/usage.md); distclean empties it too.
clean:
	if [ -d artifacts ]; then find artifacts -mindepth 1 -maxdepth 1 ! -name .stage-cache -exec rm -rf {} +; fi
	rm -rf .pytest_cache .hypothesis
	find . -name __pycache__ -type d -prune -not -path './$(VENV)/*' -exec rm -rf {} +

distclean: clean
	rm -rf artifacts $(VENV) *.egg-info

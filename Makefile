# viewfuse — see README.md. Every target creates .venv and installs the project on first use.
SHELL   := /bin/bash
PYTHON  ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
CONFIG  ?= configs/synthetic.toml
# Extra flags for viewfuse, e.g. make evaluate ARGS="--force --device cpu"
ARGS    ?=
STAGES  := data classifier features models evaluate report simulate

.PHONY: help venv venv-ray $(STAGES) study test bench clean distclean

help:
	@echo "make features models evaluate   run the main job on CONFIG (default $(CONFIG))"
	@echo "make <stage>                    one stage (+ stale upstream): $(STAGES)"
	@echo "make study                      seed study: the chain once per study.seeds classifier seed"
	@echo "make venv-ray                   add the optional Ray extra (run.executor = \"ray\" / --executor ray)"
	@echo "make test | bench | clean | distclean"

$(VENV)/.installed: pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[test]'
	@touch $@

venv: $(VENV)/.installed

# The optional Ray extra into the same .venv (the default install does not need it).
$(VENV)/.installed-ray: $(VENV)/.installed
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[test,ray]'
	@touch $@

venv-ray: $(VENV)/.installed-ray

$(STAGES): $(VENV)/.installed
	$(BIN)/viewfuse $@ --config $(CONFIG) $(ARGS)

study: $(VENV)/.installed
	$(BIN)/viewfuse study --config $(CONFIG) $(ARGS)

test: $(VENV)/.installed
	$(BIN)/python -m pytest -q $(PYTEST_ARGS)

bench: $(VENV)/.installed
	$(BIN)/python tests/bench/run_all.py $(BENCH_ARGS)

clean:
	rm -rf artifacts .pytest_cache .hypothesis
	find . -name __pycache__ -type d -prune -not -path './$(VENV)/*' -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV) *.egg-info

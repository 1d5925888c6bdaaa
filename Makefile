# The two set-up commands: `make demo` and `make test`. Both create/reuse .venv and install what they need.
# `make lab` (extra): JupyterLab in the same environment with the notebooks open (LAB_ARGS, e.g. --no-browser).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
CKSUM  := $(shell cat pyproject.toml | cksum | cut -d' ' -f1)
STAMP  := $(VENV)/.installed-$(CKSUM)
LAB_STAMP := $(VENV)/.lab-installed-$(CKSUM)
LAB_ARGS ?=
LAB_ROOT  := $(if $(filter 0,$(shell id -u)),--allow-root,)   # containers often run as root

.PHONY: demo test venv clean benchmarks lab

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first and pinned: an unpinned torch pulls GBs of CUDA packages (see DESIGN.md)
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[test]"
	rm -f $(VENV)/.installed-*
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/proprio demo --out demo_output

$(LAB_STAMP): $(STAMP)
	$(PY) -m pip install -q -e ".[lab]"
	rm -f $(VENV)/.lab-installed-*
	touch $(LAB_STAMP)

lab: $(LAB_STAMP)
	$(VENV)/bin/jupyter lab --ServerApp.ip=localhost $(LAB_ROOT) $(LAB_ARGS) notebooks/*.ipynb

test: $(STAMP)
	$(VENV)/bin/lint-imports
	MPLBACKEND=Agg $(PY) -m pytest -q tests --nbmake notebooks

benchmarks: $(STAMP)
	for f in benchmarks/bench_*.py; do echo "== $$f"; OPENBLAS_NUM_THREADS=1 $(PY) $$f || exit 1; done

clean:
	rm -rf $(VENV) demo_output .pytest_cache

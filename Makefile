# The two set-up commands: `make demo` and `make test`. Both create/reuse .venv and install what they need.
# `make docs` builds the documentation site (docs/, mkdocs.yml) in strict mode; `make test` builds it too (tests/test_docs.py).
# `make test` runs every module, command and demo stage on reduced sizes and every notebook, on every core
# (pytest-xdist, one test module or notebook per worker at a time: module fixtures such as the demo are built once;
# the longest modules first, tests/conftest.py LONGEST_FIRST, so the short ones fill in behind them);
# `make test-all` adds the full-size runs (pytest --full: the tests marked slow, the demo at its own sizes).
# A notebook cell may take 180 s: nbclient sometimes waits a cell's whole timeout after a cell that displays an
# ipywidgets control, then goes on (jupyter/nbclient#312; measured 297 s of idle wait at nbmake's default 300 s).
# Two notebook kernels started at once can race for a TCP port ("Kernel died before replying to kernel_info", zmq
# "Address already in use"): such a test, and only such, is run again (pytest-rerunfailures).
# TEST_WORKERS=1 runs it in one process. One BLAS/OpenMP thread per worker: the workers already fill the cores.
# `make lab` (extra): JupyterLab in the same environment with the notebooks open (LAB_ARGS, e.g. --no-browser).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
CKSUM  := $(shell cat pyproject.toml | cksum | cut -d' ' -f1)
STAMP  := $(VENV)/.installed-$(CKSUM)
LAB_ARGS ?=
TEST_WORKERS ?= auto
PYTEST := MPLBACKEND=Agg OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 \
          $(PY) -m pytest -q tests --nbmake notebooks --nbmake-timeout=180 -n $(TEST_WORKERS) --dist loadscope \
          --no-loadscope-reorder --reruns 2 --only-rerun "Kernel died"
LAB_ROOT  := $(if $(filter 0,$(shell id -u)),--allow-root,)   # containers often run as root

.PHONY: demo test test-all venv clean benchmarks lab cuda-torch docs

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

# the test extra holds the lab extra (jupyterlab, ipywidgets): `make lab` runs in the .venv that `make test` made
lab: $(STAMP)
	$(VENV)/bin/jupyter lab --ServerApp.ip=localhost $(LAB_ROOT) $(LAB_ARGS) notebooks/*.ipynb

test: $(STAMP)
	$(VENV)/bin/lint-imports
	$(PYTEST)

test-all: $(STAMP)
	$(VENV)/bin/lint-imports
	$(PYTEST) --full

# the documentation site (mkdocs.yml, docs/) into site/, strict: a broken link, anchor or API reference fails the
# build; tests/test_docs.py builds it under `make test` too
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

benchmarks: $(STAMP)
	for f in benchmarks/bench_*.py; do echo "== $$f"; OPENBLAS_NUM_THREADS=1 $(PY) $$f || exit 1; done

# A GPU machine: swap the CPU wheel for a CUDA build of the same torch (PyPI's Linux x86_64 wheel brings CUDA 12 as
# nvidia-* packages, a few GB); TORCH_INDEX="--index-url URL" picks another build (PyTorch's per-CUDA wheel indexes).
# `make test` / CI keep the CPU wheel: they never run this target.
TORCH_INDEX ?=
cuda-torch: $(STAMP)
	$(PY) -m pip uninstall -y torch
	PIP_FIND_LINKS= $(PY) -m pip install $(TORCH_INDEX) torch==2.13.0
	$(PY) -c "import torch; print('torch', torch.__version__, 'CUDA', torch.version.cuda, 'GPU available:', torch.cuda.is_available()); assert torch.version.cuda, 'got a CPU build: set TORCH_INDEX'"

clean:
	rm -rf $(VENV) demo_output .pytest_cache site

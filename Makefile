# Quick start: `make demo` and `make test`. Both create .venv with the pinned
# versions of requirements.lock on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
export IPC_TAICHI_ARCH ?= auto

.PHONY: install install-gpu test test-quick test-gpu demo bench figures lock clean lint docs test-py312 test-py313

$(STAMP): pyproject.toml requirements.lock
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade "pip>=24"
	$(BIN)/python -m pip install -q -r requirements.lock
	$(BIN)/python -m pip install -q --no-deps --no-build-isolation -e .
	touch $@

install: $(STAMP)

# Tests run Taichi on the CPU arch in f64; GPU tests (marker `gpu`) skip without CUDA.
# `make test`: every test (CI); `make test-quick`: the development lane, without the
# tests marked `slow` (full-size calibrations, the recorded kernel outputs).
# TEST_WORKERS: pytest-xdist processes (default 2, each running Taichi on the CPU; 0 runs
# the tests in this process, in file order).
TEST_WORKERS ?= 2
export TEST_WORKERS
test: install
	IPC_TAICHI_ARCH=cpu IPC_TAICHI_PRECISION=f64 $(BIN)/python -m pytest -q -n $(TEST_WORKERS) -m "not gpu"

test-quick: install
	IPC_TAICHI_ARCH=cpu IPC_TAICHI_PRECISION=f64 $(BIN)/python -m pytest -q -n $(TEST_WORKERS) -m "not gpu and not slow"

# A CUDA machine: Python 3.12 and a CUDA build of PyTorch, in build/venv-gpu, without the
# CPU lock (it pins a CPU torch for Python 3.11). --system-site-packages keeps a
# torch/cupy the machine already has. Offline: see docs/performance.md.
PY_GPU ?= python3.12
GPU_VENV := build/venv-gpu
GPU_STAMP := $(GPU_VENV)/.installed-stamp
# "yes" where ipc_taichi.gpus.cuda_present() says so (the file runs without the package)
HAVE_CUDA := $(shell $(PY) ipc_taichi/gpus.py 2>/dev/null)

$(GPU_STAMP): pyproject.toml
	test -x $(GPU_VENV)/bin/python || $(PY_GPU) -m venv --system-site-packages $(GPU_VENV)
	$(GPU_VENV)/bin/python -m pip install -q --upgrade "pip>=24"
	$(GPU_VENV)/bin/python -m pip install -q -e ".[gpu]"
	touch $@

install-gpu: $(GPU_STAMP)

# Only tests/test_gpu.py: the other test files need the CPU extras (galsim, jwst, ...).
test-gpu: install-gpu
	IPC_TAICHI_ARCH=cuda $(GPU_VENV)/bin/python -m pytest -q -p no:cacheprovider -rs -m gpu \
	  -W "ignore::UserWarning:cupy" tests/test_gpu.py

demo: install
	$(BIN)/ipc-taichi demo

# Speed benchmark: writes bench/results.json and bench/RESULTS.md (with the machine).
# On a CUDA machine from build/venv-gpu (CPU and CUDA rows), elsewhere from .venv.
ifeq ($(HAVE_CUDA),yes)
bench: install-gpu
	$(GPU_VENV)/bin/ipc-taichi bench
else
bench: install
	$(BIN)/ipc-taichi bench
endif

# Every figure of the paper that can be made, and figures/RESULTS.md; rebuilds only what changed.
figures: install
	$(MAKE) -C figures PYTHON=$(abspath $(BIN)/python)

lock:
	rm -rf /tmp/ipc-taichi-lock && $(PY) -m venv /tmp/ipc-taichi-lock
	/tmp/ipc-taichi-lock/bin/pip install -q ".[test,docs,lint]"
	{ echo "# Exact versions for .venv (Python 3.11; regenerate with 'make lock' after changing pyproject.toml)."; \
	  /tmp/ipc-taichi-lock/bin/pip freeze --all | grep -v "^ipc.taichi\|^pip=" ; } > requirements.lock

# Lint (ruff, configured in pyproject.toml) and the API reference (Sphinx, warnings are errors).
lint: install
	$(BIN)/ruff check .

docs: install
	$(BIN)/python -m sphinx -W --keep-going -q -b html docs/api docs/api/_build/html
	@echo "API reference: docs/api/_build/html/index.html"

# The test suite on Python 3.12 / 3.13 (pyenv's, or PY312=/path/to/python3.12), in a venv
# under /tmp pinned by requirements-py3XX.lock (torch left out: its tests are skipped,
# see .ci/test-python). MARK picks the tests: MARK="not gpu and not slow" is the quick lane.
PY312 ?= $(HOME)/.pyenv/versions/3.12.1/bin/python
PY313 ?= $(HOME)/.pyenv/versions/3.13.0/bin/python
MARK ?= not gpu
test-py312:
	.ci/test-python $(PY312) requirements-py312.lock /tmp/ipc-taichi-py312 -m "$(MARK)"
test-py313:
	.ci/test-python $(PY313) requirements-py313.lock /tmp/ipc-taichi-py313 -m "$(MARK)"

clean:
	rm -rf $(VENV) $(GPU_VENV) build *.egg-info .pytest_cache .hypothesis docs/api/_build

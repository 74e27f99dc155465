# Quick start: `make demo` and `make test`. Both create .venv with the pinned
# versions of requirements.lock on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
export IPC_TAICHI_ARCH ?= auto

.PHONY: install test test-gpu demo bench figures lock clean lint docs test-py312 test-py313

$(STAMP): pyproject.toml requirements.lock
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade "pip>=24"
	$(BIN)/python -m pip install -q -r requirements.lock
	$(BIN)/python -m pip install -q --no-deps --no-build-isolation -e .
	touch $@

install: $(STAMP)

# Tests run Taichi on the CPU arch in f64; GPU tests (marker `gpu`) skip without CUDA.
test: install
	IPC_TAICHI_ARCH=cpu IPC_TAICHI_PRECISION=f64 $(BIN)/python -m pytest -q -m "not gpu"

test-gpu: install
	IPC_TAICHI_ARCH=cuda $(BIN)/python -m pytest -q -m gpu

demo: install
	$(BIN)/ipc-taichi demo

# Speed benchmark: writes bench/results.json and bench/RESULTS.md (with the machine).
bench: install
	$(BIN)/ipc-taichi bench

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
# under /tmp pinned by requirements-py3XX.lock (torch left out: see .ci/test-python).
PY312 ?= $(HOME)/.pyenv/versions/3.12.1/bin/python
PY313 ?= $(HOME)/.pyenv/versions/3.13.0/bin/python
test-py312:
	.ci/test-python $(PY312) requirements-py312.lock /tmp/ipc-taichi-py312
test-py313:
	.ci/test-python $(PY313) requirements-py313.lock /tmp/ipc-taichi-py313

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis docs/api/_build

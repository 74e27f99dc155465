# Quick start: `make demo` and `make test`. Both create .venv with the pinned
# versions of requirements.lock on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
export IPC_TAICHI_ARCH ?= auto

.PHONY: install test test-gpu demo bench figures lock clean

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
	/tmp/ipc-taichi-lock/bin/pip install -q ".[test]"
	{ echo "# Exact versions for .venv (Python 3.11; regenerate with 'make lock' after changing pyproject.toml)."; \
	  /tmp/ipc-taichi-lock/bin/pip freeze --all | grep -v "^ipc.taichi\|^pip=" ; } > requirements.lock

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis

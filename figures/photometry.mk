# Binary-star photometry and astrometry (paper section 4; issue 5). Included by
# figures/Makefile (`-include *.mk`); recipes run in figures/ with $(PYTHON).
PYTHON ?= ../.venv/bin/python
_binary_goal := $(.DEFAULT_GOAL)

BINARY_PNG := binary_bright.png binary_mid.png binary_dim.png binary_noise.png binary_methods.png
BINARY_DEPS := ../analysis/binary.py ../analysis/photometry.py ../analysis/photometry_forward.py \
               ../analysis/psf.py $(wildcard ../ipc_taichi/*.py)

FIGURES += $(BINARY_PNG)
RESULT_PARTS += data/50_binary.results.md
DATA_FILES += data/binary_grid.json data/binary_methods.json data/binary_fitter.json

# The grid and the method study, 2 worker processes; per-task results are cached in
# data/cache/binary_cache.npz, so a re-run only computes tasks whose inputs changed.
data/binary_grid.json data/binary_methods.json data/binary_fitter.json &: scripts/binary_data.py $(BINARY_DEPS)
	$(PYTHON) scripts/binary_data.py --workers 2

binary_bright.png binary_mid.png binary_dim.png binary_noise.png &: scripts/plot_binary_grid.py data/binary_grid.json
	$(PYTHON) scripts/plot_binary_grid.py

binary_methods.png: scripts/plot_binary_methods.py data/binary_methods.json
	$(PYTHON) scripts/plot_binary_methods.py

data/50_binary.results.md: scripts/binary_results.py data/binary_grid.json data/binary_methods.json \
		data/binary_fitter.json
	$(PYTHON) scripts/binary_results.py

.PHONY: binary
binary: $(BINARY_PNG) data/50_binary.results.md

# this file must not take over figures/Makefile's default goal
.DEFAULT_GOAL := $(_binary_goal)

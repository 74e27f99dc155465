# Discover on the real FGS ramp (docs/discover.md, "Real ramps"). Included by
# figures/Makefile (`-include *.mk`); recipes run in figures/ with $(PYTHON).
REALRAMPS_PNG := realramps_fgs_raw.png realramps_fgs.png
FIGURES += $(REALRAMPS_PNG)
DATA_FILES += data/realramps_fgs_raw.json data/realramps_fgs.json

$(REALRAMPS_PNG) data/realramps_fgs_raw.json data/realramps_fgs.json &: scripts/realramps.py \
		../tests/data/jwst_fgs_guider2_acq1.fits $(wildcard ../ipc_taichi/discover/*.py) \
		$(wildcard ../ipc_taichi/calibrate/*.py)
	$(PYTHON) scripts/realramps.py

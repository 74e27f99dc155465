"""Calibrate: measure a detector's own coupling from its darks, flats and
reference files, and write the coupling-model file that ``decouple`` uses.

- :mod:`.inputs`: products read as charge [e-] with their masks;
- :mod:`.stream`: flat ramps too large for memory, read by sections and row strips;
- :mod:`.hotpixels`: isolated hot pixels, alpha(S, 0) per direction;
- :mod:`.flats`: flats of frames at one level, alpha(S, S) per axis (exact kernel relation);
- :mod:`.ramps`: flat ramps: gain, classical non-linearity, brighter-fatter and
  the IPC kernel with its signal dependence, told apart by their time structure
  (:mod:`.rampsums` the ramps' sums, :mod:`.rampmodel` their covariance model,
  :mod:`.rampfit` its fit, errors and reports);
- :mod:`.reffiles`: JWST and Roman IPC reference files as a constant law;
- :mod:`.lawfit`: geometry weights and a symmetric law chosen by held-out evidence;
- :mod:`.transfer`: the law fitted on half the hot pixels, checked on the other half;
- :mod:`.report`: the report (JSON), its console summary and figures;
- :mod:`.workflow`: :func:`calibrate`, the whole procedure;
- :mod:`.benchmark`: :func:`measure_calibrate`.

See ``docs/calibrate.md``.
"""

from .workflow import calibrate

__all__ = ["calibrate"]

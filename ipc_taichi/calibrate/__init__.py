"""Calibrate: measure a detector's own coupling from its darks, flats and
reference files, and write the coupling-model file that ``decouple`` uses.

- :mod:`.inputs`: products read as charge [e-] with their masks;
- :mod:`.hotpixels`: isolated hot pixels, alpha(S, 0) per direction;
- :mod:`.flats`: flat-field covariances, alpha(S, S) per axis (exact kernel relation);
- :mod:`.reffiles`: JWST and Roman IPC reference files as a constant law;
- :mod:`.lawfit`: geometry weights and a symmetric law chosen by evidence;
- :mod:`.report`: the report (JSON) and figures;
- :mod:`.workflow`: :func:`calibrate`, the whole procedure;
- :mod:`.benchmark`: :func:`measure_calibrate`.

See ``docs/calibrate.md``.
"""

from .workflow import calibrate

__all__ = ["calibrate"]

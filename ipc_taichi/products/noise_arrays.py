"""The noise arrays beside a science array: which a product holds, and whether
a run propagates them.

A product may hold, beside its science array, its ``ERR`` and ``VAR_*``
arrays (FITS ``EXTNAME``; Roman's and the JWST datamodels' ``err`` and
``var_*``). Every reader asks :func:`noise_of`, before the work, whether they
are propagated through the linearised decoupler
(:func:`ipc_taichi.noise.propagate_noise`, applied frame by frame by
:func:`~ipc_taichi.products.correction.correct_frames`) and what the record
(``IPCNOISE``) says of them; a datamodel's own are found by :func:`held`.
"""

import warnings

import numpy as np

from ..noise import METHOD
from .conventions import ProductWarning

__all__ = ["NOISE_ARRAYS", "noise_of", "held"]

NOISE_ARRAYS = ("err", "var_poisson", "var_rnoise", "var_flat")
"""The noise arrays a product may hold beside its science array (FITS
``EXTNAME`` in upper case), as :func:`ipc_taichi.noise.propagate_noise` names them."""


def noise_of(operation, options, found, where):
    """Whether a product's noise arrays are propagated, and the record's text.

    Propagated (:data:`ipc_taichi.noise.METHOD`) when decoupling, unless
    ``options.noise`` is ``"keep"``; ``couple`` leaves them as they came
    (the forward model adds the coupling to a signal whose noise the caller
    knows; what the arrays describe is not changed by it); a tiled run leaves
    them as they came and says so in one line (the linearisation is made on
    whole frames).

    Parameters
    ----------
    found : list of str
        The names (:data:`NOISE_ARRAYS`) of the arrays of the science
        array's shape that the product holds.
    where : str
        The file and its first noise array, for the one line of a tiled run.

    Returns
    -------
    propagate : bool
    text : str
        The ``IPCNOISE`` keyword's value (at most 68 characters).
    """
    names = ", ".join(n.upper() for n in found)
    if not found:
        return False, "none: no ERR or VAR_* array"
    if options.noise == "keep":
        return False, f"unchanged (--keep-noise): {names}"
    if operation != "decouple":
        return False, f"unchanged (couple): {names}"
    if options.tile:
        warnings.warn(f"{where}: {names} left unchanged with --tile (the noise is propagated "
                      "on whole frames); run without --tile to propagate it",
                      ProductWarning, stacklevel=3)
        return False, f"unchanged (--tile): {names}"
    return True, METHOD




def held(get, shape):
    """The noise arrays a datamodel holds of the science data's ``shape``,
    floating point: ``name -> ndarray`` (``get``: ``name -> value or None``)."""
    found = {}
    for name in NOISE_ARRAYS:
        value = get(name)
        if value is not None and np.shape(value) == tuple(shape) and \
                np.asarray(value).dtype.kind == "f":
            found[name] = np.asarray(value)
    return found

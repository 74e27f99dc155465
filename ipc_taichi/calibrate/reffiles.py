"""Official IPC reference files read for ``calibrate --reference``.

The formats (JWST ``ipc`` 2-D and 4-D, inverse kernels; Roman ``IPC`` and
romanimpreprocess IPC4D, forward kernels) are read by
:mod:`ipc_taichi.refformats`, the kernels converted by the one rule of
:mod:`ipc_taichi.refkernels`: a 2-D kernel gives a constant law with its
geometry, a 4-D one a constant law with its geometry and the map of the
detector (none when every pixel holds the same kernel); a file written by
``ipc-taichi export-reference`` gives back the model kept in it. The file's
kind is read from the file (never guessed from the numbers); another kind is
refused in one line.
"""

from ..refformats import read_model
from ..refkernels import invert_kernels, law_from_forward_kernel

__all__ = ["read_reference", "read_reference_model", "invert_kernel",
           "law_from_forward_kernel", "pedigree_of"]

invert_kernel = invert_kernels
"""The convolution inverse of a kernel (:func:`ipc_taichi.refkernels.invert_kernels`)."""


def read_reference_model(path):
    """``(model, info)`` of a JWST (FITS) or Roman / IPC4D (ASDF) IPC reference
    file (:func:`ipc_taichi.refformats.read_model`): the model with its map, if any."""
    return read_model(path)


def read_reference(path):
    """``(law, geometry, info)`` of a reference file (its model's law and
    geometry; ``info["map"]`` says whether it has a map).

    Raises
    ------
    IPCInputError
        One line naming the file: not readable, or not an IPC reference of a
        known kind.
    """
    model, info = read_model(path)
    return model.law, model.geometry, info


def pedigree_of(path):
    """The PEDIGREE of a FITS reference file (None when absent or not FITS)."""
    try:
        from astropy.io import fits

        return str(fits.getval(path, "PEDIGREE")).strip() or None
    except Exception:  # ASDF, or no such keyword: the reader's own info says the rest
        return None

"""Tiled decoupling of FITS images larger than memory (moved out of
:mod:`ipc_taichi.tiling`, which keeps arrays only; to be absorbed by the
product pipeline)."""

import os

import numpy as np

from . import iteration
from .errors import IPCInputError
from .model import CouplingModel
from .tiling import decouple_blocks

__all__ = ["decouple_fits_tiled"]


def decouple_fits_tiled(input_path, output_path, hdu=None, tile=1024, overwrite=False,
                        law="donlon2018", geometry=None, edge="zero", max_iter=20, tol=1e-5,
                        arch=None, precision=None, progress=False, keywords=None, history=()):
    """Decouple a FITS image larger than memory, tile by tile.

    The input HDU is memory-mapped and read one tile plus halo at a time
    (a 3-D cube frame by frame); the float64 result is written into a
    memory-mapped primary HDU at a temporary path beside ``output_path``,
    renamed into place when complete. The input header is kept (minus
    structural and scaling keywords); ``keywords`` and ``history`` are added.

    Returns the list of :class:`DecoupleInfo`, one per frame.
    """
    from astropy.io import fits

    from .fitsio import atomic_output, parse_hdu

    model = CouplingModel.resolve(law, geometry, edge)
    if not os.path.exists(input_path):
        raise IPCInputError(f"{input_path}: no such file")
    try:
        hdul = fits.open(input_path, memmap=True)
    except Exception as exc:
        raise IPCInputError(f"{input_path}: not a readable FITS file ({type(exc).__name__})") \
            from None
    with hdul:
        hdu = parse_hdu(hdu)
        if hdu is None:
            hdu = next((k for k, h in enumerate(hdul) if h.is_image
                        and h.header.get("NAXIS", 0) > 0), None)
            if hdu is None:
                raise IPCInputError(f"{input_path}: no HDU holds image data")
        try:
            src = hdul[hdu]
        except (KeyError, IndexError):
            raise IPCInputError(f"{input_path}[{hdu}]: no such HDU") from None
        if not src.is_image or src.header.get("NAXIS", 0) not in (2, 3):
            raise IPCInputError(f"{input_path}[{hdu}]: expected a 2-D image or 3-D cube")
        shape = tuple(src.header[f"NAXIS{k}"] for k in range(src.header["NAXIS"], 0, -1))
        header = _output_header(src.header, shape, keywords, history)
        infos = []
        with atomic_output(output_path, overwrite) as tmp:
            _allocate_fits(tmp, header, shape)
            with fits.open(tmp, mode="update", memmap=True) as out_hdul:
                out = out_hdul[0].data
                frames = shape[0] if len(shape) == 3 else 1
                for k in range(frames):
                    def read(window, k=k):
                        sec = src.section[(k,) + window] if len(shape) == 3 else \
                            src.section[window]
                        return np.asarray(sec, dtype=np.float64)

                    def write(core, values, k=k):
                        (out[k] if len(shape) == 3 else out)[core] = values

                    infos.append(decouple_blocks(read, write, shape[-2:], tile, model, max_iter,
                                                 tol, arch, precision, progress))
                    iteration.warn_unconverged(infos[-1], max_iter, tol)
                out_hdul.flush()
    return infos


def _output_header(header, shape, keywords, history):
    from astropy.io import fits

    from .fitsio import output_header

    out = fits.Header([("SIMPLE", True), ("BITPIX", -64), ("NAXIS", len(shape))]
                      + [(f"NAXIS{k + 1}", n) for k, n in enumerate(reversed(shape))])
    out.extend(output_header(header, keywords, history), end=True)
    return out


def _allocate_fits(path, header, shape):
    """Create a FITS file of ``header`` and zero data of ``shape`` without
    holding the data in memory (the file is extended, not written)."""
    text = header.tostring()
    nbytes = int(np.prod(shape)) * 8
    padded = -(-nbytes // 2880) * 2880
    with open(path, "wb") as f:
        f.write(text.encode("ascii"))
        f.truncate(len(text) + padded)

"""Official IPC reference files read as a constant law with geometry.

Two kinds exist, and the file says which it is (never guessed from the
numbers):

- **JWST ``ipc`` reference** (FITS, ``REFTYPE = 'IPC'``): a 3x3 or 5x5 kernel
  in the primary or SCI HDU that the JWST pipeline *convolves the ramp with to
  remove IPC*: an already inverted (deconvolution) kernel, centre above 1.
  The forward kernel is its convolution inverse, computed here on a padded
  Fourier grid and cut back to the kernel's size.
- **Roman IPC reference** (ASDF, ``meta.reftype == 'IPC'``): a 3x3 forward
  kernel (centre ~0.92), the fraction each neighbour receives.

From the forward kernel ``F``: ``alpha`` is the mean of the four nearest
entries, and the geometry is ``F / alpha`` (anisotropy and diagonals kept).
A file whose kind is not one of these is refused in one line.
"""

import numpy as np

from ..errors import IPCInputError
from ..geometry import Geometry
from ..laws import constant
from ..products.fitsfile import open_fits
from ..products.missions import is_asdf

__all__ = ["read_reference", "invert_kernel", "law_from_forward_kernel"]


def invert_kernel(kernel, size=64):
    """The convolution inverse of a small kernel (Fourier, on a ``size`` grid), cut to its shape."""
    k = np.asarray(kernel, dtype=np.float64)
    c = k.shape[0] // 2
    grid = np.zeros((size, size))
    for dy in range(k.shape[0]):
        for dx in range(k.shape[1]):
            grid[(dy - c) % size, (dx - c) % size] = k[dy, dx]
    inv = np.real(np.fft.ifft2(1.0 / np.fft.fft2(grid)))
    out = np.zeros_like(k)
    for dy in range(k.shape[0]):
        for dx in range(k.shape[1]):
            out[dy, dx] = inv[(dy - c) % size, (dx - c) % size]
    return out


def law_from_forward_kernel(kernel, name):
    """``(law, geometry)`` of a forward kernel: constant alpha = mean nearest entry."""
    k = np.asarray(kernel, dtype=np.float64)
    if k.ndim != 2 or k.shape[0] != k.shape[1] or k.shape[0] not in (3, 5):
        raise IPCInputError(f"{name}: an IPC kernel must be 3x3 or 5x5, got shape {k.shape}")
    c = k.shape[0] // 2
    alpha = float(np.mean([k[c, c - 1], k[c, c + 1], k[c - 1, c], k[c + 1, c]]))
    if not alpha > 0:
        raise IPCInputError(f"{name}: the kernel's nearest entries are not positive "
                            f"(alpha {alpha:.3g}); not a forward IPC kernel")
    kk = np.where(k < 0, 0.0, k)  # tiny negative far entries (noise) carry no coupling
    return constant(alpha), Geometry.from_kernel(kk, alpha)


def read_reference(path):
    """``(law, geometry, info)`` from a JWST (FITS) or Roman (ASDF) IPC reference file.

    Raises
    ------
    IPCInputError
        One line naming the file: not readable, or not an IPC reference of a
        known kind.
    """
    if is_asdf(path):
        return _roman(path)
    return _jwst(path)


def _jwst(path):
    hdul = open_fits(path, memmap=False)
    with hdul:
        primary = hdul[0].header
        reftype = str(primary.get("REFTYPE", "")).strip().upper()
        telescope = str(primary.get("TELESCOP", "")).strip().upper()
        if reftype != "IPC" or telescope not in ("JWST", ""):
            raise IPCInputError(f"{path}: not an IPC reference file of a known kind "
                                f"(REFTYPE={primary.get('REFTYPE')!r}, TELESCOP="
                                f"{primary.get('TELESCOP')!r}); expected the JWST 'ipc' "
                                "reference (FITS) or Roman's IPC reference (ASDF)")
        hdu = hdul["SCI"] if "SCI" in hdul else hdul[0]
        kernel = np.asarray(hdu.data, dtype=np.float64)
    if kernel.ndim == 4:
        raise IPCInputError(f"{path}[SCI]: a per-pixel (4-D) IPC kernel; only a single "
                            "kernel is read")
    forward = invert_kernel(kernel)
    c = kernel.shape[0] // 2
    law, geometry = law_from_forward_kernel(forward, path)
    return law, geometry, {"kind": "jwst_ipc (inverse kernel, inverted here)",
                           "file_kernel": kernel.tolist(), "forward_kernel": forward.tolist(),
                           "centre": float(kernel[c, c])}


def _roman(path):
    try:
        import asdf
    except ImportError:
        raise IPCInputError(f"{path}: reading ASDF needs the asdf package") from None
    try:
        af = asdf.open(path, lazy_load=False)
    except Exception as exc:
        raise IPCInputError(f"{path}: cannot read as ASDF ({type(exc).__name__})") from None
    with af:
        roman = af.tree.get("roman", {})
        meta = roman.get("meta", {}) if hasattr(roman, "get") else {}
        reftype = str(meta.get("reftype", "")).strip().upper() if hasattr(meta, "get") else ""
        if reftype != "IPC" or "data" not in roman:
            raise IPCInputError(f"{path}: not an IPC reference file of a known kind "
                                f"(reftype={reftype or None!r}); expected Roman's IPC "
                                "reference (ASDF) or the JWST 'ipc' reference (FITS)")
        kernel = np.asarray(roman["data"], dtype=np.float64)
    law, geometry = law_from_forward_kernel(kernel, path)
    return law, geometry, {"kind": "roman_ipc (forward kernel)", "forward_kernel": kernel.tolist(),
                           "centre": float(kernel[kernel.shape[0] // 2, kernel.shape[1] // 2])}

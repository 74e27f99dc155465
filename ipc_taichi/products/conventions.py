"""Which pixels take part, in which units: the rules shared by every product.

These are pure functions of arrays and header values; the readers and writers
(:mod:`ipc_taichi.products.fits`, :mod:`ipc_taichi.products.roman`, the
``stpipe`` step) call them, and :func:`correct_frames` applies them to the
science array. The conventions (also in ``docs/products.md``):

- **DQ.** A pixel whose data-quality word has any of the chosen bits set
  (default ``DO_NOT_USE``) is not trusted: it keeps its value and neither
  gives nor takes charge. Its neighbours are corrected for their other
  neighbours only; their exchange with the masked pixel (about alpha times
  its charge) stays in them.
- **Reference pixels** (the ``REFERENCE_PIXEL`` flag, or a border of ``N``
  pixels) are never changed. The science region inside them is decoupled with
  the ``zero`` edge rule: reference pixels collect no photo-charge, so they
  act as zero-signal neighbours, as the JWST ``ipc`` step treats them.
  Reference-flagged pixels inside the science region (not a border) are
  treated as masked.
- **NaN** keeps its meaning: a bad pixel, left NaN, not coupled.
- **Units.** The coupling law is written in electrons of collected charge.
  ``BUNIT`` says what the numbers are: electrons pass through; DN are
  multiplied by the gain (e-/DN); rates (DN/s, e-/s) also by the integration
  time. The result is converted back to the input's units.
"""

import re
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import ConvergenceWarning, DivergenceError, IPCInputError
from ..interrupts import check_stop

__all__ = ["ProductWarning", "JWST_DQ_FLAGS", "dq_flag_table", "parse_dq_bits", "science_region",
           "region_model",
           "charge_scale", "correct_frames", "Units", "RATE_UNITS", "CHARGE_UNITS"]

class ProductWarning(UserWarning):
    """Something about a product the user should know (the run goes on)."""


JWST_DQ_FLAGS = {
    "GOOD": 0, "DO_NOT_USE": 1, "SATURATED": 2, "JUMP_DET": 4, "DROPOUT": 8,
    "NON_SCIENCE": 2 ** 9, "DEAD": 2 ** 10, "HOT": 2 ** 11, "WARM": 2 ** 12,
    "REFERENCE_PIXEL": 2 ** 31,
}
"""The JWST data-quality bits this module relies on, used when ``stdatamodels``
(which has the full table) is not installed."""

REFERENCE_PIXEL = JWST_DQ_FLAGS["REFERENCE_PIXEL"]


def dq_flag_table(mission="jwst"):
    """Flag name -> bit value: from ``stdatamodels`` (JWST) or
    ``roman_datamodels`` (Roman) when installed, else :data:`JWST_DQ_FLAGS`."""
    try:
        if mission == "roman":
            from roman_datamodels.dqflags import pixel
        else:
            from stdatamodels.jwst.datamodels.dqflags import pixel
    except ImportError:
        return dict(JWST_DQ_FLAGS)
    return {str(k): int(v) for k, v in dict(
        pixel.__members__ if hasattr(pixel, "__members__") else pixel).items()}


def parse_dq_bits(text, mission="jwst"):
    """``"DO_NOT_USE,HOT"``, ``"1,2048"``, ``"0"`` or ``"none"`` -> the bit mask (int)."""
    if text is None:
        text = "DO_NOT_USE"
    if isinstance(text, (int, np.integer)):
        return int(text)
    table = dq_flag_table(mission)
    bits = 0
    for item in str(text).replace("+", ",").split(","):
        item = item.strip()
        if not item or item.lower() == "none":
            continue
        if item.isdigit():
            bits |= int(item)
        elif item.upper() in table:
            bits |= table[item.upper()]
        else:
            raise IPCInputError(f"--dq-bits: unknown flag {item!r} (give integers or names such "
                                f"as {', '.join(sorted(table)[:6])}, ...)")
    return bits


def science_region(shape, refpix=None, reference=None):
    """The science region inside the reference pixels, and any reference
    pixels left inside it.

    Parameters
    ----------
    shape : (int, int)
        The frame's shape.
    refpix : int, optional
        Width of a reference border on all four sides (overrides ``reference``).
    reference : ndarray of bool, optional
        Pixels flagged ``REFERENCE_PIXEL``.

    Returns
    -------
    region : (slice, slice)
        The bounding box of the non-reference pixels.
    inside : ndarray of bool or None
        Reference-flagged pixels inside ``region`` (treated as masked).
    """
    ny, nx = shape
    if refpix is not None:
        n = int(refpix)
        if n < 0 or 2 * n >= min(ny, nx):
            raise IPCInputError(f"--refpix {n}: needs 0 <= N < {min(ny, nx) // 2} for a "
                                f"{ny}x{nx} frame")
        return (slice(n, ny - n), slice(n, nx - n)), None
    if reference is None or not reference.any():
        return (slice(0, ny), slice(0, nx)), None
    science = ~reference
    rows, cols = np.flatnonzero(science.any(axis=1)), np.flatnonzero(science.any(axis=0))
    if rows.size == 0:
        raise IPCInputError("every pixel is a reference pixel")
    region = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    inside = reference[region]
    return region, (inside if inside.any() else None)


def region_model(model, region, shape):
    """The model for the science region: the ``zero`` edge rule where the
    region leaves a reference border (reference pixels are zero-signal
    neighbours), else ``model`` itself."""
    from ..model import CouplingModel

    whole = (region[0].stop - region[0].start, region[1].stop - region[1].start) == tuple(shape)
    return model if whole else CouplingModel(model.law, model.geometry, "zero")


CHARGE_UNITS = ("electron", "electrons", "e", "e-", "electron(s)", "el")
DN_UNITS = ("dn", "adu", "count", "counts", "ct", "cts", "data number")
RATE_UNITS = tuple(u + "/s" for u in CHARGE_UNITS + DN_UNITS)
FLUX_HINTS = ("jy", "erg", "w/", "w m", "mag", "sr", "flam", "fnu")


@dataclass(frozen=True)
class Units:
    """What the numbers are: ``kind`` in {"charge", "dn", "charge_rate",
    "dn_rate"} and the text they came from."""

    kind: str
    text: str

    @property
    def rate(self):
        return self.kind.endswith("_rate")

    @property
    def needs_gain(self):
        return self.kind.startswith("dn")


def _normal(text):
    """``"DN / s"``, ``"DN s-1"``, ``"DN s**-1"``, ``"DN/sec"``, ``"DN per s"`` -> ``"dn/s"``."""
    t = re.sub(r"\s+", " ", str(text).strip().lower().replace("sec", "s"))
    t = re.sub(r"\s*(?:/|\bper\b)\s*s$", "/s", t)
    t = re.sub(r"\s+s(?:\*\*|\^)?-1$", "/s", t)
    return t.replace(" ", "")


def parse_units(bunit, label):
    """:class:`Units` of a ``BUNIT`` value (``None``: electrons, the law's unit).

    Raises :class:`IPCInputError` (one line, naming ``label``) for flux-calibrated
    or unknown units."""
    if bunit is None or str(bunit).strip() == "":
        return Units("charge", "")
    t = _normal(bunit)
    if t in CHARGE_UNITS:
        return Units("charge", str(bunit))
    if t in DN_UNITS:
        return Units("dn", str(bunit))
    if t.endswith("/s") and t[:-2] in CHARGE_UNITS:
        return Units("charge_rate", str(bunit))
    if t.endswith("/s") and t[:-2] in DN_UNITS:
        return Units("dn_rate", str(bunit))
    if any(h in t for h in FLUX_HINTS):
        raise IPCInputError(
            f"{label}: BUNIT {bunit!r} is flux-calibrated; IPC acts on collected charge: "
            "decouple the rate (DN/s) or ramp (DN) product instead")
    raise IPCInputError(f"{label}: BUNIT {bunit!r} not understood; give --bunit electron, DN "
                        "or DN/s (with --gain E_PER_DN, and --exptime SECONDS for rates)")


def charge_scale(units, gain, exptime, label):
    """Electrons per unit of the data: 1, gain, gain*exptime or exptime.

    Parameters
    ----------
    units : Units
    gain : float, ndarray or None
        e-/DN (an array: per pixel, the frame's shape).
    exptime : float or None
        Integration time in seconds (rates only).
    label : str
        The file and HDU, for error messages.

    Returns
    -------
    scale : float or ndarray
    text : str
        How the conversion was made (for the HISTORY).
    """
    scale, parts = 1.0, []
    if units.needs_gain:
        if gain is None:
            raise IPCInputError(f"{label}: data in {units.text} need a gain: give --gain E_PER_DN "
                                "(a number or a gain image .fits), or a GAIN keyword")
        g = np.asarray(gain, dtype=np.float64)
        if g.ndim == 0:
            if not (np.isfinite(g) and g > 0):
                raise IPCInputError(f"{label}: gain must be a positive number, got {gain!r}")
            scale = float(g)
            parts.append(f"gain {scale:g} e-/DN")
        else:  # per pixel; pixels without a usable gain are masked by correct_frames
            scale = g
            parts.append(f"gain image (median {float(np.nanmedian(g)):g} e-/DN)")
    if units.rate:
        if exptime is None:
            raise IPCInputError(f"{label}: a rate in {units.text} needs the integration time: "
                                "give --exptime SECONDS or an EFFINTTM keyword")
        t = float(exptime)
        if not (np.isfinite(t) and t > 0):
            raise IPCInputError(f"{label}: integration time must be > 0 s, got {exptime!r}")
        scale = scale * t
        parts.append(f"integration time {t:g} s")
    text = (f"{units.text or 'electrons (no BUNIT)'} -> electrons"
            + (f" with {', '.join(parts)}" if parts else ""))
    return scale, text


class named:
    """Context manager: a :class:`DivergenceError` raised inside is raised
    again with ``where`` (the file, HDU and frame) in front of its message."""

    def __init__(self, where):
        self.where = where

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None and issubclass(exc_type, DivergenceError):
            raise DivergenceError(f"{self.where}: {exc}") from None
        return False


def correct_frames(data, operation, model, *, mask=None, region=None, scale=1.0,
                   out=None, max_iter=20, tol=1e-5, arch=None, precision=None, label="data"):
    """Couple or decouple every 2-D frame of ``data`` by the product rules.

    The pure correction function under every product reader/writer.

    Parameters
    ----------
    data : ndarray, shape (..., ny, nx)
        The science array in its own units (any real dtype).
    operation : {"couple", "decouple"}
    model : CouplingModel
        Its edge rule is replaced by ``zero`` when ``region`` leaves a
        reference border (reference pixels are zero-signal neighbours).
    mask : ndarray of bool, optional
        Untrusted pixels (True), broadcastable to ``data``: they keep their
        values and do not couple.
    region : (slice, slice), optional
        The science region inside the reference pixels (default: the frame).
    scale : float or ndarray (ny, nx)
        Electrons per data unit (see :func:`charge_scale`).
    out : ndarray, optional
        Where to write (same shape as ``data``; default: a float64 copy).
        Pixels outside ``region`` and masked pixels are copied from ``data``.
    max_iter, tol, arch, precision :
        As for :func:`ipc_taichi.decouple`.
    label : str
        The file and HDU, for error messages.

    Returns
    -------
    out : ndarray
    infos : list of DecoupleInfo (decouple) or of None (couple), one per frame.
    """
    from ..coupling import couple
    from ..decoupling import decouple

    data = np.asarray(data)
    shape = data.shape
    ny, nx = shape[-2:]
    region = region or (slice(0, ny), slice(0, nx))
    inner_model = region_model(model, region, (ny, nx))
    frames = data.reshape((-1, ny, nx))
    masks = None if mask is None else np.broadcast_to(mask, shape).reshape((-1, ny, nx))
    if out is None:
        out = np.array(data, dtype=np.float64)
    else:
        out[...] = data
    flat_out = out.reshape((-1, ny, nx))
    s = np.asarray(scale, dtype=np.float64)
    s_in = s[region] if s.ndim == 2 else s
    infos = []
    for k in range(frames.shape[0]):
        check_stop()  # a SIGINT/SIGTERM swallowed by a library stops the run here
        where = f"{label} frame {k}" if frames.shape[0] > 1 else label
        measured = frames[k][region].astype(np.float64) * s_in
        m = None if masks is None else np.array(masks[k][region], dtype=bool)
        if s.ndim == 2:  # pixels without a usable gain cannot be converted
            bad_gain = ~(np.isfinite(s_in) & (s_in > 0))
            if bad_gain.any():
                m = bad_gain if m is None else (m | bad_gain)
        good = np.isfinite(measured) if m is None else (np.isfinite(measured) & ~m)
        if not good.any():
            raise IPCInputError(f"{where}: no finite, unmasked pixel to {operation} "
                                "(all NaN or flagged)")
        with warnings.catch_warnings(), named(where):
            warnings.simplefilter("ignore", ConvergenceWarning)  # reported per frame by callers
            if operation == "decouple":
                result, info = decouple(measured, model=inner_model, mask=m, max_iter=max_iter,
                                        tol=tol, arch=arch, precision=precision,
                                        full_output=True)
            else:
                result, info = couple(measured, model=inner_model, mask=m, arch=arch,
                                      precision=precision), None
        with np.errstate(divide="ignore", invalid="ignore"):  # pixels without a gain: masked
            result = np.ma.getdata(result) / s_in
        target = flat_out[k][region]
        keep = None if m is None else m
        if keep is None:
            target[...] = result
        else:
            target[...] = np.where(keep, frames[k][region], result)
        infos.append(info)
    return out, infos

"""Which pixels take part, in which units: the rules shared by every product.

These are pure functions of arrays and header values; the readers and writers
(:mod:`ipc_taichi.products.fits`, :mod:`ipc_taichi.products.roman`, the
``stpipe`` step) call them, and
:func:`~ipc_taichi.products.correction.correct_frames` applies them to the
science array. The conventions (also in ``docs/products.md``):

- **DQ.** A pixel whose data-quality word has any of the chosen bits set
  (default ``DO_NOT_USE,SATURATED``; with ``--saturation LEVEL`` also every
  pixel at or above LEVEL) is not trusted: it keeps its value and neither
  gives nor takes charge (:func:`untrusted`, the one rule for every product).
  Its neighbours are corrected for their other neighbours only; their
  exchange with the masked pixel (about alpha times its charge) stays in them.
- **Reference pixels** (the ``REFERENCE_PIXEL`` flag, or a border of ``N``
  pixels) are never changed. The science region inside them is decoupled with
  the ``zero`` edge rule: reference pixels collect no photo-charge, so they
  act as zero-signal neighbours, as the JWST ``ipc`` step treats them (where
  they are and which edge a frame gets: :mod:`ipc_taichi.products.plan`).
  Reference-flagged pixels inside the science region (not a border) are
  treated as masked.
- **NaN** keeps its meaning: a bad pixel, left NaN, not coupled.
- **Units.** The coupling law is written in electrons of collected charge.
  ``BUNIT`` says what the numbers are: electrons pass through; DN are
  multiplied by the gain (e-/DN); rates (DN/s, e-/s) also by the integration
  time; coadded frames are divided by the number of exposures summed. The
  result is converted back to the input's units. Pixels without a usable
  per-pixel gain are left out (:func:`unusable_gain`).
- **Pedestal.** The law is evaluated at the charge on the node, which
  includes what was there before the first read (a zeroth read):
  the array plan's ``pedestal``
  (:class:`~ipc_taichi.products.correction.FramePlan`).
- **Unphysical values** that nothing flags (an infinite value, or a charge
  outside :data:`PHYSICAL_RANGE`) are masked like flagged pixels (they keep
  their values and neither give nor take charge), counted
  (:class:`Unphysical`; the ``IPCNBAD`` keyword) and said in one line per
  science array. ``unphysical="keep"`` (``--keep-unphysical``) leaves the
  finite ones in, as before: the law then spreads them to their neighbours.
  NaN is not counted: it is the documented bad-pixel marker, always left out.
"""

import re
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import IPCInputError
from .checks import dq_word
from .missions import DEFAULT_DQ, JWST_DQ_FLAGS, REFERENCE_PIXEL

__all__ = ["ProductWarning", "parse_dq_bits", "untrusted", "unusable_gain", "science_region",
           "charge_scale", "Units", "RATE_UNITS", "CHARGE_UNITS", "Unphysical",
           "REFERENCE_PIXEL", "PHYSICAL_RANGE", "unphysical", "UNPHYSICAL_CHOICES"]


class ProductWarning(UserWarning):
    """Something about a product the user should know (the run goes on)."""


def parse_dq_bits(text, flags=None):
    """``"DO_NOT_USE,HOT"``, ``"1,2048"``, ``"0"`` or ``"none"`` -> the bit mask (int).

    ``flags``: name -> bit (a :class:`~ipc_taichi.products.missions.Mission`'s
    ``dq_flags``: the file's ``DQ_DEF`` first, then its mission's names)."""
    if text is None:
        text = DEFAULT_DQ
    if isinstance(text, (int, np.integer)):
        return dq_word(int(text), text)
    table = dict(JWST_DQ_FLAGS) if flags is None else flags
    bits = 0
    for item in str(text).replace("+", ",").split(","):
        item = item.strip()
        if not item or item.lower() == "none":
            continue
        if item.isdigit():
            bits |= dq_word(int(item), item)
        elif item.upper() in table:
            bits |= table[item.upper()]
        else:
            raise IPCInputError(f"--dq-bits: unknown flag {item!r} (give integers or names such "
                                f"as {', '.join(sorted(table)[:6])}, ...)")
    return bits


def untrusted(flags, bits, shape, inside=None, values=None, saturation=None, gain=None):
    """The masked-pixel rule, the same for every product and every window.

    Parameters
    ----------
    flags : list of ndarray
        Bit-flag arrays (DQ, PIXELDQ, GROUPDQ), each broadcastable to ``shape``.
    bits : int
        A pixel with any of these bits set is left out.
    shape : tuple
        The shape of the data (or of the window).
    inside : ndarray of bool, optional
        Reference-flagged pixels inside the science region.
    values : ndarray, optional
        The data: pixels at or above ``saturation`` are left out.
    saturation : float, optional
    gain : ndarray, optional
        A per-pixel gain: pixels without a usable one are left out.

    Returns
    -------
    ndarray of bool, or None when nothing is left out.
    """
    mask = None

    def add(m):
        nonlocal mask
        m = np.broadcast_to(m, shape)
        mask = np.array(m, dtype=bool) if mask is None else (mask | m)

    for f in flags if bits else ():
        add((np.asarray(f).astype(np.int64) & bits) != 0)
    if inside is not None:
        add(inside)
    if saturation is not None and values is not None:
        with np.errstate(invalid="ignore"):
            add(np.asarray(values) >= saturation)
    if gain is not None and np.ndim(gain) == 2:
        add(unusable_gain(gain))
    return mask


def unusable_gain(gain):
    """Pixels whose gain cannot convert their data to charge (not finite, <= 0)."""
    g = np.asarray(gain, dtype=np.float64)
    return ~(np.isfinite(g) & (g > 0))


PHYSICAL_RANGE = (-2e4, 1e6)
"""Electrons a pixel of one exposure can plausibly hold (an H2RG/H4RG node holds
about 1e5; a few 1e4 below zero is noise and bias residue). Unflagged values
outside it, and infinite ones, are *unphysical*: masked by default
(:class:`Unphysical`)."""

UNPHYSICAL_CHOICES = ("mask", "keep")
"""What is done with unphysical pixels: masked (the default), or kept in the
correction (the finite ones; an infinite value is never coupled)."""


def unphysical(charge):
    """Pixels holding a charge no detector can hold: infinite, or finite and
    outside :data:`PHYSICAL_RANGE` (electrons). NaN is not included (it is the
    bad-pixel marker, always left out)."""
    c = np.asarray(charge)
    with np.errstate(invalid="ignore"):
        return np.isinf(c) | (c < PHYSICAL_RANGE[0]) | (c > PHYSICAL_RANGE[1])


class Unphysical:
    """The unflagged unphysical pixels of one science array, frame by frame:
    counted, masked (``action="mask"``) or kept (``"keep"``), said in one line
    (:meth:`warn`)."""

    def __init__(self, action="mask"):
        if action not in UNPHYSICAL_CHOICES:
            raise IPCInputError(f"unphysical={action!r}: give one of "
                                f"{', '.join(UNPHYSICAL_CHOICES)}")
        self.action = action
        self.count = 0
        self.infinite = 0
        self.frames = set()  # where they were found (file, HDU, frame)
        self.first = None  # (where, y, x, value in electrons)

    @property
    def masked(self):
        """Pixels masked because they are unphysical (0 when kept)."""
        return self.count if self.action == "mask" else self.infinite

    def add(self, charge, mask, where, offset=(0, 0)):
        """Count the unflagged unphysical pixels of ``charge`` (a frame or a
        window of one; ``mask``: the pixels already left out; ``offset``: the
        window's first pixel in the frame). Returns the pixels to mask
        (None when none)."""
        bad = unphysical(charge)
        if mask is not None:
            bad &= ~mask
        n = int(bad.sum())
        if not n:
            return None
        self.count += n
        self.infinite += int(np.isinf(np.asarray(charge)[bad]).sum())
        self.frames.add(where)
        if self.first is None:
            y, x = np.argwhere(bad)[0]
            self.first = (where, int(y) + offset[0], int(x) + offset[1], float(charge[y, x]))
        if self.action == "keep":  # an infinite value cannot couple: masked whatever
            bad &= np.isinf(np.asarray(charge))
        return bad if bad.any() else None

    def warn(self, label, stacklevel=3):
        """One line saying what was found and what was done (nothing when none)."""
        if not self.count:
            return
        where, y, x, value = self.first
        frames = f" in {len(self.frames)} frames" if len(self.frames) > 1 else ""
        at = f"{where} " if where != label else ""
        found = (f"{label}: {self.count} unflagged pixel(s){frames} hold values no detector can "
                 f"hold (outside {PHYSICAL_RANGE[0]:g}..{PHYSICAL_RANGE[1]:g} e-, or infinite; "
                 f"first at {at}y={y}, x={x}: {value:.4g} e-)")
        if self.action == "mask":
            done = ("masked: they keep their values and neither give nor take charge "
                    "(IPCNBAD); flag them in DQ, or give --saturation LEVEL")
        else:
            finite = self.count - self.infinite
            done = "kept as asked (--keep-unphysical): " + "; ".join(
                ([f"the {finite} finite one(s) give their charge to their neighbours"]
                 if finite else [])
                + ([f"the {self.infinite} infinite one(s) are masked (they cannot couple)"]
                   if self.infinite else []))
        warnings.warn(f"{found}: {done}", ProductWarning, stacklevel=stacklevel)


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


def parse_units(bunit, label, source="BUNIT"):
    """:class:`Units` of a ``BUNIT`` value (``None``: electrons, the law's unit);
    ``source`` names where the value came from in errors (Roman: its schema).

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
            f"{label}: {source} {bunit!r} is flux-calibrated; IPC acts on collected charge: "
            "decouple the rate (DN/s) or ramp (DN) product instead")
    raise IPCInputError(f"{label}: {source} {bunit!r} not understood; give --bunit electron, DN "
                        "or DN/s (with --gain E_PER_DN, and --exptime SECONDS for rates)")


def charge_scale(units, gain, exptime, label, time_source="EFFINTTM", coadds=1,
                 gain_source="a GAIN keyword"):
    """Electrons per unit of the data, per exposure: 1, gain, gain*exptime or
    exptime, divided by the number of coadded exposures.

    Parameters
    ----------
    units : Units
    gain : float, ndarray or None
        e-/DN (an array: per pixel, the frame's shape).
    exptime : float or None
        Integration time in seconds (rates only).
    label : str
        The file and HDU, for error messages.
    time_source, gain_source : str
        Where the integration time and the gain are looked for (for the error
        messages: FITS keywords, or a Roman model's fields).
    coadds : int
        Exposures summed in each frame: the law sees the charge of one.

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
                                f"(a number or a gain image file), or {gain_source}")
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
                                f"give --exptime SECONDS or {time_source}")
        t = float(exptime)
        if not (np.isfinite(t) and t > 0):
            raise IPCInputError(f"{label}: integration time must be > 0 s, got {exptime!r}")
        scale = scale * t
        parts.append(f"integration time {t:g} s")
    if coadds is not None and int(coadds) != 1:
        n = int(coadds)
        if n < 1:
            raise IPCInputError(f"{label}: coadds must be >= 1, got {coadds!r}")
        scale = scale / n
        parts.append(f"divided by {n} coadded exposures")
    text = (f"{units.text or 'electrons (no BUNIT)'} -> electrons"
            + (f" ({'; '.join(parts)})" if parts else ""))
    return scale, text

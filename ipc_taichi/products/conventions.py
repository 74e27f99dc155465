"""Which pixels take part, in which units: the rules shared by every product.

These are pure functions of arrays and header values; the readers and writers
(:mod:`ipc_taichi.products.fits`, :mod:`ipc_taichi.products.roman`, the
``stpipe`` step) call them, and :func:`correct_frames` applies them to the
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
  :func:`correct_frames` with ``pedestal``.
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

from .. import iteration, noise
from ..coupling import couple
from ..decoupling import decouple
from ..errors import ConvergenceWarning, DivergenceError, IPCInputError
from ..interrupts import check_stop
from ..progress import reporters
from .checks import FrameLost, LostFrames, dq_word
from .missions import DEFAULT_DQ, JWST_DQ_FLAGS, REFERENCE_PIXEL

__all__ = ["ProductWarning", "parse_dq_bits", "untrusted", "unusable_gain", "science_region",
           "charge_scale", "correct_frames", "Units", "RATE_UNITS", "CHARGE_UNITS", "Unphysical",
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
                   out=None, max_iter=iteration.MAX_ITER, tol=iteration.TOL, arch=None,
                   precision=None, label="data", pedestal=None, unphysical="mask",
                   progress=None, ramp=False, noise=None):
    """Couple or decouple every 2-D frame of ``data`` by the product rules.

    The pure correction function under every product reader/writer.

    Parameters
    ----------
    data : ndarray, shape (..., ny, nx)
        The science array in its own units (any real dtype).
    operation : {"couple", "decouple"}
    model : CouplingModel
        The model of the science region (its edge rule decided by
        :func:`ipc_taichi.products.plan.edge_of`).
    mask : ndarray of bool, optional
        Untrusted pixels (True), broadcastable to ``data``: they keep their
        values and do not couple (see :func:`untrusted`).
    region : (slice, slice), optional
        The science region inside the reference pixels (default: the frame).
    scale : float or ndarray (ny, nx)
        Electrons per data unit (see :func:`charge_scale`); pixels without a
        usable per-pixel gain are left out.
    out : ndarray, optional
        Where to write (same shape as ``data``; default: a float64 copy).
        Pixels outside ``region`` and masked pixels are copied from ``data``.
    max_iter, tol, arch, precision :
        As for :func:`ipc_taichi.decouple`.
    label : str
        The file and HDU, for error messages.
    pedestal : ndarray (ny, nx), optional
        Charge on the node before the first read, in electrons, as measured
        (e.g. a zeroth read). The law sees ``data + pedestal``: decouple gives
        ``D(M + P) - D(P)``, couple ``C(S + P) - C(P)``, so the frame keeps its
        meaning (charge since the pedestal) while alpha is evaluated at the
        charge really on the node.
    unphysical : {"mask", "keep"} or Unphysical
        What is done with unflagged pixels no detector can hold (see
        :class:`Unphysical`; pass one to read the count afterwards). Said in
        one warning line for the whole array.
    progress : callable, optional
        Told of each frame done, or of each iteration of a lone frame (see
        :func:`ipc_taichi.progress.reporters`).
    ramp : bool
        The frames along axis -3 are the groups of a ramp (the charge grows
        from one to the next): decouple each integration's groups with warm
        starts (:func:`ipc_taichi.decouple` ``warm_start=True``: each group
        starts from the previous group's answer plus the new charge; the same
        stopping rule, so the same tolerance as from scratch).
    noise : dict, optional
        The product's noise arrays beside ``data`` (``err``, ``var_poisson``, ``var_rnoise``,
        ``var_flat``; each of ``data``'s shape, float64, C-contiguous, data units), replaced in
        place, frame by frame, by their values after the decoupler with this frame's region,
        model, mask, scale and pedestal (:func:`ipc_taichi.noise.propagate_noise`). Decouple only.

    Returns
    -------
    out : ndarray
    infos : list of DecoupleInfo (decouple) or of None (couple), one per frame.
    """
    data = np.asarray(data)
    shape = data.shape
    ny, nx = shape[-2:]
    region = region or (slice(0, ny), slice(0, nx))
    frames = data.reshape((-1, ny, nx))
    masks = None if mask is None else np.broadcast_to(mask, shape).reshape((-1, ny, nx))
    if out is None:
        out = np.array(data, dtype=np.float64)
    else:  # the region is written frame by frame below; the rest kept from data
        _copy_outside(out, data, region)
    flat_out = out.reshape((-1, ny, nx))
    s = np.asarray(scale, dtype=np.float64)
    s_in = s[region] if s.ndim == 2 else s
    base = None if pedestal is None else np.asarray(pedestal, dtype=np.float64)[region]
    after_frame, after_iteration = reporters(progress, frames.shape[0], max_iter)
    settings = dict(operation=operation, model=model, max_iter=max_iter, tol=tol, arch=arch,
                    precision=precision, callback=after_iteration, spare={})
    record = unphysical if isinstance(unphysical, Unphysical) else Unphysical(unphysical)
    offset = (region[0].start or 0, region[1].start or 0)
    if any(not v.flags.c_contiguous for v in (noise or {}).values()):
        raise ValueError("correct_frames: noise arrays must be C-contiguous (updated in place)")
    noisy = {k: v.reshape((-1, ny, nx)) for k, v in (noise or {}).items()
             if operation == "decouple"}
    cached = {}
    infos, lost = [], LostFrames(frames.shape[0])
    groups = shape[-3] if ramp and operation == "decouple" and len(shape) > 2 else 1
    for k0 in range(0, frames.shape[0], groups):
        check_stop()  # a SIGINT/SIGTERM swallowed by a library stops the run here
        ks = range(k0, k0 + groups)
        wheres = [f"{label} frame {k}" if frames.shape[0] > 1 else label for k in ks]
        into = settings["spare"].pop("in", None) if groups == 1 else None  # done with
        try:
            measured, ms = zip(*(_frame_in(frames[k][region], s, s_in, base, record, where,
                                           offset, operation,
                                           None if masks is None else masks[k][region], into)
                                 for k, where in zip(ks, wheres)))
        except FrameLost as exc:  # one frame of a stack: left as it came, said
            infos.append(lost.keep(exc, operation, groups))
            flat_out[k0][region] = frames[k0][region]
            continue
        results, run_infos = _solve(measured, ms, base, cached, wheres, settings)
        for k, y, m, result, info in zip(ks, measured, ms, results, run_infos):
            if not _unit(s_in):
                with np.errstate(divide="ignore", invalid="ignore"):  # no gain: masked
                    result = result / s_in
            target = flat_out[k][region]
            target[...] = result if m is None else np.where(m, frames[k][region], result)
            if noisy:
                _propagate(noisy, k, region, target, y, m, model, s_in, base)
            infos.append(info)
            if after_frame is not None:
                after_frame(k + 1)
        settings["spare"].update({"in": measured[0]} if groups == 1 else {})
    record.warn(label)
    if lost.said():
        warnings.warn(lost.said(), ProductWarning, stacklevel=2)
    return out, infos


def _frame_in(frame, s, s_in, base, record, where, offset, operation, flagged, into=None):
    """One frame's measured charge (electrons) and its mask (None when none);
    written into ``into`` (a float64 array the caller has done with) when it fits."""
    fits = into is not None and into.shape == frame.shape
    measured = into if fits else frame.astype(np.float64)
    if fits:
        np.copyto(measured, frame, casting="unsafe")
    if not _unit(s_in):
        measured *= s_in
    m = untrusted([], 0, measured.shape, flagged, gain=s_in if s.ndim == 2 else None)
    bad = record.add(measured if base is None else measured + base, m, where, offset)
    if bad is not None:
        m = bad if m is None else (m | bad)
    good = np.isfinite(measured) if m is None else (np.isfinite(measured) & ~m)
    if not good.any():
        raise FrameLost(f"{where}: no finite, unmasked pixel to {operation} "
                        "(all NaN, flagged or unphysical)")
    return measured, m


def _copy_outside(out, data, region):
    """``out = data`` outside ``region``, in four slabs (the frame loop writes
    every pixel inside it: its result, or the input for a masked pixel)."""
    (y0, y1, _), (x0, x1, _) = (r.indices(n) for r, n in zip(region, data.shape[-2:]))
    for part in ((slice(0, y0), slice(None)), (slice(y1, None), slice(None)),
                 (slice(y0, y1), slice(0, x0)), (slice(y0, y1), slice(x1, None))):
        out[(Ellipsis,) + part] = data[(Ellipsis,) + part]


def _unit(scale):
    """Whether electrons per unit is the number 1: a pass saved, no bit changed."""
    return scale.ndim == 0 and float(scale) == 1.0


def _solve(measured, masks, base, cached, wheres, settings):
    """The frames (one, or the groups of one integration, warm-started) through
    the decoupler or the forward model; ``D(M + P) - D(P)`` with a pedestal."""
    if len(measured) == 1:
        charge, mask, where = measured[0], masks[0], wheres[0]
    else:
        charge, where = np.stack(measured), f"{wheres[0]}-{wheres[-1].rsplit(' ', 1)[-1]}"
        mask = None if all(m is None for m in masks) else np.stack(
            [np.zeros(charge.shape[1:], bool) if m is None else m for m in masks])
    if base is not None:
        charge = charge + base
    result, info = _run(charge, mask, where, **settings)
    results = [result] if len(measured) == 1 else list(result)
    infos = [info] if len(measured) == 1 else list(info)
    if base is not None:
        for i, (m, w) in enumerate(zip(masks, wheres)):
            key = None if m is None else m.tobytes()
            if key not in cached:  # the pedestal through the same law, once per mask
                cached[key] = _run(base, m, w, **{**settings, "spare": None})[0]
            results[i] = results[i] - cached[key]
    return results, infos


def _propagate(noisy, k, region, solution, measured, mask, model, s_in, base):
    """Frame ``k`` of the noise arrays through the linearised decoupler, in place."""
    given = {name: array[k][region] for name, array in noisy.items()}
    with np.errstate(divide="ignore", invalid="ignore"):
        y = measured / s_in
    new = noise.propagate_noise(np.asarray(solution, dtype=np.float64), model, measured=y,
                                mask=mask, scale=s_in, pedestal=base, **given)
    for name, value in new.items():
        given[name][...] = value


def _run(charge, mask, where, operation, model, max_iter, tol, arch, precision, callback,
         spare=None):
    """One frame in electrons (or a ramp's groups: warm-started) through the decoupler or
    the forward model; ``spare`` (dict or None): the previous frame's decoupled array,
    done with, is written again (a new one pays a page fault per page), this one kept."""
    out = None if spare is None else spare.pop("frame", None)
    out = out if out is not None and out.shape == np.shape(charge) else None
    with warnings.catch_warnings(), named(where):
        warnings.simplefilter("ignore", ConvergenceWarning)  # reported per frame by callers
        if operation == "decouple":
            result, info = decouple(charge, model=model, mask=mask, max_iter=max_iter,
                                    tol=tol, arch=arch, precision=precision, full_output=True,
                                    callback=callback, warm_start=np.ndim(charge) == 3,
                                    out=out)
            if spare is not None and type(result) is np.ndarray and result.ndim == 2:
                spare["frame"] = result
        else:
            result, info = couple(charge, model=model, mask=mask, arch=arch,
                                  precision=precision), None
    return np.asarray(np.ma.getdata(result), dtype=np.float64), info

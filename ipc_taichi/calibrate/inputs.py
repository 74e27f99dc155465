"""Calibration inputs: darks, ramps and flats read as charge [e-] with their masks.

The product conventions are those of :mod:`ipc_taichi.products` (the same
science-HDU choice, BUNIT parsing, gain reader, DQ bits, reference border and
bias-product refusal as ``decouple``); this module arranges the result for
measuring: every input becomes ``(nints, nframes, ny, nx)`` float64
electrons and a boolean mask of the same shape (DQ bits, NaN, the reference
border), and says in :attr:`ChargeFrames.meta` what the file is and how its
numbers became electrons.

**Ramp or frames** (``meta["stack"]`` in {"ramp", "frames"}, with
``meta["stack_reason"]``, one sentence):

- a 4-D science array is ramps, ``(nints, ngroups, ny, nx)``;
- a 2-D array is one frame;
- a 3-D cube is one ramp when its reads rise, else a stack of frames at one
  level. The test (:func:`cube_rises`): per step ``k -> k + 1`` the pixel
  differences ``D_k`` (pixels unmasked in both), their median ``s_k``, their
  noise ``sigma_k`` (1.4826 x the median absolute deviation of the
  differences of horizontal neighbours in ``D_k``, over sqrt(2): the
  illumination pattern and its gradients drop out) and the error of the
  median ``e_k = 1.2533 sigma_k / sqrt(n_k)``. The cube is a ramp when no
  step falls (every ``s_k > -5 e_k``) and the whole rise ``sum_k s_k``
  exceeds ``5 x median_k sigma_k``: the reads gain much more charge than the
  noise of one read difference. Frames at one level (independent exposures)
  change by lamp drift only, well inside that noise (``sqrt(2 S)`` at level
  ``S``), or fall. A dark's reads gain little charge and are "frames" by this
  test unless the JWST keywords confirm a ramp (``NGROUPS`` equal to the
  number of reads): for hot pixels the difference does not matter.

**Units, gain, science region and DQ** (:func:`plan_charge`): decided by the product
plan, as for ``decouple`` (:func:`ipc_taichi.products.plan.plan_array`:
``bunit`` overrides BUNIT; a file without units is DN when a gain is given
or the file has a GAIN keyword, electrons otherwise,
:func:`ipc_taichi.products.plan.units_of`; DN need a gain, given or the GAIN
keyword; a gain given for data in electrons is refused, in the same words),
the pixels left out by :func:`ipc_taichi.products.conventions.untrusted`
with the bits of :func:`ipc_taichi.products.plan.dq_bits_of`. Calibrate's own
reading: rates are refused (it needs accumulated charge). Each case is said
in ``meta["units_note"]``; never silent.

**Refusals** (:class:`~ipc_taichi.errors.IPCInputError`, one line naming the
file and HDU): bias products (:func:`ipc_taichi.products.missions.check_not_bias`,
the same refusal as ``decouple``), other JWST reference files but darks
(``REFTYPE``), rates, raw reads that are not a ramp (integer frames hold the
bias: a raw bias read is named as one), and files in which no pixel has a
usable read (all saturated: said). A raw integer 4-D ramp (``_uncal``), which ``decouple``
refuses for the bias in it, is accepted: the first read of each integration
is subtracted, so the data are the charge collected since the first read.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import IPCInputError
from ..fitsio import parse_hdu
from ..model import CouplingModel
from ..products import conventions as cv
from ..products import missions, plan
from ..products.fits import array_facts
from ..products.fitsfile import (
    flag_hdus,
    hdu_label,
    keyword,
    open_fits,
    read_array,
    science_indices,
    shape_of,
)
from ..products.options import ProductOptions
from . import stream

__all__ = ["ChargeFrames", "read_frames", "DEFAULT_DQ_BITS", "ROLES", "plan_charge",
           "cube_rises", "RISE_SIGMAS"]

DEFAULT_DQ_BITS = "DO_NOT_USE,SATURATED,JUMP_DET,DEAD"
"""DQ bits whose pixels are left out of every measurement (HOT and WARM are
not among them: hot pixels are what the darks are measured with)."""

ROLES = (None, "dark", "flat")
"""What an input is given as (None: not said)."""

RISE_SIGMAS = 5.0
"""The ramp test's margin (see :func:`cube_rises`)."""

_ACCEPTED_REFTYPES = ("DARK",)
_SAMPLE_PIXELS = 100_000


@dataclass
class ChargeFrames:
    """Charge and mask of one input file.

    ``meta`` keys: ``stack`` ("ramp" or "frames"), ``stack_reason`` (one
    sentence), ``nints``, ``ngroups`` (None for frames), ``nframes`` (reads or
    frames per integration), ``units_note`` (one sentence), ``gain`` (e-/DN
    used, the median of a gain image; None for electrons), ``gain_source``
    ("given", "GAIN keyword" or None), ``saturation`` (e-, or None),
    ``first_read_subtracted`` (bool), ``dq_note`` (the DQ names the file's
    own ``DQ_DEF`` lacks, one sentence, or None), ``role``.
    """

    path: str
    label: str
    data: np.ndarray  # (nints, nframes, ny, nx) electrons
    mask: np.ndarray  # same shape, True = not trusted
    units: str
    meta: dict = field(default_factory=dict)

    @property
    def shape2d(self):
        return self.data.shape[-2:]


def _as4d(array):
    a = np.asarray(array)
    return a.reshape((1,) * (4 - a.ndim) + a.shape)


def read_frames(path, hdu=None, gain=None, dq_bits=DEFAULT_DQ_BITS, refpix=None, bunit=None, *,
                role=None, sections=False):
    """Read a dark, ramp or flat product into :class:`ChargeFrames`.

    Parameters
    ----------
    path : str
        FITS (a JWST product or plain) or Roman ASDF.
    hdu : int, str or None
        Science HDU (FITS; default SCI, else the first image HDU).
    gain : float, str or None
        e-/DN (a number or a gain image file). Without BUNIT, a gain given
        (or a GAIN keyword) makes the data DN; see :func:`plan_charge`.
    dq_bits : str or int
        See :data:`DEFAULT_DQ_BITS`.
    refpix : int or None
        Reference border (default: the product's, as for ``decouple``).
    bunit : str or None
        Override the file's units (``DN``, ``electron``; rates are refused).
    role : {None, "dark", "flat"}
        What the file is given as (named in errors).
    sections : bool
        A 4-D FITS ramp is read by sections (:mod:`.stream`: ``data`` and
        ``mask`` are :class:`.stream.LazyCharge`, never held whole).

    Returns
    -------
    ChargeFrames
        ``data`` (nints, nframes, ny, nx) float64 e- (NaN where masked),
        ``mask`` of the same shape, ``meta`` (see :class:`ChargeFrames`).
    """
    if role not in ROLES:
        raise IPCInputError(f"{path}: role {role!r}: expected 'dark' or 'flat'")
    if missions.is_asdf(path):
        frames, ndim, keys = _read_asdf(path, gain, dq_bits, refpix, bunit)
        saturated = (None, "")
    else:
        frames, ndim, keys, saturated = _read_fits(path, hdu, gain, dq_bits, refpix, bunit,
                                                   sections=sections)
    frames.meta["role"] = role
    frames.meta.update(_stack(frames, ndim, keys))
    _check_usable(frames, saturated, role)
    return frames


# ---- units and gain ------------------------------------------------------------------

def _gain_text(g):
    g = np.asarray(g, dtype=np.float64)
    if g.ndim == 0:
        return f"{float(g):g} e-/DN"
    return f"a gain image (median {float(np.nanmedian(g)):g} e-/DN)"


def plan_charge(facts, mission, gain=None, bunit=None, refpix=None, source="BUNIT"):
    """The product plan of one science array, made as ``decouple`` makes it,
    and the sentence that says how its numbers became electrons.

    Units, gain and the science region are :func:`ipc_taichi.products.plan.plan_array`'s
    (the rule of ``decouple``, :func:`ipc_taichi.products.plan.units_of`: a
    file without units is DN when a gain is known, given or its GAIN
    keyword, else electrons; DN need a gain; a gain given for data in
    electrons is refused; a GAIN keyword that is not a number, or a gain
    image with no usable pixel, is refused naming it). Calibrate adds one
    reading of its own: rates are refused (it needs accumulated charge). The
    frames are measured as stored (``NCOADDS`` is not applied: a coadded
    frame's noise is its sum's).

    Parameters
    ----------
    facts : ArrayFacts
        The array (:func:`ipc_taichi.products.fits.array_facts`, or a Roman
        model's).
    mission : Mission
    gain : float, str or None
        e-/DN given by the caller (a number or a gain image file).
    bunit : str or None
        Units given by the caller (override).
    refpix : int or None
    source : str
        Where the file's units come from, in the sentences.

    Returns
    -------
    arrays : ArrayPlan
        ``scale`` (electrons per data unit), ``units_text``, ``science_region``.
    info : dict
        ``units_note`` (one sentence), ``gain`` (float: e-/DN, the median of
        a gain image; None for electrons), ``gain_source`` ("given", "GAIN
        keyword" or None).

    Raises
    ------
    IPCInputError
        Rates, flux units, unknown units, DN without a gain, a gain given
        for data in electrons (one line naming ``facts.label``).
    """
    text = bunit if bunit is not None else facts.keyword("BUNIT")
    said = "bunit" if bunit is not None else source
    gain_source = "given" if gain is not None else (
        "GAIN keyword" if facts.keyword("GAIN") is not None else None)
    options = ProductOptions.from_kwargs(gain=gain, bunit=bunit, refpix=refpix, pedestal="none",
                                         coadds=1)
    units = plan.units_of(facts, mission, options, said)  # decouple's rule, no-BUNIT case too
    if units.rate:
        raise IPCInputError(f"{facts.label}: a rate ({units.text}); calibrate needs darks, "
                            "ramps or flats of accumulated charge (DN or electrons)")
    if text is not None and str(text).strip():
        head = f"{said} {str(text).strip()!r}"
    elif units.needs_gain:
        head = f"no {source}: taken as DN"
    else:
        head = f"no {source} and no gain: taken as electrons"
    arrays = plan.plan_array(facts, mission, CouplingModel.resolve(), options)
    if not units.needs_gain:
        note = head if head.startswith("no ") else f"{head}: electrons"
        return arrays, {"units_note": note, "gain": None, "gain_source": None}
    where = "given" if gain_source == "given" else "from the GAIN keyword"
    note = (f"{head}, gain {_gain_text(arrays.scale)} {where}" if head.startswith("no ")
            else f"{head}: DN converted with gain {_gain_text(arrays.scale)} {where}")
    used = float(np.nanmedian(np.asarray(arrays.scale, dtype=np.float64)))
    return arrays, {"units_note": note, "gain": used, "gain_source": gain_source}


# ---- FITS ----------------------------------------------------------------------------

def _science_hdu(path, hdul, hdu):
    """The science HDU as ``decouple`` chooses it (its first), a raw integer
    4-D ramp (``_uncal``) accepted: calibrate subtracts the first read."""
    index, label = science_indices(path, hdul, hdu, raw_ok=True)[0]
    h = hdul[index]
    integer = h.header["BITPIX"] > 0
    if integer and not (h.header.get("NAXIS") == 4 and h.header.get("NAXIS3", 1) >= 2):
        raise IPCInputError(
            f"{label}: integer {'x'.join(map(str, h.shape))} reads: raw reads hold the "
            "detector's bias, not collected charge; give the raw ramp (4-D, 2 or more reads: "
            "calibrate subtracts its first read) or frames with the bias removed")
    return index, label, integer


def _check_reftype(primary, label):
    """Bias products as ``decouple`` refuses them; then any other JWST
    reference file but a dark (a kernel, a flat-field response, a gain map
    hold no collected charge)."""
    missions.check_not_bias(primary, label)
    reftype = str(primary.get("REFTYPE", "")).strip().upper()
    if reftype and reftype not in _ACCEPTED_REFTYPES:
        hint = " (give it as the reference: --reference)" if reftype == "IPC" else ""
        raise IPCInputError(f"{label}: a {reftype.lower()} reference file (REFTYPE = {reftype})"
                            f", not a dark, ramp or flat exposure of collected charge{hint}")


def _read_fits(path, hdu, gain, dq_bits, refpix, bunit, sections=False):
    """``sections``: a 4-D ramp is read by sections (:mod:`.stream`)."""
    hdul = open_fits(path, memmap=False)
    with hdul:
        index, label, raw = _science_hdu(path, hdul, parse_hdu(hdu))
        _check_reftype(hdul[0].header, label)
        shape = shape_of(hdul[index].header)
        mission = missions.recognise(hdul[0].header, hdul[index].header, hdul)
        arrays, info = plan_charge(array_facts(path, hdul, index, label), mission, gain, bunit,
                                   refpix)
        region, scale = arrays.science_region, arrays.scale
        if not region.arrangement.identity:
            raise IPCInputError(f"{label}: {region.arrangement.describe()}: calibrate reads "
                                "contiguous frames; give the products after the refpix step "
                                "(its reference samples removed)")
        bits, lacking = plan.dq_bits_of(dq_bits, mission)
        saturate = keyword(hdul, index, "SATURATE")
        level = None if saturate is None else float(saturate) * float(np.max(scale))
        keys = {k: keyword(hdul, index, k) for k in ("NGROUPS", "NINTS", "READPATT")}
        keys["hdu"] = hdu_label(hdul, index)
        if (sections and len(shape) == 4
                and stream.readable_by_sections(path, hdul, index)):
            source = stream.RampSource(path, hdul, index, scale,
                                       flag_hdus(hdul, index, shape, path),
                                       bits, bits & mission.flag("SATURATED"),
                                       region.inside_mask(), region.slices, level, raw)
            data = stream.LazyCharge([(source, shape[0])])
            info.update(saturation=None if raw else level, first_read_subtracted=raw,
                        dq_note=_dq_note(lacking, path))
            return (ChargeFrames(path, label, data, data.like("mask"), arrays.units_text, info),
                    4, keys, (data.like("saturated"), "DQ SATURATED or >= SATURATE"))
        data = np.asarray(read_array(path, hdul, index), dtype=np.float64) * scale
        flags = [read_array(path, hdul, k) for k in flag_hdus(hdul, index, shape, path)]
        mask = _untrusted(flags, bits, shape, region, scale)
        saturated = _untrusted(flags, bits & mission.flag("SATURATED"), shape)
    said = ["DQ SATURATED"] if saturated.any() else []
    if level is not None:
        with np.errstate(invalid="ignore"):
            above = data >= level
        saturated |= above
        said += [f">= SATURATE ({_e(level)} e-)"] if above.any() else []
    if raw:  # bias in every read: keep the charge collected since the first read
        mask |= saturated
        data = data - data[:, :1]
        mask = mask | mask[:, :1]
        level = None
    info.update(saturation=level, first_read_subtracted=raw, dq_note=_dq_note(lacking, path))
    frames = _finish(path, label, data, mask, region.slices, arrays.units_text, info)
    return frames, len(shape), keys, (_as4d(saturated), " or ".join(said))


def _untrusted(flags, bits, shape, region=None, scale=None):
    """The pixels ``decouple`` leaves out
    (:func:`ipc_taichi.products.conventions.untrusted`: the DQ ``bits`` of
    ``flags``, the reference-flagged pixels inside ``region``, a
    :class:`~ipc_taichi.products.plan.ScienceRegion`, the pixels of a gain
    image ``scale`` without a usable gain),
    as an array of ``shape`` (all False when none)."""
    mask = cv.untrusted(flags, bits, shape, None if region is None else region.inside_mask(),
                        gain=scale)
    return np.zeros(shape, dtype=bool) if mask is None else mask


def _dq_note(lacking, path):
    """The sentence saying which DQ names the file's own ``DQ_DEF`` lacks (a
    NIRSpec dark defines HOT = 4, JUMP_DET in science products: the
    mission's names never fill in; :func:`ipc_taichi.products.plan.dq_bits_of`),
    or None."""
    if not lacking:
        return None
    return (f"{path}[DQ_DEF] defines no {', '.join(lacking)}: those pixels are not left out "
            "by name")


# ---- Roman ASDF ----------------------------------------------------------------------

def _read_asdf(path, gain, dq_bits, refpix, bunit):
    try:
        import roman_datamodels.datamodels as rdm
    except ImportError:
        raise IPCInputError(f"{path}: Roman ASDF needs roman_datamodels") from None
    label = f"{path}[data]"
    try:
        dm = rdm.open(path)
    except Exception as exc:
        raise IPCInputError(f"{path}: not a readable Roman datamodel ({type(exc).__name__})") \
            from None
    with dm:
        data = np.asarray(dm.data, dtype=np.float64)
        names = [n for n in ("pixeldq", "groupdq", "dq") if n in dm and dm[n] is not None]
        flags = [np.asarray(dm[n]) for n in names]
        for name, f in zip(names, flags, strict=True):
            if f.shape != data.shape[data.ndim - f.ndim:]:
                raise IPCInputError(f"{path}[{name}]: shape {f.shape} does not match the "
                                    f"data {data.shape}")
        mission = missions.roman_mission()
        keys = missions.roman_keywords(type(dm).__name__, dm.meta)
        facts = plan.ArrayFacts(0, "data", label, data.shape, keys, keys, _reference(flags))
        arrays, info = plan_charge(facts, mission, gain, bunit, refpix, source="Roman schema")
        bits, _ = plan.dq_bits_of(dq_bits, mission)
    data = data * arrays.scale
    mask = _untrusted(flags, bits, data.shape, arrays.science_region, arrays.scale)
    info.update(saturation=None, first_read_subtracted=False, dq_note=None)
    frames = _finish(path, label, data, mask, arrays.region, arrays.units_text, info)
    return frames, data.ndim, {"hdu": "data"}


def _reference(flags):
    """``() -> the REFERENCE_PIXEL flags of the first DQ array's first frame``
    (a Roman model's, as :func:`ipc_taichi.products.plan.science_region_of` asks)."""
    def reference():
        if not flags:
            return None
        first = flags[0].reshape((-1,) + flags[0].shape[-2:])[0].astype(np.int64)
        return (first & cv.REFERENCE_PIXEL) != 0
    return reference


def _finish(path, label, data, mask, region, units_text, meta):
    """Mask NaN and the reference border; NaN where masked (in place: the
    arrays are this module's own)."""
    mask |= ~np.isfinite(data)
    outside = np.ones(data.shape[-2:], dtype=bool)
    outside[region] = False
    mask |= outside
    np.copyto(data, np.nan, where=mask)
    return ChargeFrames(path, label, _as4d(data), _as4d(mask), units_text, meta)


# ---- ramp or frames ------------------------------------------------------------------

def _sample(cube):
    """Rows of ``cube`` (n, ny, nx), every k-th, about :data:`_SAMPLE_PIXELS` per frame."""
    ny, nx = cube.shape[-2:]
    return cube[:, ::max(1, (ny * nx) // _SAMPLE_PIXELS)]


def _e(x):
    """Charge for a sentence: ``41000``, ``150``, ``0.497``."""
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.3g}"


def _level(frame):
    values = frame[np.isfinite(frame)]
    return float(np.median(values)) if values.size else float("nan")


def cube_rises(cube):
    """Whether the reads of a cube rise: the ramp test of this module.

    Parameters
    ----------
    cube : ndarray, (n, ny, nx)
        Charge [e-], NaN where masked.

    Returns
    -------
    dict
        ``rises`` (bool), ``first``, ``last`` (median charge of the first and
        last frame, e-), ``rise`` (sum of the median steps, e-), ``noise``
        (median pixel noise of one step, e-), ``falls`` (steps that fall by
        more than :data:`RISE_SIGMAS` errors of their median).
    """
    cube = np.asarray(_sample(cube), dtype=np.float64)
    steps, noises, falls = [], [], 0
    for k in range(cube.shape[0] - 1):
        step = cube[k + 1] - cube[k]
        values = step[np.isfinite(step)]
        neighbour = (step[:, 1:] - step[:, :-1]).ravel()
        neighbour = neighbour[np.isfinite(neighbour)]
        if values.size < 2 or neighbour.size < 2:
            continue  # no pixel good in both reads: the step says nothing
        s = float(np.median(values))
        sigma = 1.4826 * float(np.median(np.abs(neighbour - np.median(neighbour)))) / np.sqrt(2)
        steps.append(s)
        noises.append(sigma)
        falls += s < -RISE_SIGMAS * 1.2533 * sigma / np.sqrt(values.size)
    rise = float(np.sum(steps)) if steps else 0.0
    noise = float(np.median(noises)) if noises else float("nan")
    rises = bool(steps) and falls == 0 and rise > RISE_SIGMAS * noise
    return {"rises": rises, "first": _level(cube[0]), "last": _level(cube[-1]), "rise": rise,
            "noise": noise, "falls": int(falls)}


def _keyword_ramp(keys, n):
    """``"; NGROUPS = n"`` when the JWST keywords say the ``n`` reads are groups."""
    ngroups, nints = keys.get("NGROUPS"), keys.get("NINTS")
    try:
        match = int(ngroups) == n and (nints is None or int(nints) == 1)
    except (TypeError, ValueError):
        return ""
    if not match:
        return ""
    patt = keys.get("READPATT")
    return f"; NGROUPS = {n}" + (f", READPATT {str(patt).strip()}" if patt else "")


def _stack(frames, ndim, keys):
    """``stack``, ``stack_reason``, ``nints``, ``ngroups``, ``nframes``."""
    nints, n = frames.data.shape[:2]
    name = keys.get("hdu", "")
    if ndim == 2 or (ndim == 3 and n == 1):
        return {"stack": "frames", "stack_reason": f"{ndim}-D {name}: one frame", "nints": 1,
                "ngroups": None, "nframes": 1}
    rise = cube_rises(frames.data[0])
    change = f"{_e(rise['first'])} -> {_e(rise['last'])} e-"
    if ndim == 4:
        raw = ("; integers: a raw (_uncal) ramp, its first read subtracted"
               if frames.meta.get("first_read_subtracted") else "")
        verb = "rises" if rise["rises"] else "changes"
        reason = (f"4-D {name} ({nints} integrations x {n} groups; the mean of the first "
                  f"{verb} {change}){raw}")
        return {"stack": "ramp", "stack_reason": reason, "nints": nints, "ngroups": n,
                "nframes": n}
    confirmed = _keyword_ramp(keys, n)
    if rise["rises"]:
        reason = f"3-D cube of {n} reads whose mean rises {change} (a ramp{confirmed})"
    elif confirmed:
        reason = (f"3-D cube of {n} reads ({confirmed[2:]}): a ramp whose mean changes "
                  f"{change}, within {RISE_SIGMAS:g} x its noise of {rise['noise']:.3g} e- "
                  "per read difference")
    else:
        why = ("it falls between frames" if rise["falls"] else
               f"a change within {RISE_SIGMAS:g} x the noise of a frame difference, "
               f"{rise['noise']:.3g} e-")
        return {"stack": "frames", "nints": 1, "ngroups": None, "nframes": n,
                "stack_reason": f"3-D stack of {n} frames at one level (mean {change}: {why})"}
    return {"stack": "ramp", "stack_reason": reason, "nints": 1, "ngroups": n, "nframes": n}


# ---- refusals after reading ----------------------------------------------------------

def _check_usable(frames, saturated, role):
    """Refuse a file where no pixel has a usable read (two, in a ramp or a
    stack: a difference, or a deviation free of the fixed pattern, needs
    them), saying when saturation is why. ``saturated``: the pixels
    saturated (DQ or SATURATE) or None, and the sentence saying by what."""
    sat, by_what = saturated
    shape = frames.mask.shape
    need = min(2, shape[1])
    but_saturation = False  # usable but for saturation
    for rows in stream.row_strips(shape[-2], 8 * shape[0] * shape[1] * shape[-1]):  # float64
        mask = frames.mask[:, :, rows]
        part = np.zeros(mask.shape, dtype=bool) if sat is None else sat[:, :, rows]
        if ((~mask & ~part).sum(axis=1) >= need).any():
            return
        but_saturation |= bool(((~(mask & ~part)).sum(axis=1) >= need).any())
    what = f"{role} {frames.meta['stack']}" if role else frames.meta["stack"]
    if but_saturation:
        raise IPCInputError(f"{frames.label}: every read of this {what} is saturated "
                            f"({by_what}): no pixel has {need} unsaturated read(s) to measure; "
                            "lower the illumination or shorten the ramp")
    raise IPCInputError(f"{frames.label}: every pixel of this {what} is masked (DQ bits, NaN "
                        f"or the reference border): no pixel has {need} usable read(s)")

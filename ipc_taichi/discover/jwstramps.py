"""A JWST ramp (``_uncal``-like) as a discovery ramp file (``docs/discover.md``,
"Real ramps").

The input is read as ``calibrate`` reads it
(:func:`ipc_taichi.calibrate.inputs.read_frames`: the science HDU, BUNIT and
gain to electrons, DQ, saturation and the reference border masked as NaN):
``(nints, ngroups, ny, nx)`` electrons. The group time is ``TGROUP`` (primary
or science header; ``tgroup`` overrides it, and a file without it needs one).

**Reads.** The bias and reset level of a raw read are not known per pixel
(no superbias, no reference pixels: the FGS ACQ1 file has neither), so
every integration's first group is subtracted from its others: read ``j``
of the ramp pair is ``group j+1 - group 0``, at ``t_j = (j + 1) TGROUP``
(``TFRAME = TFIRST = TGROUP``), and ``FIRSTSUB = T`` says that the first
increment carries the subtracted read's noise too (the model then whitens
with it). The charge collected before group 0 is not in the reads; the
coupling acts on the charge present, which for a constant law is the same.

**SCENE** (the rate, e-/s) is not known for real data: it is estimated.
With 2 or more integrations, integration ``k``'s SCENE is the mean over the
*other* integrations of each one's slope (its last read over that read's
time), each slope first cleared of the offsets its rows and columns share
(its departure from the pixel's median slope less that departure's row and
column medians: those integrations' 1/f read noise must not enter
integration ``k``'s rate): leave one out, so the rate holds none of
integration ``k``'s noise and the gap stays a test of the model (a rate
below 0, a dark pixel's noise, is set to 0: the model collects no negative
charge, and its simulations would not match the mean). The price: the rate's own noise
enters every residual. For a pixel with ``n`` integrations of one increment
each, the residual's variance is ``n / (n - 1)`` times the model's (1.2 for
the FGS file's 6; :func:`expected_gap_factor`, exact where read noise
dominates). So the file carries that variance (``SCENEVAR``, e-/s squared,
:func:`scene_variance`, from the model: the slope's shot and read variance
over the number of other integrations): the increments are whitened with
it and the floor simulations draw it, and a complete model reaches its
floor. What it cannot carry: integration ``k``'s rate error is shared with
the others' (they are made of the same slopes), which matters only to
statistics across integrations (an after-image decaying over
integrations). With one integration
the rate is the ramp's own slope (its last read over its time): the
residuals then sum to zero per pixel, but the slope carries the noise of
the first and last reads into every increment, and the two nearly cancel
(1.004 for 9 increments).

**READNOIS** (e- per read) is given, or measured on the same data
(:func:`measure_read_noise`): the residual increments (less the leave-one-out
rate; with one integration the second differences of the reads) less
their row and column medians (what lines share is not one pixel's noise),
their variance within 5 robust sigmas (hot and telegraph pixels and cosmic
rays do not count) less the shot noise at the median rate and the rate's
own noise. Measured on the data it absorbs a white excess of the read
noise: discovery can then only see structure.
"""

import json
import math
import warnings

import numpy as np

from ..calibrate.inputs import read_frames
from ..errors import IPCInputError
from ..fitsio import atomic_output
from ..model import CouplingModel
from .ramps import write_ramps

__all__ = ["JwstRamps", "jwst_ramps", "write_jwst_ramps", "measure_read_noise",
           "expected_gap_factor", "group_time", "symmetric_model", "scene_variance"]


class JwstRamps:
    """Ramp pairs made from a JWST ramp: ``rates`` and ``reads`` (per
    integration), ``tgroup`` (s), ``readnoise`` (e-), ``notes`` (sentences:
    how each number was chosen) and ``gap_factor``
    (:func:`expected_gap_factor`: 1 where ``scene_vars``, the SCENE's
    variance per integration, accounts for the rate's noise)."""

    def __init__(self, path, rates, reads, tgroup, readnoise, notes, gap_factor,
                 scene_vars=None):
        self.path, self.rates, self.reads, self.tgroup = path, rates, reads, tgroup
        self.readnoise, self.notes, self.gap_factor = readnoise, notes, gap_factor
        self.scene_vars = scene_vars


def group_time(path, tgroup=None):
    """``tgroup`` (s) or the file's ``TGROUP`` keyword (primary, then SCI)."""
    from astropy.io import fits

    if tgroup is None:
        with fits.open(path, memmap=False) as hdul:
            for hdu in hdul[:2]:
                if "TGROUP" in hdu.header:
                    tgroup = hdu.header["TGROUP"]
                    break
        if tgroup is None:
            raise IPCInputError(f"{path}: no TGROUP keyword (s between groups): give --tgroup")
    try:
        tgroup = float(tgroup)
    except (TypeError, ValueError):
        raise IPCInputError(f"{path}: TGROUP = {tgroup!r} is not a number (s)") from None
    if not (math.isfinite(tgroup) and tgroup > 0):
        raise IPCInputError(f"{path}: TGROUP = {tgroup} must be finite and > 0 (s)")
    return tgroup


def _slopes(reads, times):
    """Each integration's rate per pixel: last read over its time, ``(nints, ny, nx)``."""
    return reads[:, -1] / times[-1]


def _rates(reads, times):
    """SCENE per integration (module docstring): leave one out of the slopes
    less their own row and column offsets, or own slope."""
    slope = _slopes(reads, times)
    n = len(slope)
    if n == 1:
        return slope.copy()
    with warnings.catch_warnings():  # pixels left out in every integration
        warnings.simplefilter("ignore", RuntimeWarning)
        typical = np.nanmedian(slope, axis=0)
    slope = typical[None] + _less_lines(slope - typical[None])
    finite = np.isfinite(slope)
    total = np.where(finite, slope, 0.0).sum(axis=0)
    count = finite.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rates = (total[None] - np.where(finite, slope, 0.0)) / (count[None] - finite)
    rates[~finite] = np.nan  # a pixel masked in integration k stays masked there
    return rates


def _less_lines(x):
    """``x`` (``(..., ny, nx)``) less its row and column medians (twice): what
    rows and columns share is not the read noise of one pixel."""
    x = x.copy()
    with warnings.catch_warnings():  # lines left out entirely
        warnings.simplefilter("ignore", RuntimeWarning)
        for _ in range(2):
            x -= np.nanmedian(x, axis=-1, keepdims=True)
            x -= np.nanmedian(x, axis=-2, keepdims=True)
    return x


def _robust_variance(x):
    """The variance of the values within 5 robust sigmas (1.4826 x MAD) of
    their median: hot and telegraph pixels and cosmic rays do not count, and
    unlike the MAD itself it is not quantised by integer data."""
    x = x[np.isfinite(x)]
    centre = np.median(x)
    scale = 1.4826 * np.median(np.abs(x - centre))
    return float(np.var(x[np.abs(x - centre) <= 5.0 * scale]))


def measure_read_noise(reads, tgroup, rates):
    """Read noise per read (e-) from ramps less their first group
    ``(nints, m, ny, nx)`` and their rates (module docstring): the residual
    increments less what rows and columns share, their variance within 5
    robust sigmas less the shot noise at the median rate and the rate's
    own noise; ``None`` for one integration of one increment."""
    nints, m = reads.shape[:2]
    d = np.diff(reads, axis=1, prepend=0.0)  # increments, each with 2 reads' noise
    used = np.where(np.isfinite(reads[:, -1]), rates, np.nan)  # not the pixels left out
    shot = max(float(np.nanmedian(used)), 0.0) * tgroup  # per increment
    if nints >= 2:  # V = shot + 2 r + (shot m + 2 r) / (m^2 (n - 1))
        total = _robust_variance(_less_lines(d - rates[:, None] * tgroup))
        share = 1.0 / (m * m * (nints - 1))
        r = (total - shot * (1.0 + m * share)) / (2.0 * (1.0 + share))
    elif m >= 2:  # second differences: V = 2 shot + 6 r
        total = _robust_variance(_less_lines(np.diff(d[0], axis=0)))
        r = (total - 2.0 * shot) / 6.0
    else:
        return None
    return math.sqrt(max(float(r), 0.0))


def scene_variance(rates, reads, tgroup, readnoise):
    """Each integration's SCENE variance ((e-/s)^2, ``(nints, ny, nx)``) when it
    is the mean slope of the other integrations: the slope's variance
    ``(rate t_m + 2 r) / t_m^2`` over their number (module docstring)."""
    t_last = tgroup * reads.shape[1]
    finite = np.isfinite(reads[:, -1])
    others = finite.sum(axis=0)[None] - finite
    slope_var = (np.clip(rates, 0.0, None) * t_last + 2.0 * readnoise ** 2) / t_last ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(others > 0, slope_var / others, 0.0)
    return np.where(np.isfinite(out), out, 0.0)


def expected_gap_factor(nints, nreads):
    """The gap a complete model shows over its floor with the rate estimated
    as in the module docstring, where read noise dominates (exact then):
    ``tr(C^-1 R) / m`` for the ``m = nreads`` increments' covariance ``C``
    (each read's noise in two of them) and the residuals' ``R``: ``C`` plus
    the left-out rate's noise (``n / (n - 1)`` for one increment), or ``C``
    projected by the own slope (one integration)."""
    m = int(nreads)
    diff = np.eye(m, m + 1, 1) - np.eye(m, m + 1)  # increments of m + 1 reads' noise
    cov = diff @ diff.T
    ones = np.ones((m, 1)) / m  # the slope's weights on the increments
    if nints == 1:
        proj = np.eye(m) - np.ones((m, 1)) @ ones.T
        resid = proj @ cov @ proj.T
    else:
        resid = cov + (ones.T @ cov @ ones).item() / (nints - 1) * np.ones((m, m))
    return float(np.trace(np.linalg.solve(cov, resid)) / m)


def _exclude(data, boxes, label):
    """NaN in the boxes ``(y0, y1, x0, x1)`` (0-based, ends excluded) of every read."""
    ny, nx = data.shape[-2:]
    for y0, y1, x0, x1 in boxes or ():
        if not (0 <= y0 < y1 <= ny and 0 <= x0 < x1 <= nx):
            raise IPCInputError(f"{label}: exclude box {y0}:{y1},{x0}:{x1} is not inside the "
                                f"{ny}x{nx} frame")
        data[..., y0:y1, x0:x1] = np.nan


def jwst_ramps(path, gain, tgroup=None, readnoise=None, hdu=None, exclude=None,
               frame_offsets=False):
    """Read a JWST ramp ``path`` (``gain`` e-/DN) as :class:`JwstRamps`
    (module docstring); ``exclude``: boxes ``(y0, y1, x0, x1)`` left out
    (NaN: a scene that moves between integrations, such as a guide star,
    is outside the model); ``frame_offsets``: subtract from every group its
    median over the frame (what the pipeline's reference-pixel step removes;
    a subarray without reference pixels keeps it). One-line errors name the file: no TGROUP, fewer
    than 2 groups, one integration of 2 groups (its one increment would be
    its own rate), a box outside the frame."""
    frames = read_frames(path, hdu=hdu, gain=gain)
    data = frames.data
    nints, ngroups = data.shape[:2]
    if ngroups < 2:
        raise IPCInputError(f"{frames.label}: {ngroups} group per integration: a ramp needs 2 "
                            "or more (the first is subtracted)")
    if nints == 1 and ngroups == 2:
        raise IPCInputError(f"{frames.label}: one integration of 2 groups: its one increment "
                            "would be fitted by its own rate, leaving nothing to test")
    tg = group_time(path, tgroup)
    _exclude(data, exclude, frames.label)
    if frame_offsets:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            data = data - np.nanmedian(data, axis=(2, 3), keepdims=True)
    reads = data[:, 1:] - data[:, :1]
    times = tg * np.arange(1, ngroups, dtype=np.float64)
    rates = _rates(reads, times)
    for rate, ramp in zip(rates, reads):  # left out: reads NaN, SCENE 0 (simulated as dark)
        bad = ~np.isfinite(rate) | ~np.all(np.isfinite(ramp), axis=0)
        rate[bad] = 0.0
        np.clip(rate, 0.0, None, out=rate)  # a rate below 0 is noise: the model collects none
        ramp[:, bad] = np.nan
    notes = [frames.meta.get("units_note", ""),
             f"reads: groups 1..{ngroups - 1} less group 0, TGROUP {tg:g} s",
             ("SCENE: each integration's rate is the mean slope of the other "
              f"{nints - 1} (leave one out)") if nints > 1 else
             "SCENE: the integration's own slope (one integration)"]
    if frame_offsets:
        notes.append("each group less its median over the frame (as a reference-pixel step)")
    if exclude:
        notes.append("left out: " + "; ".join(f"rows {a}:{b}, columns {c}:{d}"
                                              for a, b, c, d in exclude))
    if readnoise is None:
        readnoise = measure_read_noise(reads, tg, rates)
        notes.append(f"READNOIS {readnoise:.2f} e- measured on the same increments")
    else:
        readnoise = float(readnoise)
        notes.append(f"READNOIS {readnoise:.2f} e- given")
    if nints > 1:
        scene_vars = list(scene_variance(rates, reads, tg, readnoise))
        factor = 1.0
        notes.append("SCENEVAR: the left-out rate's variance (whitened and simulated: a "
                     "complete model reaches the floor)")
    else:
        scene_vars = None
        factor = expected_gap_factor(1, ngroups - 1)
        notes.append(f"a complete model shows a gap of about {factor:.3f} x its floor "
                     "(the rate is the ramp's own slope)")
    return JwstRamps(path, list(rates), list(reads), tg, readnoise, notes, factor, scene_vars)


def write_jwst_ramps(path, output, gain, tgroup=None, readnoise=None, law="donlon2018",
                     overwrite=False, hdu=None, exclude=None, frame_offsets=False):
    """:func:`jwst_ramps` written as a discovery ramp file ``output`` (one
    pair per integration, ``FIRSTSUB = T``); returns the :class:`JwstRamps`."""
    ramps = jwst_ramps(path, gain, tgroup, readnoise, hdu, exclude, frame_offsets)
    pairs = [(rate, reads, ramps.tgroup) for rate, reads in zip(ramps.rates, ramps.reads)]
    write_ramps(output, pairs, ramps.readnoise, law=law, overwrite=overwrite,
                first_subtracted=True, scene_vars=ramps.scene_vars)
    return ramps


def symmetric_model(model_path, output, overwrite=False):
    """A coupling-model file with its second neighbours along x and y set to
    their mean (all else kept), the symmetric form ``discover`` starts from
    (:meth:`~.model.DetectorModel.from_coupling`); calibrate measures the two
    apart (on the FGS file 0.102 +- 0.111 and 0.000 +- 0.074 of alpha).
    Written through a temporary file; the result is loaded back as a check."""
    with open(model_path) as f:
        doc = json.load(f)
    weights = {(int(dy), int(dx)): float(w) for dy, dx, w in doc.get("geometry", [])}
    second = 0.5 * (weights.get((0, 2), 0.0) + weights.get((2, 0), 0.0))
    for d in ((0, 2), (0, -2), (2, 0), (-2, 0)):
        weights[d] = second
    doc["geometry"] = [[dy, dx, w] for (dy, dx), w in sorted(weights.items()) if w != 0.0]
    with atomic_output(output, overwrite=overwrite) as tmp:
        with open(tmp, "w") as f:
            json.dump(doc, f, indent=2)
    CouplingModel.load(output)
    return output

"""Ramps for the model-discrepancy workflow: read, simulate read by read, and
measure the gap from the time structure (``docs/discover.md``, "Ramps").

A ramp pair (``docs/discovery_format.md``, "Ramps") holds a 3-D MEASURED
``(NREADS, ny, nx)``, electrons, bias and reset removed, read ``i`` at time
``t_i = TFIRST + i TFRAME``, and a SCENE that is the expected collection
*rate*, electrons per second (2-D, ``OVERSAMP`` allowed).

The model read by read (:func:`expected_reads`, :func:`simulate_ramp`)
--------------------------------------------------------------------
The expected collected charge at read ``i`` is the frame model's collection
stage (:meth:`~.model.DetectorModel.collected`: reciprocity, diffusion, dark
charge and brighter-fatter while collecting) of ``SCENE t_i``; a simulation
draws the charge collected between reads as independent Poisson increments
of the expected ones and sums them, so each read holds the shot noise of
everything collected so far. The read-out chain (IPC with its law and
signal-dependent coupling, then the non-linearity) acts on the charge
present at each read; read noise is drawn anew for every read.

The gap from increments (:func:`ramp_gap`)
------------------------------------------
Per pixel the increments ``d_0 = M_0``, ``d_i = M_i - M_{i-1}`` have, under
the model, the means of the expected reads' differences and the covariance

    Var d_0 = s_0 + r,   Var d_i = s_i - s_{i-1} + 2 r,   Cov(d_{i-1}, d_i) = -r

with ``s_i`` the shot variance the model propagates to read ``i`` and ``r``
the read variance (the other terms are zero: shot increments are
independent, each read's noise enters two neighbouring increments with
opposite signs). The increments are whitened by the Cholesky factor of that
covariance, pixel by pixel; the **gap** is the mean square of the whitened
increments over valid pixels and reads (1 for a complete model), the **gap
per read** its mean over pixels at each read (where in time the model
fails: an after-image decays over the first reads, a jump sits at one), and
the **neighbour correlation** the mean product of whitened increments of
horizontal and of vertical neighbours (IPC gives a small positive value the
floor simulations reproduce; read noise shared along rows or columns, or
brighter-fatter's moving boundaries, add to it). The floor is the model
simulated with fresh noise (:func:`ramp_gap` with ``n_sim``). The
**cross-read products** (:data:`~.ramp_cross.CROSS_LAGS`) are the mean products of a
pixel's whitened increment at read ``i`` with its own (``self``) and its
neighbours' (``x``, ``y``, ``diagonal``) at every later read ``j > i``: zero
for independent increments; a pixel whose collection slows with the charge
it holds (brighter-fatter in a flat: ``E ~ I dt a(d)`` per pair) makes them
depart, which the mean square cannot see. Each is compared with its floor
from the same simulations, and a simulation of a model with brighter-fatter
collects each read in steps (:mod:`.ramp_cross`) at the rate its noisy
charge sets (``1 + sum_d a(d) dQ(p + d)``, the kernel of its parameters).

This module names no effect: the search over the ramp vocabulary and the
frame effects read by read is :mod:`.ramp_search` (:mod:`.ramp_effects`,
:mod:`.ramp_chain`); :func:`describe_ramp_misfit` says in words where the
time structure departs from the model.
"""

import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..detector import read_noise
from ..errors import IPCInputError
from ..fitsio import atomic_output
from .diagnostics import fill_scene, near_holes
from .labdata import read_header
from .model import DetectorModel
from .ramp_cross import CROSS_LAGS, bf_kernel_of, collect_reads, cross_products, cross_read_excess
from .sampling import block_sum

__all__ = ["RampPair", "RampData", "RampModel", "whitened", "read_ramps", "write_ramps",
           "is_ramp_file", "with_scene_holes",
           "read_times", "expected_reads", "expected_mean", "increment_factors", "whiten",
           "simulate_ramp", "ramp_gap", "describe_ramp_misfit", "earlier_charge", "released",
           "dark_charge",
           "RAMP_UNEXPLAINED_Z"]

RAMP_UNEXPLAINED_Z = 5.0  # a pattern is described when it stands out at this many sigma
JUMP_P = 1e-4  # a pixel's increments are off the model beyond this chi-square tail
RETURN_Z = 3.0  # an odd pixel goes up and down: increments beyond this many sigma both ways


@dataclass(frozen=True)
class RampPair:
    """One ramp pair: ``rate`` (SCENE, e-/s, 2-D; ``oversample`` its
    ``OVERSAMP``), ``reads`` (MEASURED, e-, ``(NREADS, ny, nx)``) and the
    reads' ``times`` after reset (s); ``first_subtracted`` (``FIRSTSUB``): the
    reads are differences from a read before read 0 that the file does not
    hold (a raw ramp's first read, its bias and reset level in it), so read
    0's increment carries that read's noise too; ``scene_var`` (the
    ``SCENEVAR`` HDU of the same ``EXTVER``, (e-/s)^2, 2-D, or ``None``): the
    variance of a SCENE estimated from data independent of these reads, so
    read ``i`` holds the SCENE's error times ``t_i`` (whitened and simulated
    with the rest); ``holes`` (2-D bool at the reads' shape, or ``None``): the
    pixels near a SCENE pixel that was not finite, left out of the statistics
    (:func:`with_scene_holes`: ``rate`` then holds a filled value there)."""

    extver: int
    rate: np.ndarray
    reads: np.ndarray
    times: np.ndarray
    oversample: int = 1
    first_subtracted: bool = False
    scene_var: object = None
    holes: object = None

    @property
    def valid(self):
        """Pixels finite in SCENE and in every read, away from SCENE's holes."""
        total = block_sum(self.rate, self.oversample)
        valid = np.isfinite(total) & np.all(np.isfinite(self.reads), axis=0)
        return valid if self.holes is None else valid & ~self.holes


def with_scene_holes(rate, oversample):
    """``(rate, holes)``: a SCENE whose non-finite pixels are filled (so the
    model can be simulated: a NaN rate has no Poisson draw) and the pixels
    within 2 of one at the reads' resolution (their expected charge depends
    on the unknown rate through the coupling), as the frames' statistics
    leave them out (:func:`~.diagnostics.valid_mask`); ``holes`` is ``None``
    for a finite SCENE."""
    bad = ~np.isfinite(block_sum(rate, oversample))
    if not bad.any():
        return rate, None
    return fill_scene(rate), near_holes(bad)


@dataclass
class RampData:
    """The ramp pairs of a lab file (:func:`read_ramps`) and its header."""

    path: str
    readnoise: float
    shot_noise: bool
    law: str
    ramps: list

    def model(self):
        """The starting model the file's header describes."""
        return DetectorModel(self.law, self.readnoise, self.shot_noise)


def read_times(header, nreads, label):
    """The reads' times after reset, ``TFIRST + i TFRAME`` (s), from a
    MEASURED header; one-line errors name ``label`` (file and HDU)."""
    if "TFRAME" not in header:
        raise IPCInputError(f"{label}: a 3-D MEASURED (a ramp) needs TFRAME (s between reads)")
    try:
        tframe = float(header["TFRAME"])
        tfirst = float(header.get("TFIRST", tframe))
    except (TypeError, ValueError):
        raise IPCInputError(f"{label}: TFRAME/TFIRST must be numbers (s)") from None
    if not (math.isfinite(tframe) and tframe > 0 and math.isfinite(tfirst) and tfirst > 0):
        raise IPCInputError(f"{label}: TFRAME = {tframe}, TFIRST = {tfirst}: both must be "
                            "finite and > 0 (s)")
    return tfirst + tframe * np.arange(nreads, dtype=np.float64)


def read_ramps(path):
    """The ramp pairs of a lab file (3-D MEASURED; 2-D pairs are left to
    :func:`~.labdata.read_lab`) as :class:`RampData`. One-line errors name
    the file and HDU: no ramp, a missing SCENE, a SCENE that is not 2-D or not
    ``OVERSAMP`` times the reads' shape, fewer than 2 reads, missing ``TFRAME``."""
    from astropy.io import fits

    if not os.path.exists(path):
        raise IPCInputError(f"{path}: no such file")
    with fits.open(path, memmap=False) as hdul:
        readnoise, shot_noise, law = read_header(hdul[0].header, path)
        scenes, ramps, scene_vars = {}, [], {}
        for hdu in hdul[1:]:
            name = str(hdu.header.get("EXTNAME", "")).strip().upper()
            ver = int(hdu.header.get("EXTVER", 1))
            if name == "SCENE" and hdu.data is not None:
                scenes[ver] = (np.asarray(hdu.data, dtype=np.float64),
                               int(hdu.header.get("OVERSAMP", 1)))
            if name == "SCENEVAR" and hdu.data is not None:
                scene_vars[ver] = np.asarray(hdu.data, dtype=np.float64)
        for hdu in hdul[1:]:
            name = str(hdu.header.get("EXTNAME", "")).strip().upper()
            if name != "MEASURED" or hdu.data is None or hdu.data.ndim != 3:
                continue
            ver = int(hdu.header.get("EXTVER", 1))
            label = f"{path}[MEASURED,{ver}]"
            reads = np.asarray(hdu.data, dtype=np.float64)
            first = bool(hdu.header.get("FIRSTSUB", False))
            if reads.shape[0] < (1 if first else 2):
                raise IPCInputError(f"{label}: a ramp needs at least 2 reads (1 with FIRSTSUB"
                                    f" = T), got {reads.shape[0]}")
            if ver not in scenes:
                raise IPCInputError(f"{label}: unpaired: no SCENE HDU with EXTVER={ver}")
            rate, n = scenes[ver]
            if rate.ndim != 2 or rate.shape != (n * reads.shape[1], n * reads.shape[2]):
                raise IPCInputError(f"{path}[SCENE,{ver}]: shape {rate.shape} is not OVERSAMP "
                                    f"= {n} times the reads' {reads.shape[1:]}")
            var = scene_vars.get(ver)
            if var is not None and (n != 1 or var.shape != reads.shape[1:]):
                raise IPCInputError(f"{path}[SCENEVAR,{ver}]: shape {var.shape} is not the "
                                    f"reads' {reads.shape[1:]} (or SCENE has OVERSAMP > 1)")
            rate, holes = with_scene_holes(rate, n)
            ramps.append(RampPair(ver, rate, reads, read_times(hdu.header, len(reads), label),
                                  n, first, var, holes))
    if not ramps:
        raise IPCInputError(f"{path}: no 3-D MEASURED (ramp) HDU")
    return RampData(path, readnoise, shot_noise, law, ramps)


def is_ramp_file(path):
    """Whether a lab file holds a ramp pair (a 3-D MEASURED HDU); ``False``
    for anything unreadable (the frame reader then says why)."""
    from astropy.io import fits

    try:
        with fits.open(path, memmap=False) as hdul:
            return any(str(h.header.get("EXTNAME", "")).strip().upper() == "MEASURED"
                       and h.header.get("NAXIS", 0) == 3 for h in hdul[1:])
    except (OSError, ValueError):
        return False


def write_ramps(path, ramps, readnoise, law="donlon2018", shot_noise=True, overwrite=False,
                first_subtracted=False, scene_vars=None):
    """Write ``ramps`` (``[(rate, reads, tframe), ...]``) as a lab file of ramp
    pairs (``TFIRST = TFRAME``; ``FIRSTSUB`` = ``first_subtracted`` and
    ``scene_vars`` (one 2-D array per pair, or ``None``) a ``SCENEVAR`` HDU per
    pair, see :class:`RampPair`), through a temporary file renamed into place."""
    from astropy.io import fits

    hdus = [fits.PrimaryHDU()]
    hdus[0].header["READNOIS"] = float(readnoise)
    hdus[0].header["SHOTNOIS"] = bool(shot_noise)
    hdus[0].header["IPCLAW"] = str(law)
    for k, (rate, reads, tframe) in enumerate(ramps, start=1):
        scene = fits.ImageHDU(np.asarray(rate, dtype=np.float64), name="SCENE")
        scene.header["EXTVER"] = k
        measured = fits.ImageHDU(np.asarray(reads, dtype=np.float64), name="MEASURED")
        measured.header["EXTVER"] = k
        measured.header["TFRAME"] = float(tframe)
        if first_subtracted:
            measured.header["FIRSTSUB"] = (True, "reads less an earlier read not in the file")
        hdus += [scene, measured]
        if scene_vars is not None and scene_vars[k - 1] is not None:
            var = fits.ImageHDU(np.asarray(scene_vars[k - 1], dtype=np.float64), name="SCENEVAR")
            var.header["EXTVER"] = k
            var.header["BUNIT"] = "(electron/s)**2"
            hdus.append(var)
    with atomic_output(path, overwrite=overwrite) as tmp:
        fits.HDUList(hdus).writeto(tmp)
    return path


def earlier_charge(ramps, k):
    """``E`` of ramp ``k``, electrons per pixel: the earlier exposure an
    after-image releases (``persistence``, :mod:`.ramp_effects`)."""
    source = ramps[k - 1] if k > 0 else ramps[k]
    rate = source.rate
    n = source.oversample
    if n > 1:
        rate = rate.reshape(rate.shape[0] // n, n, rate.shape[1] // n, n).sum(axis=(1, 3))
    return np.nan_to_num(rate) * float(source.times[-1])


def released(params, ramps, k):
    """The persistence charge collected by each read of ramp ``k``,
    ``fraction E (1 - exp(-t_i / tau))``, ``(NREADS, ny, nx)``."""
    t = ramps[k].times
    growth = 1.0 - np.exp(-t / max(float(params["tau_s"]), 1e-6))
    return float(params["fraction"]) * earlier_charge(ramps, k)[None] * growth[:, None, None]


def dark_charge(params, ramps, k):
    """The dark charge collected by each read of ramp ``k``,
    ``dark_rate_e_per_s t_i`` in every pixel, ``(NREADS, ny, nx)``
    (``dark_current`` on ramps, :mod:`.ramp_effects`)."""
    ramp = ramps[k]
    rate = float(params["dark_rate_e_per_s"])
    return np.broadcast_to(rate * ramp.times[:, None, None],
                           (len(ramp.times),) + ramp.valid.shape).copy()


def _charge_scene(ramp):
    """SCENE times each read's time: the expected charge per read if nothing acted."""
    return ramp.rate[None] * ramp.times[:, None, None]


@dataclass(frozen=True)
class RampModel:
    """The frame model read by read (``frame``, a
    :class:`~.model.DetectorModel`) and the effects only ramps show
    (``effects``, ``{name: params}`` of :data:`~.ramp_effects.RAMP_EFFECTS`);
    ``odd`` the pixels a ``random_telegraph_noise`` step gave their own
    levels (``(ny, nx)`` bool, or ``None``)."""

    frame: object
    effects: dict = field(default_factory=dict)
    odd: object = None

    @property
    def shot_noise(self):
        return self.frame.shot_noise

    def read_variance(self):
        """Each read's noise variance per pixel: the frame's plus what rows and
        columns share (``correlated_read_noise``) and the whole frame shares
        (``bias_drift``)."""
        c = self.effects.get("correlated_read_noise", {})
        b = self.effects.get("bias_drift", {})
        return (self.frame.read_variance() + max(c.get("row_variance_e2", 0.0), 0.0)
                + max(c.get("column_variance_e2", 0.0), 0.0)
                + max(b.get("variance_e2", 0.0), 0.0))

    def afterglow(self, ramps, k):
        """The charge the ramp effects add to each read of ramp ``k`` (before
        readout), ``(NREADS, ny, nx)``, or ``None``: persistence's release
        (:func:`released`) and the dark charge (:func:`dark_charge`)."""
        parts = [form(self.effects[name], ramps, k) for name, form in
                 (("persistence", released), ("dark_current", dark_charge))
                 if name in self.effects]
        return sum(parts[1:], parts[0]) if parts else None

    def valid(self, ramp):
        return ramp.valid if self.odd is None else ramp.valid & ~self.odd


def _as_ramp_model(model):
    return model if isinstance(model, RampModel) else RampModel(model)


def _afterglow_read_out(frame, extra):
    """What an after-image ``extra`` adds to the reads, to first order."""
    return frame.readout(extra) - frame.readout(np.zeros_like(extra))


def expected_mean(model, ramp, extra=None):
    """The mean of every read ``(NREADS, ny, nx)`` of :func:`expected_reads`
    alone (no variance propagated: what a fit of the mean evaluates)."""
    frame = _as_ramp_model(model).frame
    mean = frame.expected(_charge_scene(ramp), ramp.oversample)
    return mean if extra is None else mean + _afterglow_read_out(frame, extra)


def expected_reads(model, ramp, extra=None):
    """``(mean, shot variance, read variance)`` of every read (the first two
    ``(NREADS, ny, nx)``): the frame model's prediction of ``SCENE t_i``
    (:meth:`~.model.DetectorModel.predict_parts`) at each read, with
    ``extra`` collected charge per read (an after-image) added before the
    read-out to first order: its coupled value to the mean, itself to the
    shot variance."""
    model = _as_ramp_model(model)
    frame = model.frame
    mean, var, _ = frame.predict_parts(_charge_scene(ramp), ramp.oversample)
    shot = np.clip(var - frame.read_variance(), 0.0, None)
    if extra is not None:
        mean = mean + _afterglow_read_out(frame, extra)
        shot = shot + np.clip(extra, 0.0, None)
    return mean, shot, model.read_variance()


def simulate_ramp(model, ramp, rng, extra=None):
    """A noisy ramp of ``model`` (a seeded ``numpy.random.Generator``): the
    expected collected charge per read (``extra`` added), its increments
    drawn as independent Poisson charges and summed, read out at each read,
    read noise per read, and the offsets rows and columns share at each read
    (``correlated_read_noise``) and the whole frame shares (``bias_drift``)."""
    model = _as_ramp_model(model)
    frame = model.frame
    c = frame.collected(_charge_scene(ramp), ramp.oversample)
    if extra is not None:
        c = c + extra
    charge = collect_reads(c, rng if frame.shot_noise else None, bf_kernel_of(frame))
    n, ny, nx = charge.shape
    m = n + 1 if ramp.first_subtracted else n  # FIRSTSUB: the read subtracted from all
    noise = read_noise((m, ny, nx), math.sqrt(frame.read_variance()), rng)
    shared = model.effects.get("correlated_read_noise", {})
    if shared.get("row_variance_e2", 0.0) > 0:
        noise += rng.normal(0.0, math.sqrt(shared["row_variance_e2"]), (m, ny, 1))
    if shared.get("column_variance_e2", 0.0) > 0:
        columns = rng.normal(0.0, math.sqrt(shared["column_variance_e2"]), (m, 1, nx))
        rho = shared.get("column_lag1", 0.0)  # adjacent columns alike: AR(1) along x
        for x in range(1, nx if rho else 0):
            columns[..., x] = rho * columns[..., x - 1] + math.sqrt(1 - rho * rho) * columns[..., x]
        noise += columns
    drift = model.effects.get("bias_drift", {}).get("variance_e2", 0.0)
    if drift > 0:
        noise += rng.normal(0.0, math.sqrt(drift), (m, 1, 1))
    if ramp.first_subtracted:
        noise = noise[1:] - noise[:1]
    out = frame.readout(charge) + noise
    if ramp.scene_var is not None:  # the SCENE's own error, the same at every read
        error = rng.normal(0.0, 1.0, (ny, nx)) * np.sqrt(np.clip(ramp.scene_var, 0.0, None))
        out += error[None] * ramp.times[:, None, None]
    return out


def increment_factors(reads, mean, shot, r, valid, ramp=None):
    """The increments' covariance of the valid pixels (module docstring) as
    Cholesky factors ``(npix, NREADS, NREADS)``, the residual increments
    ``(NREADS, npix)`` (measured less expected) and their variances
    (``ramp``: its ``first_subtracted`` gives read 0's increment two reads'
    noise, its ``scene_var`` adds ``var dt_i dt_j``; see :class:`RampPair`)."""
    d = np.diff(reads, axis=0, prepend=0.0)[:, valid]
    mu = np.diff(mean, axis=0, prepend=0.0)[:, valid]
    # shot variance only accumulates: a model whose reads fall (a non-linearity
    # at its bound) must not make the covariance indefinite
    var = np.clip(np.diff(shot[:, valid], axis=0, prepend=0.0), 0.0, None) + 2.0 * r
    if ramp is None or not ramp.first_subtracted:
        var[0] -= r  # read 0 follows the reset, which was removed: one read's noise
    n = len(var)
    cov = np.zeros((d.shape[1], n, n))
    idx = np.arange(n)
    cov[:, idx, idx] = np.clip(var, 1e-9, None).T
    cov[:, idx[1:], idx[:-1]] = cov[:, idx[:-1], idx[1:]] = -r
    if ramp is not None and ramp.scene_var is not None:
        dt = np.diff(ramp.times, prepend=0.0)
        x = np.clip(ramp.scene_var[valid], 0.0, None)
        cov += x[:, None, None] * np.outer(dt, dt)
        var = var + dt[:, None] ** 2 * x[None]
    return np.linalg.cholesky(cov), d - mu, var


def whiten(chol, residual):
    """Residual increments ``(NREADS, npix)`` whitened by ``chol``."""
    return np.linalg.solve(chol, residual.T[..., None])[..., 0].T


def _whitened(reads, mean, shot, r, valid, ramp=None):
    """Whitened increments ``(NREADS, npix)`` of the valid pixels (module docstring)."""
    chol, residual, _ = increment_factors(reads, mean, shot, r, valid, ramp)
    return whiten(chol, residual)


def _neighbour_products(w, valid):
    """Mean product of whitened increments of horizontal and vertical neighbours."""
    full = np.full((w.shape[0],) + valid.shape, np.nan)
    full[:, valid] = w
    out = {}
    for axis, (a, b) in (("x", (full[..., :, :-1], full[..., :, 1:])),
                         ("y", (full[..., :-1, :], full[..., 1:, :]))):
        p = a * b
        out[axis] = float(np.nanmean(p))
    return out


def _jumps(w):
    """The pixels whose increments lie off the model at single reads
    (:data:`JUMP_P` chi-square tail of their whitened increments): their
    number, how many would be expected by chance, and how many of them go up
    *and* down by more than :data:`RETURN_Z` sigma (a level that returns: a
    telegraph pixel; one way only: a step such as a cosmic ray)."""
    from scipy.stats import chi2

    per_pixel = np.sum(w * w, axis=0)
    odd = per_pixel > chi2.isf(JUMP_P, w.shape[0])
    both = odd & (w.max(axis=0) > RETURN_Z) & (w.min(axis=0) < -RETURN_Z)
    return int(odd.sum()), JUMP_P * w.shape[1], int(both.sum())


def whitened(model, ramps, k, reads=None):
    """Whitened increments ``(NREADS, npix)`` of ramp ``k`` of ``ramps``
    (``reads`` in place of its MEASURED) under ``model``, and its valid mask."""
    model = _as_ramp_model(model)
    ramp = ramps[k]
    mean, shot, r = expected_reads(model, ramp, model.afterglow(ramps, k))
    valid = model.valid(ramp)
    return _whitened(ramp.reads if reads is None else reads, mean, shot, r, valid, ramp), valid


def _statistics(model, ramps, reads_of):
    """Gap, gap per read, neighbour products, :func:`_jumps`, the number of
    whitened increments of ``reads_of(k)`` (ramp ``k``'s reads) under
    ``model`` and the cross-read products (``{name: (mean, number)}``)."""
    squares, per_read, products, jumps, cross = [], [], [], np.zeros(3), []
    for k in range(len(ramps)):
        w, valid = whitened(model, ramps, k, reads_of(k))
        squares.append((w * w).ravel())
        per_read.append(np.mean(w * w, axis=1))
        products.append(_neighbour_products(w, valid))
        cross.append(cross_products(w, valid))
        jumps += _jumps(w)
    nb = {a: float(np.mean([p[a] for p in products])) for a in ("x", "y")}
    n = sum(s.size for s in squares)
    counts = {name: sum(c[name][1] for c in cross) for name in CROSS_LAGS}
    cross = {name: (sum(c[name][0] * c[name][1] for c in cross) / max(counts[name], 1),
                    counts[name]) for name in CROSS_LAGS}
    return (float(np.mean(np.concatenate(squares))), np.mean(per_read, axis=0), nb,
            tuple(float(j) for j in jumps), n, cross)


def ramp_gap(data, model=None, n_sim=8, seed=0):
    """The gap of a ramp file's pairs under ``model`` (the header's when
    ``None``) and its floor from ``n_sim`` simulations of the model.

    Returns a dict: ``gap``, ``gap_per_read``, ``neighbour_correlation``
    (``{"x", "y"}``), and from the simulations ``gap_floor``,
    ``gap_floor_sigma`` (at least ``sqrt(2 / n)`` for ``n`` whitened
    increments), ``gap_per_read_floor`` (mean, scatter),
    ``neighbour_floor`` (``{axis: (mean, scatter)}``) and ``complete`` (the
    gap within 3 floor scatters of the floor); ``unexplained`` from
    :func:`describe_ramp_misfit` when it is not.
    """
    data = data if isinstance(data, RampData) else read_ramps(data)
    model = _as_ramp_model(model or data.model())
    ramps = data.ramps
    rng = np.random.default_rng(seed)
    gap_now, per_read, nb, jumps, n, cross = _statistics(model, ramps,
                                                         lambda k: ramps[k].reads)
    sims = [_statistics(model, ramps, lambda k: simulate_ramp(
        model, ramps[k], rng, model.afterglow(ramps, k))) for _ in range(int(n_sim))]
    gaps = np.array([s[0] for s in sims])
    reads = np.array([s[1] for s in sims])
    out = {"gap": gap_now, "gap_per_read": per_read.tolist(), "neighbour_correlation": nb,
           "gap_floor": float(gaps.mean()),
           # a mean of n squared unit normals scatters by at least sqrt(2 / n):
           # a few simulations can say less by chance
           "gap_floor_sigma": max(float(gaps.std(ddof=1)), math.sqrt(2.0 / n)),
           "gap_per_read_floor": (reads.mean(axis=0).tolist(), reads.std(axis=0, ddof=1).tolist()),
           # a mean product's scatter is at least that of n independent products
           "neighbour_floor": {a: (float(np.mean([s[2][a] for s in sims])),
                                   max(float(np.std([s[2][a] for s in sims], ddof=1)),
                                       1.0 / math.sqrt(n)))
                               for a in ("x", "y")},
           "odd_pixels": {"count": int(jumps[0]), "expected": jumps[1],
                          "up_and_down": int(jumps[2])},
           "cross_read": {name: v[0] for name, v in cross.items()},
           # as for the neighbour products: at least n independent products' scatter
           "cross_read_floor": {name: (float(np.mean([s[5][name][0] for s in sims])),
                                       max(float(np.std([s[5][name][0] for s in sims],
                                                        ddof=1)),
                                           1.0 / math.sqrt(max(v[1], 1))))
                                for name, v in cross.items()}}
    out["complete"] = bool(abs(gap_now - out["gap_floor"]) <= 3.0 * out["gap_floor_sigma"]
                           and not cross_read_excess(out))
    out["unexplained"] = [] if out["complete"] else describe_ramp_misfit(out)
    return out


def describe_ramp_misfit(stats):
    """Words for where a ramp's time structure departs from the model
    (``stats`` a :func:`ramp_gap` result): the gap per read falling or rising
    with time, a neighbour correlation along x or y beyond the floor's."""
    out = []
    per = np.asarray(stats["gap_per_read"])
    floor, sigma = (np.asarray(a) for a in stats["gap_per_read_floor"])
    z = (per - floor) / np.maximum(sigma, 1e-12)
    bad = z > RAMP_UNEXPLAINED_Z
    if bad.any():
        first, last = int(np.argmax(bad)), int(len(bad) - 1 - np.argmax(bad[::-1]))
        shape = ("falling with time" if per[0] > 2 * per[-1] and bad[0] else
                 "rising with time" if per[-1] > 2 * per[0] and bad[-1] else
                 "at reads " + ", ".join(str(i) for i in np.flatnonzero(bad)))
        out.append(f"increments off the model {shape} (chi-square per increment "
                   f"{per[first]:.2f} at read {first}, {per[last]:.2f} at read {last}; the "
                   f"floor {floor.mean():.2f})" + (
                       ": a signal decaying within the integration (an after-image of earlier "
                       "light, persistence?)" if shape == "falling with time" else ""))
    excess = {}
    for axis in ("x", "y"):
        m, s = stats["neighbour_floor"][axis]
        value = stats["neighbour_correlation"][axis]
        if (value - m) / s > RAMP_UNEXPLAINED_Z:
            excess[axis] = f"{axis} {value:.3f} (the floor {m:.3f} +- {s:.3f})"
    if len(excess) == 1:
        axis = next(iter(excess))
        out.append(f"increments of neighbours correlated beyond the model along {excess[axis]} "
                   f"only: noise shared along {'a row' if axis == 'x' else 'a column'} at each "
                   "read (correlated read noise?)")
    elif excess:
        out.append("increments of neighbours correlated beyond the model along "
                   f"{excess['x']} and {excess['y']}: a misfit shared by neighbouring pixels, "
                   "a signal over areas the model lacks")
    cross = cross_read_excess(stats)
    if cross:
        out.append("increments correlated across reads beyond the model (" + ", ".join(
            f"{name} {stats['cross_read'][name]:.4f}, the floor "
            f"{stats['cross_read_floor'][name][0]:.4f} +- {stats['cross_read_floor'][name][1]:.4f}"
            for name in cross) + "): a pixel's later increments depend on the charge it and "
                   "its neighbours already hold (brighter-fatter?)")
    odd = stats["odd_pixels"]
    if odd["count"] > odd["expected"] + RAMP_UNEXPLAINED_Z * math.sqrt(max(odd["expected"], 1)):
        kind = (f"most of them up and down by more than {RETURN_Z:g} sigma: levels that "
                "jump and return (telegraph pixels?)" if 2 * odd["up_and_down"] > odd["count"]
                else "mostly one way: a step (a cosmic ray?) or a signal the model lacks "
                "at those pixels")
        out.append(f"{odd['count']} pixels whose increments lie off the model at single reads "
                   f"({odd['expected']:.1f} expected by chance), {kind}")
    if not out:
        out.append("an excess spread over reads and pixels without a pattern in time or "
                   "between neighbours")
    return out

"""The effects only ramps show: one record each (:class:`RampEffect`, the
frame vocabulary's :class:`~.record.Effect` with its own fit), all in
:data:`RAMP_EFFECTS`: its fit to a ramp file's increments
(:meth:`RampEffect.fit`, what :func:`~.ramp_search.discover_ramps` tries),
its contradiction and its physical range (``docs/discovery_format.md``,
"Ramps"; the frame vocabulary is :mod:`.effects`).

``persistence``
    ``fraction``, ``tau_s``: charge trapped during earlier light is released
    during this integration at the rate ``fraction E exp(-t / tau) / tau``
    (e-/s), ``E`` the earlier charge of the pixel and ``t`` the time after
    reset: by read ``i`` it has added ``fraction E (1 - exp(-t_i / tau))``
    collected electrons (:func:`~.ramps.released`; coupled and shot-noisy
    like any charge). ``E`` is
    the previous ramp pair's SCENE times its last read's time (the earlier
    exposure of these pixels); for the first pair of a file, its own (the
    same light before this integration, as in a series of lab flats).
    Contradicted by ``fraction <= 0`` (a deficit where light was is not an
    after-image); outside the physical range above ``fraction`` 5 % (HgCdTe
    releases a few tenths of a per cent up to a few per cent of the earlier
    charge) or with ``tau`` above 20 times the integration (a constant rate:
    dark current, not a decay).
``dark_current``
    ``dark_rate_e_per_s``: charge generated in every pixel alike at this rate
    (e-/s), collected like light (coupled, shot-noisy): by read ``i`` it has
    added ``dark_rate_e_per_s t_i`` electrons (:func:`~.ramps.dark_charge`).
    On ramps it is a rate, not the frames' one charge per frame
    (:class:`~.effects.DarkCurrent`, ``dark_e``): what SCENE, the light's
    rate, does not hold. Where SCENE is measured from the ramps themselves
    (``ipc-taichi ramp-file``) it holds the dark current already and the fit
    finds none. Contradicted by a rate ``<= 0``, or when the pixels above the
    median SCENE and those at or under it give rates more than 5 sigma apart
    (an excess that grows with the light: a SCENE scale or gain error);
    outside the physical range above 1000 e-/s.
``correlated_read_noise``
    ``row_variance_e2``, ``column_variance_e2``: at each read an offset
    shared by every pixel of a row (a column), Gaussian of this variance
    (e-^2): the 1/f noise of a readout channel; ``column_lag1`` the
    correlation of adjacent columns' offsets (1/f noise smooth across
    columns; each column's offset follows its neighbour's as an AR(1)
    sequence along x). Contradicted when neither is
    positive, or when the lines with no light on or next to them (by SCENE)
    show under half of it (a misfit of the signal at the sources, e.g. brighter-fatter,
    raises the lines through them only), or when over half of it is an
    offset of the whole frame (``bias_drift``'s: then rows and columns are
    fitted beyond it); outside the physical range when the
    shared RMS exceeds 3 times ``READNOIS`` (a read noise is not several
    times what the detector's own characterisation says, as for
    ``excess_read_noise``).
``bias_drift``
    ``variance_e2``: at each read an offset shared by every pixel of the
    frame, Gaussian of this variance (e-^2): the readout's bias drifting
    from read to read, what reference pixels track and the pipeline's
    reference-pixel step removes (the rows' and columns' offsets of
    ``correlated_read_noise`` are taken beyond it). Contradicted when it is
    not positive, when the dark pixels (SCENE at or under the median) show
    under half of it (a misfit of the signal), or when the frame's means
    summed over each ramp's reads lie more than 5 sigma from 0 (offsets per
    read do not accumulate, a rate does); outside the physical range when
    its RMS exceeds 3 times ``READNOIS``.
``random_telegraph_noise``
    ``fraction``, ``jump_e``: that share of the pixels switches between two
    levels ``jump_e`` apart from read to read; such pixels are given their own
    levels (left out of the gap). Contradicted when the pixels off the model
    do not come back (their large increments all of one sign: a step such as
    a cosmic ray, or a signal the model lacks); outside the physical range
    above 5 % of the pixels (then it is not a few defective pixels).
"""

import math

import numpy as np
from scipy.optimize import minimize_scalar

from .ramps import (
    RAMP_UNEXPLAINED_Z,
    RampModel,
    dark_charge,
    earlier_charge,
    expected_reads,
    increment_factors,
    released,
    whitened,
)
from .record import Effect, Param

__all__ = ["RampEffect", "Persistence", "DarkCurrent", "CorrelatedReadNoise", "BiasDrift",
           "RandomTelegraphNoise", "RAMP_EFFECTS", "ramp_contradiction", "ramp_implausible",
           "RAMP_LIMITS", "DARK_SHARE", "released", "earlier_charge", "dark_charge"]

DARK_SHARE = 0.5  # shared read noise: the dark lines must show this share of it
FRAME_SHARE = 0.5  # rows' and columns' offsets: at most this share of them the frame's


def _cholesky(model, ramps, k):
    """The Cholesky factors of ramp ``k``'s increments (per valid pixel), its
    residual increments, valid mask and increment variances under ``model``
    (with the charge its ramp effects add, :meth:`~.ramps.RampModel.afterglow`)."""
    ramp = ramps[k]
    mean, shot, r = expected_reads(model, ramp, model.afterglow(ramps, k))
    valid = model.valid(ramp)
    chol, d, var = increment_factors(ramp.reads, mean, shot, r, valid, ramp)
    return chol, d, valid, var


def _template_parts(model, ramps, template):
    """Per ramp: the Cholesky factors, the whitened residual increments, the
    read-out of ``template(k)`` (collected charge per unit of the fitted
    strength, ``(ny, nx)``) at the valid pixels, to first order, and the times."""
    parts = []
    for k in range(len(ramps)):
        chol, d, valid, _ = _cholesky(model, ramps, k)
        coupled = model.frame.readout(template(k)[None])[0] - \
            model.frame.readout(np.zeros((1,) + valid.shape))[0]
        w0 = np.linalg.solve(chol, d.T[..., None])[..., 0]
        parts.append((chol, w0, coupled[valid], ramps[k].times))
    return parts


def _template_fit(parts, growth_of, pixels=None):
    """``(strength, delta chi^2, its variance)``: the weighted least-squares
    strength of a charge ``strength x template x growth_of(t)`` collected by
    the reads (:func:`_template_parts`; ``pixels``, one mask per ramp over its
    valid pixels, restricts the fit to them)."""
    num = den = 0.0
    for i, (chol, w0, coupled, t) in enumerate(parts):
        growth = np.diff(growth_of(t), prepend=0.0)
        g = np.linalg.solve(chol, (growth[None, :] * coupled[:, None])[..., None])[..., 0]
        keep = slice(None) if pixels is None else pixels[i]
        num += float(np.sum(w0[keep] * g[keep]))
        den += float(np.sum(g[keep] * g[keep]))
    strength = num / den if den > 0 else 0.0
    return strength, num * strength, (1.0 / den if den > 0 else math.inf)


class RampEffect(Effect):
    """A ramp effect's record: the frame record's fields and judging methods
    (:meth:`contradiction` also takes ``extra``, what its fit returns for
    the gates; :meth:`implausible` also the integration ``duration``, s)
    and its own fit to the increments, the rest of the model fixed."""

    def fit(self, model, ramps, ln_n):
        """``(params, evidence, new model, extra)`` of the effect fitted to
        ``ramps`` beside ``model`` (a :class:`~.ramps.RampModel`), ``extra``
        what the gates need; ``None`` when there is nothing to fit."""
        return None

    def contradiction(self, p, extra=None):
        return None

    def implausible(self, p, readnoise=None, cov=None, duration=None):
        return None

    def added(self, model, params):
        """``model`` with the effect at ``params``."""
        return RampModel(model.frame, {**model.effects, self.name: params}, model.odd)


class Persistence(RampEffect):
    """``fraction``, ``tau_s`` (module docstring); :attr:`limit` the largest
    ``fraction``, :attr:`tau_limit` the longest decay in integrations. The
    fit: :mod:`.ramp_search`, step 2."""

    limit = 0.05
    tau_limit = 20.0

    def fit(self, model, ramps, ln_n):
        parts = _template_parts(model, ramps, lambda k: earlier_charge(ramps, k))

        def solve(tau):
            return _template_fit(parts, lambda t: 1.0 - np.exp(-t / tau))[:2]

        t = ramps[0].times
        duration = float(t[-1])
        step = float(t[1] - t[0]) if len(t) > 1 else float(t[0])  # one read: TFIRST
        grid = np.geomspace(0.25 * step, 40.0 * duration, 24)
        gains = [solve(tau)[1] for tau in grid]
        i = int(np.argmax(gains))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        best = minimize_scalar(lambda x: -solve(math.exp(x))[1],
                               bounds=(math.log(lo), math.log(hi)), method="bounded")
        tau = math.exp(best.x)
        frac, gain = solve(tau)
        params = {"fraction": frac, "tau_s": tau}
        return params, gain - len(self.params) * ln_n, self.added(model, params), None

    def contradiction(self, p, extra=None):
        if p["fraction"] <= 0:
            return (f"a deficit where earlier light was (fraction {p['fraction']:.4g} <= 0) "
                    "is not an after-image")
        return None

    def implausible(self, p, readnoise=None, cov=None, duration=None):
        if p["fraction"] > self.limit:
            return (f"{100 * p['fraction']:.1f} % of the earlier charge released (at "
                    f"most {100 * self.limit:g} % is plausible)")
        if duration is not None and p["tau_s"] > self.tau_limit * duration:
            return (f"a decay time of {p['tau_s']:.3g} s, {p['tau_s'] / duration:.0f} "
                    "integrations: a constant rate (dark current), not a decay")
        return None


class DarkCurrent(RampEffect):
    """``dark_rate_e_per_s`` (module docstring); :attr:`limit` the largest
    rate. The fit: weighted least squares of the rate (the dark charge is
    linear in it), returning as ``extra`` how many sigma apart the rates
    fitted to the pixels at or under the median SCENE and to those above it
    lie (``None`` with under 8 pixels in either)."""

    limit = 1000.0

    def fit(self, model, ramps, ln_n):
        parts = _template_parts(model, ramps, lambda k: np.ones(ramps[k].valid.shape))
        rate, gain, _ = _template_fit(parts, lambda t: t)
        dark = []
        for ramp in ramps:
            light = earlier_charge([ramp], 0)[model.valid(ramp)]
            dark.append(light <= np.median(light))
        apart = None
        if min(sum(int(d.sum()) for d in dark), sum(int((~d).sum()) for d in dark)) >= 8:
            low, _, v_low = _template_fit(parts, lambda t: t, dark)
            high, _, v_high = _template_fit(parts, lambda t: t, [~d for d in dark])
            apart = (high - low) / math.sqrt(v_low + v_high)
        params = {"dark_rate_e_per_s": rate}
        return params, gain - len(self.params) * ln_n, self.added(model, params), apart

    def contradiction(self, p, extra=None):
        if p["dark_rate_e_per_s"] <= 0:
            return (f"a negative rate ({p['dark_rate_e_per_s']:.4g} e-/s): the reads "
                    "collect less than SCENE, not more")
        if extra is not None and abs(extra) > RAMP_UNEXPLAINED_Z:
            return (f"the pixels with more light than the median show a rate {extra:+.1f} "
                    "sigma from those with less: a rate that depends on the light (a SCENE "
                    "scale or gain error), not charge every pixel generates alike")
        return None

    def implausible(self, p, readnoise=None, cov=None, duration=None):
        if p["dark_rate_e_per_s"] > self.limit:
            return (f"{p['dark_rate_e_per_s']:.4g} e-/s in every pixel (at most "
                    f"{self.limit:g} e-/s is a working detector's dark current)")
        return None


def _line_means(model, ramps, axis):
    """The means over each row (``axis`` 2) or column (1) of the increments'
    residuals after read 0 (from read 0 where the first read was subtracted),
    their variances from the pixels' own noise, and whether each line and its
    two neighbours are dark (SCENE at or under the lines' median); the
    means less the frame's at each read (what the whole frame shares is
    ``bias_drift``'s); and the products of those of adjacent lines."""
    means, variances, light, beyond, pairs = [], [], [], [], []
    for k in range(len(ramps)):
        _, d, valid, var = _cholesky(model, ramps, k)
        full = np.zeros((d.shape[0],) + valid.shape)
        vfull = np.zeros_like(full)
        full[:, valid], vfull[:, valid] = d, var
        count = valid.sum(axis=axis - 1 if axis == 2 else 0)
        ok = count > 1
        m = full.sum(axis=axis)[:, ok] / count[ok]
        v = vfull.sum(axis=axis)[:, ok] / count[ok] ** 2
        # less the frame's mean at each read (``bias_drift``'s), rescaled so
        # that a line's share keeps its variance (1 - 1 / lines of it is lost)
        lines = int(ok.sum())
        mb = m if lines < 2 else (m - full.sum(axis=(1, 2))[:, None] / count.sum()) * math.sqrt(
            lines / (lines - 1))
        # read 0 holds one offset, the others two (and read 0 too when FIRSTSUB)
        first = 0 if ramps[k].first_subtracted else 1
        means.append(m[first:].ravel())
        beyond.append(mb[first:].ravel())
        pairs.append((mb[first:, :-1] * mb[first:, 1:]).ravel())
        variances.append(v[first:].ravel())
        lit = np.nan_to_num(earlier_charge([ramps[k]], 0)).sum(axis=axis - 1)
        # a line and its two neighbours: a misfit at a source reaches the next line
        near = np.maximum(lit, np.maximum(np.roll(lit, 1), np.roll(lit, -1)))
        light.append(np.broadcast_to(near <= np.median(lit), (len(m),) + lit.shape)
                     [first:][:, ok].ravel())
    return tuple(np.concatenate(a) for a in (means, variances, light, beyond, pairs))


class CorrelatedReadNoise(RampEffect):
    """``row_variance_e2``, ``column_variance_e2`` (module docstring);
    :attr:`limit` the largest shared RMS in ``READNOIS``. The fit
    (:mod:`.ramp_search`, step 2) returns as ``extra`` ``(dark share, frame
    share)``: for the direction with the larger variance, its estimate from
    the dark lines over that from all, ``None`` with under 8 of them (a read
    noise is the same where no light falls); and the share of the two
    variances that goes when each line's mean is taken less the frame's
    (``None`` once ``bias_drift`` is in the model: then the lines' means are
    always taken so). ``column_lag1``: the correlation of adjacent columns'
    offsets, from the lag-1 covariance of the columns' means (less the
    frame's) over twice their shared variance (:meth:`_lag`); not tested by
    the gap (it moves no pixel's variance), it sets the simulated neighbour
    correlation along x. The model keeps only the positive variances."""

    limit = 3.0
    lag_limit = 0.95  # the model's adjacent columns' correlation, at most this

    def fit(self, model, ramps, ln_n):
        drift = "bias_drift" in model.effects
        params, gain, dark, beyond = {}, 0.0, {}, 0.0
        for key, axis in (("row_variance_e2", 2), ("column_variance_e2", 1)):
            m, v, low, mb, pairs = _line_means(model, ramps, axis)
            if drift:
                m = mb
            q, line_gain = _shared_variance(m, v)
            params[key] = q
            dark[key] = (float(np.mean(m[low] ** 2 - v[low]) / 2.0) / q
                         if q > 0 and low.sum() >= 8 else None)
            gain += line_gain
            q_beyond = max(_shared_variance(mb, v)[0], 0.0)
            beyond += q_beyond
        params["column_lag1"] = self._lag(pairs, q_beyond)  # the loop ended on the columns
        main = max(("row_variance_e2", "column_variance_e2"), key=params.get)
        kept = {key: max(v, 0.0) for key, v in params.items()}
        kept["column_lag1"] = params["column_lag1"]
        shared = kept["row_variance_e2"] + kept["column_variance_e2"]
        frame = None if drift or shared <= 0 else 1.0 - beyond / shared
        return (params, gain - len(self.params) * ln_n, self.added(model, kept),
                (dark[main], frame))

    def _lag(self, pairs, q):
        """Adjacent columns' offsets alike: the lag-1 covariance of the
        columns' means, ``2 q rho``, where it stands out at 5 sigma (else 0),
        within :attr:`lag_limit`."""
        if q <= 0 or pairs.size < 2:
            return 0.0
        mean = float(np.mean(pairs))
        if abs(mean) * math.sqrt(pairs.size) < RAMP_UNEXPLAINED_Z * float(np.std(pairs)):
            return 0.0
        return min(max(mean / (2.0 * q), -self.lag_limit), self.lag_limit)

    def contradiction(self, p, extra=None):
        if max(p["row_variance_e2"], p["column_variance_e2"]) <= 0:
            return "rows and columns share less noise than independent pixels would"
        extra, frame = extra if isinstance(extra, tuple) else (extra, None)
        if frame is not None and frame > FRAME_SHARE:
            return (f"{100 * frame:.0f} % of what the lines share at a read is shared by the "
                    "whole frame: an offset of the frame (bias_drift), not of rows or columns")
        if extra is not None and extra < DARK_SHARE:
            return (f"the lines share it where light falls, not where none does (the lines "
                    f"with no light on or next to them show {100 * extra:.0f} % of it): a "
                    "misfit of the signal, not read noise")
        return None

    def implausible(self, p, readnoise=None, cov=None, duration=None):
        shared = math.sqrt(max(p["row_variance_e2"], 0.0) + max(p["column_variance_e2"], 0.0))
        if readnoise and shared > self.limit * readnoise:
            return (f"{shared:.1f} e- shared by rows and columns, "
                    f"{shared / readnoise:.1f} times READNOIS")
        return None


def _frame_means(model, ramps):
    """Per read (after read 0, from read 0 where the first read was
    subtracted, as :func:`_line_means`), of every ramp: the mean over the
    valid pixels of the increments' residuals and its variance from the
    pixels' own noise and the rows' and columns' shared offsets
    (``correlated_read_noise`` in ``model``); the same over the dark pixels
    (SCENE at or under the median); and per ramp the sum of the means with
    its variance without a drift (``drift`` 0) and per unit of it."""
    c = model.effects.get("correlated_read_noise", {})
    out = {key: [] for key in ("m", "v", "dark", "v_dark", "sums")}
    for k, ramp in enumerate(ramps):
        _, d, valid, var = _cholesky(model, ramps, k)
        first = 0 if ramp.first_subtracted else 1
        ny, nx = valid.shape
        lines = 2.0 * (max(c.get("row_variance_e2", 0.0), 0.0) / ny
                       + max(c.get("column_variance_e2", 0.0), 0.0) / nx)
        light = earlier_charge([ramp], 0)[valid]
        dark = light <= np.median(light)
        m = d[first:].mean(axis=1)
        v = var[first:].sum(axis=1) / d.shape[1] ** 2 + lines
        out["m"].append(m)
        out["v"].append(v)
        out["dark"].append(d[first:, dark].mean(axis=1))
        out["v_dark"].append(var[first:, dark].sum(axis=1) / max(int(dark.sum()), 1) ** 2 + lines)
        # the offsets of neighbouring increments cancel: the sum holds two
        out["sums"].append((float(m.sum()), float(v.sum()), 2.0))
    return {key: (np.concatenate(val) if key != "sums" else val) for key, val in out.items()}


def _shared_variance(m, v):
    """The moment estimate ``q`` of a variance shared by ``m`` (means whose
    own noise is ``v``, a shared offset entering each twice: ``2 q``) and
    the Gaussian deviance of ``m`` with and without it (0 when ``q <= 0``)."""
    q = float(np.mean(m * m - v) / 2.0)
    gain = (float(np.sum(m * m / v - m * m / (v + 2 * q) - np.log((v + 2 * q) / v)))
            if q > 0 else 0.0)
    return q, gain


class BiasDrift(RampEffect):
    """``variance_e2`` (module docstring); :attr:`limit` its RMS in
    ``READNOIS``. The fit (:mod:`.ramp_search`, step 2): the means over the
    frame of the increments' residuals, read by read (:func:`_frame_means`),
    their variance beyond the pixels' own noise ``2 q``
    (:func:`_shared_variance`); returns as ``extra`` ``(dark share, z)``:
    the estimate from the dark pixels alone over that from all (``None``
    when ``q <= 0``), and how many sigma from 0 the sums of each ramp's
    means lie (offsets per read do not accumulate; a rate does)."""

    limit = 3.0

    def fit(self, model, ramps, ln_n):
        f = _frame_means(model, ramps)
        q, gain = _shared_variance(f["m"], f["v"])
        share = (float(np.mean(f["dark"] ** 2 - f["v_dark"]) / 2.0) / q) if q > 0 else None
        total = sum(s for s, _, _ in f["sums"])
        spread = sum(v + n * max(q, 0.0) for _, v, n in f["sums"])
        params = {"variance_e2": q}
        kept = {"variance_e2": max(q, 0.0)}
        return (params, gain - len(self.params) * ln_n, self.added(model, kept),
                (share, total / math.sqrt(spread)))

    def contradiction(self, p, extra=None):
        if p["variance_e2"] <= 0:
            return "the frames' means scatter less than independent pixels would"
        share, z = extra if extra is not None else (None, 0.0)
        if share is not None and share < DARK_SHARE:
            return (f"the frame's offsets are where light falls, not where none does (the "
                    f"dark pixels show {100 * share:.0f} % of it): a misfit of the signal")
        if abs(z) > RAMP_UNEXPLAINED_Z:
            return (f"the frame's means keep one sign over the reads ({z:+.1f} sigma): a rate "
                    "(dark current, a SCENE error), not an offset per read")
        return None

    def implausible(self, p, readnoise=None, cov=None, duration=None):
        rms = math.sqrt(max(p["variance_e2"], 0.0))
        if readnoise and rms > self.limit * readnoise:
            return f"{rms:.1f} e- shared by the frame, {rms / readnoise:.1f} times READNOIS"
        return None


class RandomTelegraphNoise(RampEffect):
    """``fraction``, ``jump_e`` (module docstring); :attr:`limit` the largest
    share of the pixels. The fit (:mod:`.ramp_search`, step 2; ``None`` when
    chance gives as many odd pixels) returns as ``extra`` the share of them
    going both ways beyond 3 sigma."""

    limit = 0.05

    def fit(self, model, ramps, ln_n):
        from scipy.stats import chi2, norm, poisson

        odd = np.zeros(ramps[0].valid.shape, dtype=bool)
        excess, jumps, both, total = 0.0, [], 0, 0
        for k in range(len(ramps)):
            w, valid = whitened(model, ramps, k)
            per_pixel = np.sum(w * w, axis=0)
            flag = per_pixel > chi2.isf(1e-4, w.shape[0])
            idx = np.argwhere(valid)[flag]
            odd[tuple(idx.T)] = True
            excess += float(np.sum(per_pixel[flag] - w.shape[0]))
            both += int(np.sum((w.max(axis=0) > 3.0) & (w.min(axis=0) < -3.0) & flag))
            _, d, _, _ = _cholesky(model, ramps, k)
            jumps += list(np.max(np.abs(d[:, flag]), axis=0))
            total += int(valid.sum())
        count, chance = int(odd.sum()), 1e-4 * total
        if poisson.sf(count - 1, chance) > norm.sf(RAMP_UNEXPLAINED_Z):  # chance gives as many
            return None
        params = {"fraction": count / total, "jump_e": float(np.median(jumps))}
        newer = RampModel(model.frame, {**model.effects, self.name: params},
                          odd if model.odd is None else model.odd | odd)
        return params, excess - count * ln_n, newer, both / max(len(jumps), 1)

    def contradiction(self, p, extra=None):
        if extra is not None and extra <= 0.5:
            return (f"only {100 * extra:.0f} % of the pixels off the model jump both ways: "
                    "steps that do not return (a cosmic ray, or a signal the model lacks)")
        return None

    def implausible(self, p, readnoise=None, cov=None, duration=None):
        if p["fraction"] > self.limit:
            return (f"{100 * p['fraction']:.1f} % of the pixels (at most "
                    f"{100 * self.limit:g} % are a few defective pixels)")
        return None


RAMP_EFFECTS = {e.name: e for e in (
    Persistence("persistence", "collection",
                (Param("fraction", 0.0, -0.05, 0.2, 0.002), Param("tau_s", 10.0, 0.01, 1e5, 1.0)),
                "a signal left by an earlier exposure that decays during this one"),
    DarkCurrent("dark_current", "collection",
                (Param("dark_rate_e_per_s", 0.0, -1e4, 1e5, 1.0),),
                "charge generated at a uniform rate in every pixel, collected like light"),
    CorrelatedReadNoise("correlated_read_noise", "variance",
                        (Param("row_variance_e2", 0.0, -1e4, 1e5, 1.0),
                         Param("column_variance_e2", 0.0, -1e4, 1e5, 1.0),
                         Param("column_lag1", 0.0, -1.0, 1.0, 0.05)),
                        "read noise shared between the pixels of a row or a column"),
    BiasDrift("bias_drift", "variance",
              (Param("variance_e2", 0.0, -1e4, 1e5, 1.0),),
              "an offset at each read shared by every pixel of the frame"),
    RandomTelegraphNoise("random_telegraph_noise", "pixels",
                         (Param("fraction", 0.0, 0.0, 1.0, 1e-3),
                          Param("jump_e", 0.0, -1e5, 1e5, 1.0)),
                         "pixels whose signal jumps between two levels from read to read"),
)}

# persistence: at most this fraction of the earlier charge, a decay at most this
# many integrations long; shared read noise at most this many READNOIS; telegraph
# pixels at most this share of the pixels (the records' limits)
RAMP_LIMITS = {**{e.name: e.limit for e in RAMP_EFFECTS.values()},
               "persistence_tau": Persistence.tau_limit}


def ramp_contradiction(name, params, extra=None):
    """Why ``params`` contradict ramp effect ``name``, or ``None``. ``extra``:
    for telegraph noise the share of its pixels whose increments go both
    ways, for shared read noise the share of it the dark lines show (a read
    noise is the same where no light falls) or that pair with the share the
    whole frame holds, for the bias drift ``(dark share, z of the sums)``."""
    return RAMP_EFFECTS[name].contradiction(params, extra)


def ramp_implausible(name, params, readnoise, duration):
    """Why ``params`` lie outside the physical range of ramp effect ``name``
    (:data:`RAMP_LIMITS`; ``duration`` the integration, s), or ``None``."""
    return RAMP_EFFECTS[name].implausible(params, readnoise, duration=duration)

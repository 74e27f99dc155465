"""Name what a ramp file's time structure shows and the frame model lacks:
``persistence``, ``correlated_read_noise``, ``random_telegraph_noise``
(:mod:`.ramp_effects`) and the frame effects ``brighter_fatter``,
``signal_dependent_ipc``, ``classical_nonlinearity`` evaluated read by read
(:mod:`.ramp_chain`), on top of the frame model read by read (:mod:`.ramps`).

Procedure (:func:`discover_ramps`)
----------------------------------
1. The starting model (the header's, or ``start``) and its gap from the
   whitened increments with its floor (:func:`~.ramps.ramp_gap`).
2. Each ramp effect not in the model is fitted to the increments, the rest
   of the model fixed:

   - ``persistence``: ``tau`` scanned on a geometric grid (then refined),
     ``fraction`` by weighted least squares at each ``tau`` (the after-image
     is linear in it), the increments whitened by the current model's
     covariance; evidence ``delta chi^2 - 2 ln n``.
   - ``correlated_read_noise``: the means over each row (column) of the
     increments' residuals, read by read; their variance beyond what the
     pixels' own noise gives, ``2 q`` (a shared offset enters two
     increments), is the moment estimate of ``q``; evidence the Gaussian
     deviance of those means with and without ``q``, less ``ln n`` per
     variance.
   - ``random_telegraph_noise``: the pixels whose whitened increments lie
     in the ``1e-4`` chi-square tail, when chance (Poisson) gives as many
     with a probability under that of 5 sigma; each is given its own
     levels (one parameter per pixel), evidence its chi-square excess over
     its degrees of freedom less
     ``ln n`` per pixel; ``jump_e`` the median of their largest departures.
   - ``brighter_fatter``, ``signal_dependent_ipc`` (on a constant starting
     law), ``classical_nonlinearity``: least squares of the whitened
     increments (:func:`~.ramp_chain.fit_frame_effect`), evidence
     ``delta chi^2 - k ln n``; their contradictions and ranges are the
     frame vocabulary's, and brighter-fatter and signal-dependent IPC are
     judged against each other (:func:`~.ramp_chain.rival_contradiction`).

3. A candidate is named when its evidence passes the threshold (25), its fit
   does not contradict the effect and lies inside its physical range
   (:func:`~.ramp_effects.ramp_contradiction`,
   :func:`~.ramp_effects.ramp_implausible`), and once added it removes at
   least 25 % of the gap's excess over the floor and does not leave the gap
   more than 3 floor scatters below its floor (the frames' rules). The
   strongest such one is added; the search repeats until the gap lies within
   3 floor scatters of the floor or nothing qualifies.

The other frame effects (diffusion, geometry terms, reciprocity...) are not
searched on ramps: a ramp file's starting model carries them from a
coupling-model file (``start``) or not at all.
"""

import math

import numpy as np
from scipy.optimize import minimize_scalar

from ..model import CouplingModel
from .effects import contradiction, implausible
from .model import DetectorModel
from .ramp_chain import fit_frame_effect, offered, rival_contradiction
from .ramp_effects import (
    RAMP_EFFECTS,
    earlier_charge,
    ramp_contradiction,
    ramp_implausible,
)
from .ramps import (
    RAMP_UNEXPLAINED_Z,
    RampData,
    RampModel,
    expected_reads,
    increment_factors,
    ramp_gap,
    read_ramps,
    whitened,
)

__all__ = ["discover_ramps", "fit_ramp_effect"]

THRESHOLD = 25.0  # delta BIC, as for frames
MIN_EXPLAINED_FRACTION = 0.25


def _cholesky(model, ramps, k):
    """The Cholesky factors of ramp ``k``'s increments (per valid pixel), its
    residual increments, valid mask and increment variances under ``model``
    (no after-image)."""
    ramp = ramps[k]
    mean, shot, r = expected_reads(model, ramp)
    valid = model.valid(ramp)
    chol, d, var = increment_factors(ramp.reads, mean, shot, r, valid, ramp)
    return chol, d, valid, var


def _fit_persistence(model, ramps):
    """``(params, delta chi^2)`` of the after-image (module docstring)."""
    parts = []
    for k in range(len(ramps)):
        chol, d, valid, _ = _cholesky(model, ramps, k)
        coupled = model.frame.readout(earlier_charge(ramps, k)[None])[0] - \
            model.frame.readout(np.zeros((1,) + valid.shape))[0]
        w0 = np.linalg.solve(chol, d.T[..., None])[..., 0]
        parts.append((chol, w0, coupled[valid], ramps[k].times))

    def solve(tau):
        num = den = base = 0.0
        for chol, w0, coupled, t in parts:
            growth = np.diff(1.0 - np.exp(-t / tau), prepend=0.0)
            g = np.linalg.solve(chol, (growth[None, :] * coupled[:, None])[..., None])[..., 0]
            num += float(np.sum(w0 * g))
            den += float(np.sum(g * g))
            base += float(np.sum(w0 * w0))
        frac = num / den if den > 0 else 0.0
        return frac, base - (base - num * frac)

    t = ramps[0].times
    duration = float(t[-1])
    step = float(t[1] - t[0]) if len(t) > 1 else float(t[0])  # one read: TFIRST
    grid = np.geomspace(0.25 * step, 40.0 * duration, 24)
    gains = [solve(tau)[1] for tau in grid]
    i = int(np.argmax(gains))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    best = minimize_scalar(lambda x: -solve(math.exp(x))[1], bounds=(math.log(lo), math.log(hi)),
                           method="bounded")
    tau = math.exp(best.x)
    frac, gain = solve(tau)
    return {"fraction": frac, "tau_s": tau}, gain


def _fit_shared_noise(model, ramps):
    """``(params, delta deviance, dark share)`` of noise shared by rows and by
    columns; the dark share is, for the direction with the larger variance,
    its estimate from the dark lines (a line and its two neighbours at or
    under the median of the lines' SCENE) over the estimate from all, ``None``
    with under 8 of them: a read noise is the same where no light falls."""
    params, gain, dark = {}, 0.0, {}
    for key, axis in (("row_variance_e2", 2), ("column_variance_e2", 1)):
        means, variances, light = [], [], []
        for k in range(len(ramps)):
            _, d, valid, var = _cholesky(model, ramps, k)
            full = np.zeros((d.shape[0],) + valid.shape)
            vfull = np.zeros_like(full)
            full[:, valid], vfull[:, valid] = d, var
            count = valid.sum(axis=axis - 1 if axis == 2 else 0)
            ok = count > 1
            m = full.sum(axis=axis)[:, ok] / count[ok]
            v = vfull.sum(axis=axis)[:, ok] / count[ok] ** 2
            # read 0 holds one offset, the others two (and read 0 too when FIRSTSUB)
            first = 0 if ramps[k].first_subtracted else 1
            means.append(m[first:].ravel())
            variances.append(v[first:].ravel())
            lit = np.nan_to_num(earlier_charge([ramps[k]], 0)).sum(axis=axis - 1)
            # a line and its two neighbours: a misfit at a source reaches the next line
            near = np.maximum(lit, np.maximum(np.roll(lit, 1), np.roll(lit, -1)))
            light.append(np.broadcast_to(near <= np.median(lit), (len(m),) + lit.shape)
                         [first:][:, ok].ravel())
        m, v, low = np.concatenate(means), np.concatenate(variances), np.concatenate(light)
        q = float(np.mean(m * m - v) / 2.0)
        params[key] = q
        dark[key] = (float(np.mean(m[low] ** 2 - v[low]) / 2.0) / q
                     if q > 0 and low.sum() >= 8 else None)
        if q > 0:
            gain += float(np.sum(m * m / v - m * m / (v + 2 * q) - np.log((v + 2 * q) / v)))
    main = max(params, key=params.get)
    return params, gain, dark[main]


def _fit_telegraph(model, ramps):
    """``(params, delta chi^2 less the per-pixel penalty, odd pixels, share
    going both ways)`` of telegraph pixels; ``None`` when no more pixels lie
    off the model than chance gives."""
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
    return params, excess, odd, both / max(len(jumps), 1)


def fit_ramp_effect(name, model, ramps, ln_n):
    """One ramp effect fitted to ``ramps`` beside ``model``: ``(params,
    evidence, new model, extra)`` with ``extra`` what the gates need; ``None``
    when there is nothing to fit."""
    if name == "persistence":
        params, gain = _fit_persistence(model, ramps)
        k = 2
    elif name == "correlated_read_noise":
        params, gain, dark = _fit_shared_noise(model, ramps)
        k = 2
    else:
        found = _fit_telegraph(model, ramps)
        if found is None:
            return None
        params, gain, odd, both = found
        newer = RampModel(model.frame, {**model.effects, name: params},
                          odd if model.odd is None else model.odd | odd)
        return params, gain - int(odd.sum()) * ln_n, newer, both
    kept = {key: max(v, 0.0) for key, v in params.items()} if name == "correlated_read_noise" \
        else params
    newer = RampModel(model.frame, {**model.effects, name: kept}, model.odd)
    return params, gain - k * ln_n, newer, dark if name == "correlated_read_noise" else None


def _trials(model, ramps, data, ln_n, threshold, refused, say):
    """Every effect not in ``model`` fitted beside it: ``{name: (evidence,
    params, new model)}`` of those no gate refuses (refusals of candidates
    above ``threshold`` go into ``refused``, with why)."""
    duration = float(ramps[0].times[-1])
    fitted = {}
    for name in RAMP_EFFECTS:
        if name in model.effects:
            continue
        found = fit_ramp_effect(name, model, ramps, ln_n)
        if found is not None:
            params, evidence, newer, extra = found
            fitted[name] = (evidence, params, newer, ramp_contradiction(name, params, extra)
                            or ramp_implausible(name, params, data.readnoise, duration))
    for name in offered(model):
        params, evidence, newer, _ = fit_frame_effect(name, model, ramps, ln_n)
        fitted[name] = (evidence, params, newer, contradiction(name, params)
                        or implausible(name, params, data.readnoise))
    evidence = {name: f[0] for name, f in fitted.items()}
    trials = {}
    for name, (ev, params, newer, why) in fitted.items():
        why = why or (rival_contradiction(name, evidence, threshold) if ev > threshold
                      else None)
        say(f"candidate {name}: delta BIC {ev:.1f} {params}" + (f" ({why})" if why else ""))
        if why:
            if ev > threshold:
                refused[name] = why
            continue
        trials[name] = (ev, params, newer)
    return trials


_TIME_KEYS = ("gap", "gap_per_read", "neighbour_correlation", "gap_per_read_floor",
              "neighbour_floor")  # kept for the baseline and each step (the figures)


def _verdict(stats):
    return {key: stats[key] for key in ("gap", "gap_floor", "gap_floor_sigma", "complete")}


def _starting_model(data, start):
    """The frame model read by read: the header's, a
    :class:`~.model.DetectorModel`, or a coupling-model file's
    (:meth:`~.model.DetectorModel.from_coupling`, its measured sections included)."""
    if start is None:
        return data.model()
    if isinstance(start, DetectorModel):
        return start
    coupling, document = CouplingModel.load(start, with_document=True)
    return DetectorModel.from_coupling(coupling, data.readnoise, data.shot_noise, document)


def discover_ramps(data, seed=0, n_sim=8, threshold=THRESHOLD, max_steps=3, start=None,
                   log=None):
    """Find the ramp effects missing from the starting model of a ramp file
    (module docstring); ``start`` replaces the header's model
    (:func:`_starting_model`). Returns the report (``docs/discovery_format.md``):
    ``baseline_gap``, ``gap_floor``, ``gap_floor_sigma``, ``steps``,
    ``missing_effects``, ``final_gap``, ``complete``, ``unexplained``, and
    ``not_named`` (the fitted candidates refused, with why)."""
    data = data if isinstance(data, RampData) else read_ramps(data)
    say = log or (lambda line: None)
    model = RampModel(_starting_model(data, start))
    ramps = data.ramps
    stats = ramp_gap(data, model, n_sim, seed)
    baseline, steps, refused = stats["gap"], [], {}
    first = {key: stats[key] for key in _TIME_KEYS}
    ln_n = math.log(sum(r.valid.sum() * len(r.times) for r in ramps))
    while not stats["complete"] and len(steps) < max_steps:
        trials = _trials(model, ramps, data, ln_n, threshold, refused, say)
        best = max(trials, key=lambda n: trials[n][0], default=None)
        if best is None or trials[best][0] <= threshold:
            break
        evidence, params, newer = trials[best]
        after = ramp_gap(data, newer, n_sim, seed + len(steps) + 1)
        excess = stats["gap"] - stats["gap_floor"]
        fraction = (stats["gap"] - after["gap"]) / excess if excess > 0 else None
        if excess > 3 * stats["gap_floor_sigma"] and (fraction or 0) < MIN_EXPLAINED_FRACTION:
            refused[best] = f"it would remove only {100 * (fraction or 0):.1f} % of the excess"
            break
        below = (after["gap_floor"] - after["gap"]) / max(after["gap_floor_sigma"], 1e-12)
        if below > 3.0:  # the frames' rule: a variance inflated to absorb a wrong mean
            refused[best] = (f"it would leave the gap {below:.1f} floor scatters below its "
                             "floor: a variance inflated to absorb a mis-modelled mean")
            break
        steps.append({"effect": best, "params": params, "evidence": evidence,
                      "evidence_kind": "delta_BIC", "gap_before": stats["gap"],
                      "gap_after": after["gap"], "explained_fraction": fraction,
                      "floor_before": stats["gap_floor"],
                      **{key: after[key] for key in _TIME_KEYS}})
        say(f"added {best}: gap {stats['gap']:.4f} -> {after['gap']:.4f}")
        model, stats = newer, after
    unexplained = [] if stats["complete"] else stats["unexplained"] + [
        f"not named {n}: {why}" for n, why in refused.items()]
    return {"input": data.path, "baseline_gap": baseline, "gap_floor": stats["gap_floor"],
            "gap_floor_sigma": stats["gap_floor_sigma"], "steps": steps,
            "missing_effects": [s["effect"] for s in steps], "final_gap": stats["gap"],
            "complete": stats["complete"], "unexplained": unexplained,
            "not_named": refused, "gap_per_read": stats["gap_per_read"],
            "neighbour_correlation": stats["neighbour_correlation"],
            "gap_per_read_floor": stats["gap_per_read_floor"],
            "neighbour_floor": stats["neighbour_floor"],
            "baseline": first,
            "final_model": {"frame": model.frame.describe(), "effects": model.effects,
                            "own_level_pixels": 0 if model.odd is None
                            else int(model.odd.sum())}}

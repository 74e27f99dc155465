"""Name the missing effect: fit each candidate, weigh the evidence, add, repeat.

Procedure (:func:`discover`)
----------------------------
1. Start from the model the file's header describes (law ``IPCLAW``, read
   noise, shot noise, nothing else) and compute the baseline gap.
2. For every effect of the vocabulary not yet in the model, fit its
   parameters starting "off", the rest of the model fixed except the
   parameters of effects already in the model that are near-degenerate with
   it (:data:`~.effects.DEGENERATE`: diffusion and brighter-fatter,
   anisotropy and diagonal coupling, ...), which are refitted jointly.
   Effects that change the mean are fitted by least squares with the
   current model's variance held fixed; effects that change only the noise
   (``flat_field``, ``excess_read_noise``) by the Gaussian likelihood with
   the mean held fixed, with the response map's correlation between the
   pairs of a file written out exactly (:func:`deviance`). Evidence:
   ``delta BIC = -2 delta lnL - k ln n`` (``k`` new parameters, ``n`` valid
   pixels). ``signal_dependent_ipc`` is a candidate only while the law is
   constant.
3. A candidate can be named only if its fit does not contradict the
   effect's meaning (:func:`~.effects.contradiction`; a noise effect also
   needs residuals of zero mean where it adds variance), and, for
   ``anisotropic_ipc`` and ``signal_dependent_ipc``, its own signature is
   significant at 5 sigma. ``misregistration`` goes first whenever its
   evidence reaches half the best candidate's: a shift between SCENE and
   MEASURED contaminates every detector effect downstream (a much stronger
   candidate means the dipoles are the leftovers of a mis-modelled effect).
4. The best candidate is added when ``delta BIC >``
   :data:`EVIDENCE_THRESHOLD` and, after the joint refit of every parameter, it removes at least
   :data:`MIN_EXPLAINED_FRACTION` of the gap's excess over the floor (when
   that excess is significant): an effect that explains little of a large
   excess is a symptom of something the vocabulary lacks, not a finding.
   After that refit, an earlier effect whose removal no longer costs
   evidence (:func:`prune`: its parameters fell back to "off", or its work
   is now done by the newcomer) is dropped and recorded under ``pruned``.
5. The loop repeats until no candidate qualifies; the noise floor is then
   the final model simulated :data:`FLOOR_SIMULATIONS` times with fresh
   noise. ``complete`` is true when the final gap lies within
   :data:`COMPLETE_SIGMAS` floor scatters of the floor; otherwise
   ``unexplained`` describes the remaining residual (:func:`describe_unexplained`).

Uncertainties are from the Gauss-Newton covariance ``(J^T J)^-1`` of the
whitened residuals, inflated by the reduced chi-square when it exceeds 1
(mean effects), or from the curvature of the likelihood (noise effects).
"""

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares, minimize

from ..errors import GeometryError, IPCInputError, LawError
from .diagnostics import (SIGNAL_BINS, after_images, dipoles, fill_scene, find_probes, gap,
                          pair_correlation, probe_masks, residual, residual_vs_signal,
                          residuals_by_probe, stacked_windows, valid_mask)
from .effects import DEGENERATE, EFFECTS, SEPARATION, contradiction, derived_params
from .labdata import LabData, read_lab
from .model import CHAIN_ORDER, DetectorModel, is_constant_law

__all__ = ["discover", "Discovery", "Frames", "fit_parameters", "deviance", "prune",
           "describe_unexplained", "EVIDENCE_THRESHOLD",
           "MIN_EXPLAINED_FRACTION", "COMPLETE_SIGMAS", "FLOOR_SIMULATIONS", "MAX_STEPS"]

EVIDENCE_THRESHOLD = 25.0  # delta BIC; null simulations give < 0 (see docs/discover.md)
MIN_EXPLAINED_FRACTION = 0.25  # a step must remove this share of the gap's excess
COMPLETE_SIGMAS = 3.0  # complete: final gap within this many floor scatters of the floor
FLOOR_SIMULATIONS = 24
MAX_STEPS = 4
ALTERNATIVE_RATIO = 0.5
SIGNATURE_Z2 = 25.0  # an effect's own signature must be 5 sigma (see _signature)
UNEXPLAINED_Z = 5.0  # a pattern is described when it stands out at 5 sigma
_FAILED = 1e6  # whitened residual returned for a parameter set the engine rejects


def _is_noise_effect(name):
    return EFFECTS[name].stage == "variance"


def deviance(residuals, variances, scales, valids, response_variance):
    """``-2 ln L`` (up to a constant) of Gaussian residuals, summed over blocks.

    Each block holds the pairs of one shape, ``(K, ny, nx)``: ``residuals``
    ``MEASURED - mean``, ``variances`` the independent (shot + read)
    variance, ``scales`` the response scale ``a`` (the charge a unit
    response change moves, through IPC: :meth:`DetectorModel.predict_parts`).
    A response map of variance ``u`` adds ``u a_k a_l`` to the covariance
    of pairs ``k, l`` at one pixel: a rank-one term, so per pixel
    (Sherman-Morrison, matrix determinant lemma)
    ``sum r^2/v - u b^2/(1 + u c) + sum ln v + ln(1 + u c)`` with
    ``b = sum r a / v`` and ``c = sum a^2 / v``.
    """
    total = 0.0
    u = float(response_variance)
    for r, v, mu, w in zip(residuals, variances, scales, valids):
        v = np.where(w, np.maximum(v, 1e-12), 1.0)
        r = np.where(w, r, 0.0)
        mu = np.where(w, mu, 0.0)
        total += float(np.sum(r * r / v) + np.sum(np.log(v)[w]))
        if u > 0:
            b = np.sum(r * mu / v, axis=0)
            c = np.sum(mu * mu / v, axis=0)
            total += float(np.sum(np.log1p(u * c) - u * b * b / (1.0 + u * c)))
    return total


@dataclass
class Frames:
    """Prepared data: same-shape pairs stacked into 3-D blocks."""

    scenes: list
    measured: list
    valid: list
    n: int

    @classmethod
    def from_lab(cls, lab):
        groups = {}
        for ver, scene, measured in lab.pairs:
            valid = valid_mask(scene, measured)
            if not valid.any():
                raise IPCInputError(f"{lab.path}[MEASURED,{ver}]: no valid pixel left after "
                                    "masking NaNs and the border")
            groups.setdefault(scene.shape, []).append(
                (fill_scene(scene), np.where(valid, measured, 0.0), valid))
        scenes, measured, valid = [], [], []
        for items in groups.values():
            scenes.append(np.stack([s for s, _, _ in items]))
            measured.append(np.stack([m for _, m, _ in items]))
            valid.append(np.stack([v for _, _, v in items]))
        return cls(scenes, measured, valid, int(sum(v.sum() for v in valid)))

    def predict(self, model):
        """Per block ``(mean, independent variance, response scale)``
        (:meth:`DetectorModel.predict_parts`)."""
        return [model.predict_parts(s) for s in self.scenes]

    @staticmethod
    def total_variance(model, parts):
        """Per block the diagonal variance, response map included."""
        u = model.response_variance()
        return [var + u * a * a for _, var, a in parts]

    def whitened(self, model, sds):
        """Residual vector ``(M - mean) / sd`` over valid pixels, ``sds`` fixed."""
        out = []
        for s, m, v, sd in zip(self.scenes, self.measured, self.valid, sds):
            out.append(((m - model.expected(s)) / sd)[v])
        return np.concatenate(out)

    def residuals(self, model, parts=None):
        """Per-frame residual maps (NaN outside valid) and expected means."""
        parts = parts or self.predict(model)
        res, means = [], []
        for (mean, _, _), var, m, v in zip(parts, self.total_variance(model, parts),
                                           self.measured, self.valid):
            res.extend(residual(m, mean, var, v))
            means.extend(mean)
        return res, means

    def deviance(self, model, parts, response_variance=None, read_variance=None):
        """:func:`deviance` of the data under ``model`` (``parts`` its prediction);
        the response and read variances may be overridden (noise-effect fits)."""
        u = model.response_variance() if response_variance is None else response_variance
        shift = 0.0 if read_variance is None else read_variance - model.read_variance()
        return deviance([m - mean for (mean, _, _), m in zip(parts, self.measured)],
                        [var + shift for _, var, _ in parts], [a for _, _, a in parts],
                        self.valid, u)

    def floor(self, model, rng, n_sim, parts=None):
        """Gap of ``n_sim`` fresh simulations of ``model`` against its own prediction.

        Returns ``(mean, standard deviation, per-signal-bin mean chi-square)``.
        """
        parts = parts or self.predict(model)
        variances = self.total_variance(model, parts)
        gaps, per_bin = [], []
        for _ in range(n_sim):
            res, means = [], []
            for s, v, (mean, _, _), var in zip(self.scenes, self.valid, parts, variances):
                res.extend(residual(model.simulate(s, rng), mean, var, v))
                means.extend(mean)
            gaps.append(gap(res))
            per_bin.append(residual_vs_signal(res, means)[2])
        chi2_bins = None
        if n_sim:
            per_bin = np.array(per_bin)
            seen = np.isfinite(per_bin).sum(axis=0)
            chi2_bins = np.where(seen > 0, np.nansum(per_bin, axis=0) / np.maximum(seen, 1),
                                 np.nan)
        return (float(np.mean(gaps)), float(np.std(gaps, ddof=1)) if n_sim > 1 else 0.0,
                chi2_bins)


@dataclass
class FitResult:
    model: DetectorModel
    chi2: float
    values: dict            # {(effect, param): value}
    errors: dict            # {(effect, param): 1-sigma}
    cov: np.ndarray
    keys: list
    nfev: int = 0


def _with_values(model, keys, x):
    changes = {}
    for (effect, name), value in zip(keys, x):
        changes.setdefault(effect, dict(model.effects.get(effect, {})))[name] = float(value)
    return model.with_effects(changes)


def _spec(key):
    return next(p for p in EFFECTS[key[0]].params if p.name == key[1])


def fit_parameters(frames, model, keys, sds, max_nfev=40):
    """Least-squares fit of the mean parameters ``keys`` = ``[(effect, param), ...]``.

    The other parameters and the noise (``sds``, per block) stay fixed.
    """
    specs = [_spec(k) for k in keys]
    x0 = np.array([model.effects[e][n] for e, n in keys], dtype=np.float64)
    lower = np.array([p.lower for p in specs])
    upper = np.array([p.upper for p in specs])
    scale = np.array([p.scale for p in specs])
    cache = {}

    def resid(x):
        key = tuple(np.round(x, 15))
        if key not in cache:
            try:
                r = frames.whitened(_with_values(model, keys, x), sds)
            except (LawError, GeometryError):
                r = np.full(frames.n, _FAILED)
            if len(cache) > 64:
                cache.clear()
            cache[key] = r
        return cache[key]

    def jac(x):
        f0 = resid(x)
        cols = []
        for i in range(len(x)):
            h = 0.01 * scale[i]
            if x[i] + h > upper[i]:
                h = -h
            xp = x.copy()
            xp[i] += h
            cols.append((resid(xp) - f0) / h)
        return np.column_stack(cols)

    # a coarse scan per parameter (multiples of its scale, both signs) picks the
    # start: far from the truth the chi-square is strongly curved (a blur of
    # 0.2 px moves a third of a hot pixel's charge) and a trust-region step
    # from "off" can stall at the bound
    x0 = np.clip(x0, lower, upper)
    for i in range(len(x0)):
        if not specs[i].scan:
            continue
        trials = [x0[i]] + [x0[i] + sgn * m * scale[i] for m in (1, 4, 16, 64) for sgn in (1, -1)]
        trials = [t for t in trials if lower[i] <= t <= upper[i]]
        costs = []
        for t in trials:
            xt = x0.copy()
            xt[i] = t
            costs.append(float(np.sum(resid(xt) ** 2)))
        x0[i] = trials[int(np.argmin(costs))]
    res = least_squares(resid, x0, jac=jac, bounds=(lower, upper), x_scale=scale,
                        method="trf", xtol=1e-6, ftol=1e-9, gtol=1e-10, max_nfev=max_nfev)
    chi2 = float(np.sum(res.fun ** 2))
    jm = jac(res.x)
    dof = max(frames.n - len(keys), 1)
    try:
        cov = np.linalg.inv(jm.T @ jm) * max(1.0, chi2 / dof)
    except np.linalg.LinAlgError:
        cov = np.full((len(keys), len(keys)), np.inf)
    errors = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return FitResult(_with_values(model, keys, res.x), chi2,
                     dict(zip(keys, map(float, res.x))), dict(zip(keys, map(float, errors))),
                     cov, list(keys), res.nfev)


def fit_noise(frames, model, keys, parts):
    """Maximum-likelihood fit of the noise parameters ``keys`` with the mean fixed.

    ``parts`` is the model's prediction; only the response variance
    (``flat_field``) and the read variance (``excess_read_noise``) change,
    so each evaluation is arithmetic on fixed arrays. Returns a
    :class:`FitResult` whose ``chi2`` is the deviance.
    """
    specs = [_spec(k) for k in keys]
    scale = np.array([p.scale for p in specs])
    bounds = [(p.lower / s, p.upper / s) for p, s in zip(specs, scale)]
    base_read = model.read_variance() - float(
        model.effects.get("excess_read_noise", {}).get("excess_variance_e2", 0.0))
    x0 = np.array([model.effects[e][n] for e, n in keys]) / scale

    def dev(z):
        x = dict(zip(keys, z * scale))
        u = x.get(("flat_field", "response_variance"), model.response_variance())
        e = x.get(("excess_read_noise", "excess_variance_e2"),
                  model.read_variance() - base_read)
        return frames.deviance(model, parts, u, max(base_read + e, 1e-6))

    best = minimize(dev, x0, method="L-BFGS-B", bounds=bounds)
    z = best.x
    # curvature of the deviance: the Fisher information is half of it
    k = len(z)
    hess = np.zeros((k, k))
    h = 0.5
    for i in range(k):
        for j in range(k):
            zs = []
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                zz = z.copy()
                zz[i] += si * h
                zz[j] += sj * h
                zs.append(dev(np.clip(zz, [b[0] for b in bounds], [b[1] for b in bounds])))
            hess[i, j] = (zs[0] - zs[1] - zs[2] + zs[3]) / (4 * h * h)
    try:
        cov = np.linalg.inv(0.5 * hess) * np.outer(scale, scale)
    except np.linalg.LinAlgError:
        cov = np.full((k, k), np.inf)
    errors = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    x = z * scale
    return FitResult(_with_values(model, keys, x), float(best.fun),
                     dict(zip(keys, map(float, x))), dict(zip(keys, map(float, errors))),
                     cov, list(keys), int(best.nfev))


def _sds(model, parts):
    return [np.sqrt(v) for v in Frames.total_variance(model, parts)]


def _chi2(frames, model, sds):
    r = frames.whitened(model, sds)
    return float(r @ r)


def _candidates(model):
    out = []
    for name in EFFECTS:
        if name in model.effects:
            continue
        if name == "signal_dependent_ipc" and not is_constant_law(model.law):
            continue
        out.append(name)
    return out


def _partners(name, model):
    """Effects in the model that are near-degenerate with ``name`` (refitted with it)."""
    return [e for e in model.effects if frozenset({name, e}) in DEGENERATE
            and _is_noise_effect(e) == _is_noise_effect(name)]


def _signature(name, fit):
    """Squared significance of what makes ``name`` that effect, not a rescaled IPC.

    A rescaled coupling (``weight_horizontal = weight_vertical != 1``, or a
    constant law with a new floor) would otherwise pass for anisotropy or
    signal dependence whenever anything adds nearest-neighbour charge (e.g.
    diffusion). The signature is the anisotropy for ``anisotropic_ipc``, the
    two amplitudes jointly for ``signal_dependent_ipc``; for the other
    effects the evidence itself is the signature.
    """
    if name == "anisotropic_ipc":
        params, errors = _params_report(fit, name)
        sigma = errors["anisotropy"]
        return (params["anisotropy"] / sigma) ** 2 if sigma > 0 else math.inf
    if name == "signal_dependent_ipc":
        idx = [fit.keys.index((name, "amp_diff")), fit.keys.index((name, "amp_level"))]
        a = np.array([fit.values[fit.keys[i]] for i in idx])
        try:
            return float(a @ np.linalg.solve(fit.cov[np.ix_(idx, idx)], a))
        except np.linalg.LinAlgError:
            return 0.0
    return math.inf


def _noise_mean_z(frames, model, parts, name):
    """The mean of the residuals where a noise effect adds its variance, in units
    of its standard error: a variance excess has zero mean there, a missing
    signal (an after-image, a cosmic ray, a ghost) does not."""
    num = den = 0.0
    for (mean, var, a), m, v in zip(parts, frames.measured, frames.valid):
        var = np.maximum(var, 1e-12)
        r = (m - mean) / np.sqrt(var)
        # where the effect's variance is a large share of the total
        w = (1.0 / var) if name == "excess_read_noise" else (a * a / var)
        w = np.where(v, w / var.mean() if name == "excess_read_noise" else w, 0.0)
        num += float(np.sum(w * r))
        # the residuals' own scatter: a variance excess inflates it, and a
        # z in units of the model's variance would then flag noise as a signal
        den += float(np.sum(w * w * r * r))
    return num / math.sqrt(den) if den > 0 else 0.0


def _flat_interior_z(frames, model, parts, masks):
    """Significance of the chi-square excess inside flat areas (``inf`` when
    the frames have none): a response map shows there like anywhere bright,
    the leftovers of a mis-modelled blur or coupling do not."""
    values, i = [], 0
    for (mean, _, _), var, m, v in zip(parts, Frames.total_variance(model, parts),
                                       frames.measured, frames.valid):
        for k in range(len(mean)):
            inside = masks[i]["flat_patches"][0] & v[k]
            values.append(((m[k] - mean[k]) ** 2 / var[k])[inside])
            i += 1
    values = np.concatenate(values)
    if values.size < 20:  # nothing flat to confirm a response map with
        return -math.inf
    return (float(values.mean()) - 1.0) / math.sqrt(2.0 / values.size)


def _refit_all(frames, model, passes=2):
    """Refit every parameter of the model: the mean parameters with the
    variance fixed, then the noise parameters with the mean fixed, updating
    the propagated variance between passes."""
    mean_keys = [(e, p.name) for e in model.effects for p in EFFECTS[e].params
                 if not _is_noise_effect(e)]
    noise_keys = [(e, p.name) for e in model.effects for p in EFFECTS[e].params
                  if _is_noise_effect(e)]
    results = []
    for _ in range(passes):
        results = []
        parts = frames.predict(model)
        if mean_keys:
            r = fit_parameters(frames, model, mean_keys, _sds(model, parts), max_nfev=60)
            model = r.model
            results.append(r)
            parts = frames.predict(model)
        if noise_keys:
            r = fit_noise(frames, model, noise_keys, parts)
            model = r.model
            results.append(r)
        if not mean_keys:
            break
    keys = [k for r in results for k in r.keys]
    cov = np.zeros((len(keys), len(keys)))
    i = 0
    for r in results:
        n = len(r.keys)
        cov[i:i + n, i:i + n] = r.cov
        i += n
    values = {k: v for r in results for k, v in r.values.items()}
    errors = {k: v for r in results for k, v in r.errors.items()}
    return FitResult(model, results[-1].chi2, values, errors, cov, keys)


def prune(frames, model, threshold=EVIDENCE_THRESHOLD, keep=()):
    """Drop the effects whose removal no longer costs evidence.

    After a later effect joins and every parameter is refitted, an earlier
    one may fall back to "off" (its parameters at their "off" values) or
    to a value that the data no longer need: its work is now done by the
    newcomer. For each effect of ``model`` not in ``keep``, the Gaussian
    likelihood (:meth:`Frames.deviance`, mean and variance recomputed) of
    the model without it is compared with the full model's: it is dropped
    when ``delta BIC = -2 delta lnL - k ln n`` of keeping it is at or below
    ``threshold``, the same bar an effect must pass to be added. The
    weakest is dropped first and the rest are judged again.

    Returns
    -------
    (DetectorModel, list)
        The pruned model and ``[(effect, params, delta BIC of keeping it)]``.
    """
    ln_n = math.log(frames.n)
    pruned = []
    while True:
        dev_full = frames.deviance(model, frames.predict(model))
        worth = {}
        for name in model.effects:
            if name in keep:
                continue
            without = replace(model, effects={e: dict(p) for e, p in model.effects.items()
                                              if e != name})
            k = len(EFFECTS[name].params)
            worth[name] = frames.deviance(without, frames.predict(without)) - dev_full - k * ln_n
        if not worth:
            return model, pruned
        weakest = min(worth, key=worth.get)
        if worth[weakest] > threshold:
            return model, pruned
        pruned.append((weakest, dict(model.effects[weakest]), float(worth[weakest])))
        model = replace(model, effects={e: dict(p) for e, p in model.effects.items()
                                        if e != weakest})


def _params_report(result, effect, readnoise=None):
    keys = [k for k in result.keys if k[0] == effect]
    params = {n: result.values[(e, n)] for e, n in keys}
    errors = {n: result.errors[(e, n)] for e, n in keys}
    idx = [result.keys.index(k) for k in keys]
    extra, extra_err = derived_params(effect, params, cov=result.cov[np.ix_(idx, idx)],
                                      readnoise=readnoise)
    params.update(extra)
    errors.update(extra_err)
    return params, errors


@dataclass
class Discovery:
    """The outcome of :func:`discover`: the JSON-ready ``report`` and the
    arrays the figures need (``baseline`` and ``final`` diagnostics)."""

    report: dict
    model: DetectorModel
    baseline: dict = field(repr=False, default_factory=dict)
    final: dict = field(repr=False, default_factory=dict)
    gaps: list = field(default_factory=list)


def _diagnostics(frames, model, probes, masks, parts=None):
    res, means = frames.residuals(model, parts)
    stacks, counts = stacked_windows(res, probes)
    centres, mean_r, mean_r2, n = residual_vs_signal(res, means)
    blocks, i = [], 0
    for s in frames.scenes:
        blocks.append(res[i:i + len(s)])
        i += len(s)
    return {"residuals": res, "means": means, "stacks": stacks, "counts": counts,
            "signal": centres, "mean_residual": mean_r, "mean_residual2": mean_r2,
            "signal_counts": n, "gap": gap(res), "by_probe": residuals_by_probe(res, masks),
            "dipoles": dipoles(res, probes),
            "after_images": after_images(blocks, frames.scenes, frames.valid),
            "pair_correlation": pair_correlation(blocks)}


def _json_diag(d):
    def clean(a):
        return [None if not np.isfinite(v) else round(float(v), 4) for v in np.ravel(a)]

    def num(v):
        return None if not np.isfinite(v) else round(float(v), 4)

    out = {"stack_mean_residual": [[clean(row) for row in s] for s in d["stacks"]],
           "stack_counts": [int(c) for c in d["counts"]],
           "signal_bin_centres": clean(d["signal"]),
           "mean_residual_vs_signal": clean(d["mean_residual"]),
           "chi2_vs_signal": clean(d["mean_residual2"]),
           "pixels_per_signal_bin": [int(c) for c in d["signal_counts"]],
           "residuals_by_probe": {k: {w: {q: (num(x) if isinstance(x, float) else x)
                                          for q, x in part.items()}
                                      for w, part in v.items()}
                                  for k, v in d["by_probe"].items()},
           "dipole_x": {"mean": num(d["dipoles"]["x"][0]), "z": num(d["dipoles"]["x"][1])},
           "dipole_y": {"mean": num(d["dipoles"]["y"][0]), "z": num(d["dipoles"]["y"][1])},
           "after_image": {"mean": num(d["after_images"][0]), "z": num(d["after_images"][1]),
                           "n": d["after_images"][2]},
           "pair_correlation": {"mean": num(d["pair_correlation"][0]),
                                "z": num(d["pair_correlation"][1])}}
    if d.get("floor_chi2_vs_signal") is not None:
        out["floor_chi2_vs_signal"] = clean(d["floor_chi2_vs_signal"])
    return out


# What SCENE cannot tell the model, per effect in the final model: SCENE holds
# each pixel's integrated charge, not how the light lies within the pixel, and
# these effects move charge by less than a pixel (measured in docs/discover.md).
SUBPIXEL_LIMITS = {
    "misregistration":
        "the fitted shift moves SCENE by interpolating its pixel values, exact only for "
        "light smooth on the pixel scale; how the light lies within a pixel is not in "
        "SCENE (a star and a uniform 1x1 source of the same pixel values shift "
        "differently), so without the sources' profiles no interpolation shifts stars "
        "sharper than about 2.2 px FWHM, single-pixel events and sharp edges exactly (a "
        "0.3 px shift of a 1.8 px FWHM star leaves 1.8 % of its peak with a spline and "
        "with a band-limited shift alike): what remains here may be that limit of the "
        "data, not a missing effect",
    "charge_diffusion":
        "the diffusion model spreads charge generated uniformly across each pixel (right "
        "for single-pixel events and flat areas); light that peaks inside its pixel (a "
        "star) keeps more of it, so where the data's diffusion starts from the photons' "
        "true positions, star centres are left above the model (sigma 0.22 px, a 1.8 px "
        "FWHM star: the model's peak 11 % low) and SCENE cannot say which picture holds "
        "for which pixel: what remains at star centres may be that limit of the data",
}


def describe_unexplained(d, rejected=(), effects=()):
    """Words a detector scientist can act on for what the final model leaves.

    ``d`` is the final diagnostics (with ``floor_chi2_vs_signal``, the
    floor simulations' chi-square per signal bin); ``rejected`` the
    candidates that were fitted but not named, ``(effect, why)``;
    ``effects`` the final model's effects, whose known limits
    (:data:`SUBPIXEL_LIMITS`) are named. Only patterns that stand out at
    :data:`UNEXPLAINED_Z` sigma are described.
    """
    out = []
    n = d["signal_counts"]
    floor_bins = d.get("floor_chi2_vs_signal")
    expect = floor_bins if floor_bins is not None else np.ones(len(n))
    z_var = (d["mean_residual2"] - expect) / np.sqrt(2.0 / np.maximum(n, 1))
    z_mean = d["mean_residual"] * np.sqrt(np.maximum(n, 1))
    centres = d["signal"]
    ok = (n > 30) & np.isfinite(z_var) & np.isfinite(z_mean)
    for axis in ("x", "y"):
        m, z = d["dipoles"][axis]
        if np.isfinite(z) and abs(z) > UNEXPLAINED_Z:
            out.append(f"dipoles aligned with {axis} around every source (mean "
                       f"{m:+.2f} sigma per side): SCENE and MEASURED offset along {axis}?")
    m, z, cnt = d["after_images"]
    if np.isfinite(z) and z > UNEXPLAINED_Z:
        out.append(f"positive residual where the previous pair's SCENE was bright ({m:+.2f} "
                   f"sigma per pixel over {cnt} pixels, {z:.0f} standard errors): an "
                   "after-image of earlier exposures (persistence or another memory effect)")
    m, z = d["pair_correlation"]
    if np.isfinite(z) and z > UNEXPLAINED_Z:
        out.append(f"residuals repeat pixel by pixel across pairs (mean product {m:.3f}): "
                   "a fixed per-pixel pattern")
    out += [f"{name} is in the model, but {SUBPIXEL_LIMITS[name]}"
            for name in effects if name in SUBPIXEL_LIMITS]
    var_bad = ok & (z_var > UNEXPLAINED_Z) & (np.abs(z_mean) < np.maximum(3.0, 0.3 * z_var))
    if var_bad.any():
        lo, hi = centres[var_bad].min(), centres[var_bad].max()
        low_only = hi < 3000
        shape = ("at low signal" if low_only else "growing with signal"
                 if z_var[var_bad][-1] > z_var[var_bad][0] else "across signal levels")
        out.append(f"variance excess {shape} ({lo:.0f}-{hi:.0f} e-; chi-square up to "
                   f"{np.nanmax(d['mean_residual2'][var_bad]):.2f} per pixel), zero mean")
    mean_bad = ok & (np.abs(z_mean) > UNEXPLAINED_Z)
    if mean_bad.any():
        sign = np.sign(np.sum(z_mean[mean_bad]))
        lo, hi = centres[mean_bad].min(), centres[mean_bad].max()
        out.append(f"mean residual {'positive' if sign > 0 else 'negative'} at "
                   f"{lo:.0f}-{hi:.0f} e- (measured {'above' if sign > 0 else 'below'} "
                   "the model there)")
    for kind, parts in d["by_probe"].items():
        c, r = parts["centre"], parts["ring"]
        for where, part in (("centres", c), ("surroundings", r)):
            if part["n"] > 5 and np.isfinite(part["z"]) and abs(part["z"]) > UNEXPLAINED_Z:
                out.append(f"{kind.replace('_', ' ')}: {where} {part['mean']:+.2f} sigma on "
                           f"average ({part['n']} pixels, chi-square {part['chi2']:.2f})")
    for name, why in rejected:
        out.append(f"not named {name}: {why}")
    if not out:
        out.append("an excess spread over the frame without a localised pattern "
                   "(no signal range, probe type or direction stands out at "
                   f"{UNEXPLAINED_Z:g} sigma)")
    return out


def _full_evidence(frames, fitted, dev_now, k, ln_n):
    """delta BIC of a fitted candidate by the full Gaussian likelihood: its mean
    *and* its propagated variance updated (the fits hold the variance fixed).

    Reported beside near-degenerate alternatives, not used to name: it tells an
    effect before shot noise (brighter-fatter moves charge that then has its
    own Poisson noise, so the neighbours' variance grows) from one after it
    (a coupling moves noise along with the charge), but it is small (-2 to +54 on
    80x80 frames at a 1-2 % deflection, docs/discover.md) and it calls a
    flow computed from the collected charge a coupling, which in its noise it is.
    """
    return dev_now - frames.deviance(fitted, frames.predict(fitted)) - k * ln_n


def _fit_candidate(frames, model, name, parts, sds, chi2_now, dev_now, ln_n):
    """Fit one candidate (with its near-degenerate partners); ``(evidence, delta, k, fit)``."""
    trial = model.with_effects({name: model.starting_params(name)})
    keys = [(name, p.name) for p in EFFECTS[name].params]
    k = len(keys)
    keys += [(e, p.name) for e in _partners(name, model) for p in EFFECTS[e].params]
    if _is_noise_effect(name):
        fit = fit_noise(frames, trial, keys, parts)
        delta = dev_now - fit.chi2
    else:
        fit = fit_parameters(frames, trial, keys, sds)
        delta = chi2_now - fit.chi2
    return delta - k * ln_n, delta, k, fit


def discover(data, seed=0, threshold=EVIDENCE_THRESHOLD, max_steps=MAX_STEPS,
             floor_simulations=FLOOR_SIMULATIONS, log=None):
    """Find the effects missing from the starting model of a lab file.

    Parameters
    ----------
    data : str or LabData
        A lab FITS file (``docs/discovery_format.md``) or its :func:`read_lab` result.
    seed : int
        Seed of the noise-floor simulations.
    threshold : float
        Minimum delta BIC for an effect to be added.
    log : callable, optional
        Called with one progress line per step.

    Returns
    -------
    Discovery
        ``.report`` is the JSON report (``baseline_gap``, ``steps``,
        ``missing_effects``, ``final_gap``, ``gap_floor``, ``gap_floor_sigma``,
        ``complete``, ``unexplained``, ...).
    """
    lab = data if isinstance(data, LabData) else read_lab(data)
    if lab.readnoise == 0 and not lab.shot_noise:
        raise IPCInputError(f"{lab.path}[PRIMARY]: READNOIS = 0 with SHOTNOIS = F leaves no "
                            "noise to weigh residuals by")
    say = log or (lambda line: None)
    frames = Frames.from_lab(lab)
    rng = np.random.default_rng(seed)
    ln_n = math.log(frames.n)
    probes, masks = [], []
    for block_s, block_v in zip(frames.scenes, frames.valid):
        for s, v in zip(block_s, block_v):
            probes.append(find_probes(s, v))
            masks.append(probe_masks(s, v, probes[-1]))
    model = lab.model()
    parts = frames.predict(model)
    baseline = _diagnostics(frames, model, probes, masks, parts)
    current_gap = baseline["gap"]
    say(f"baseline gap {current_gap:.4f} over {frames.n} pixels ({model.describe()})")
    steps, final_fit, stop, rejected, pruned = [], None, None, [], []
    while len(steps) < max_steps:
        floor, floor_sigma, _ = frames.floor(model, rng, max(4, floor_simulations // 3), parts)
        sds = _sds(model, parts)
        chi2_now = _chi2(frames, model, sds)
        dev_now = frames.deviance(model, parts)
        trials = {n: _fit_candidate(frames, model, n, parts, sds, chi2_now, dev_now, ln_n)
                  for n in _candidates(model) if n not in {p["effect"] for p in pruned}}
        if not trials:
            stop = {"reason": "every effect of the vocabulary is in the model"}
            break
        contradicting = {}
        for n, t in trials.items():
            why = contradiction(n, {p.name: t[3].values[(n, p.name)] for p in EFFECTS[n].params})
            if why:
                contradicting[n] = "the fit contradicts the effect: " + why
        for n in trials:
            if _is_noise_effect(n) and n not in contradicting:
                z = _noise_mean_z(frames, model, parts, n)
                if abs(z) > UNEXPLAINED_Z:
                    contradicting[n] = (f"a variance excess, but the residuals there have a "
                                        f"non-zero mean ({z:+.1f} standard errors)")
        if "flat_field" in trials and "flat_field" not in contradicting:
            z = _flat_interior_z(frames, model, parts, masks)
            if z < UNEXPLAINED_Z:
                contradicting["flat_field"] = (
                    f"a response map, but flat areas show no variance excess ({z:+.1f} sigma): "
                    "the excess sits at sources and edges")
        if "misregistration" in trials:
            current = dipoles(frames.residuals(model, parts)[0], probes)
            z2 = max(current["x"][1] ** 2, current["y"][1] ** 2)
            if not z2 > SIGNATURE_Z2:  # a blur can pass for a spline shift; a shift has dipoles
                contradicting["misregistration"] = (
                    f"a shift, but the sources show no dipole (|z| {math.sqrt(z2):.1f})")
        named = {n: t for n, t in trials.items()
                 if n not in contradicting and _signature(n, t[3]) > SIGNATURE_Z2}
        say("candidates: " + ", ".join(f"{n} {trials[n][0]:.1f}" + (" (contradicts)" if n in
                                                                    contradicting else "")
                                       for n in sorted(trials, key=lambda n: -trials[n][0])))
        best = max(named or trials, key=lambda n: trials[n][0])
        shift = named.get("misregistration")
        if shift and shift[0] > max(threshold, ALTERNATIVE_RATIO * trials[best][0]):
            best = "misregistration"  # first: a shift contaminates every detector effect
        evidence, delta, k, fit = trials[best]
        above_floor = (current_gap - floor) / floor_sigma if floor_sigma > 0 else math.inf
        for n, why in contradicting.items():  # a strong fit with the wrong sign is a clue
            if trials[n][0] > threshold:
                rejected[:] = [(m, w) for m, w in rejected if m != n] + [(n, why)]
        if not (named and evidence > threshold):
            why = ("" if named else "no candidate qualifies (signature or sign); ") + (
                   f"best candidate {best} has delta BIC {evidence:.1f} "
                   f"(threshold {threshold:g}); gap {current_gap:.4f} is {above_floor:.1f} "
                   f"scatters above the floor {floor:.4f}")
            stop = {"reason": why, "best_candidate": best, "evidence": round(evidence, 2),
                    "gap_scatters_above_floor": round(above_floor, 2),
                    "contradicting": contradicting}
            say("stop: " + why)
            break
        refit = _refit_all(frames, fit.model)
        # an earlier effect whose work the newcomer now does is dropped (its
        # parameters fall back to "off" or to values the data no longer need)
        kept, dropped = prune(frames, refit.model, threshold, keep=(best,))
        if dropped:
            refit = _refit_all(frames, kept)
        new_parts = frames.predict(refit.model)
        gap_after = gap(frames.residuals(refit.model, new_parts)[0])
        excess = current_gap - floor
        fraction = (current_gap - gap_after) / excess if excess > 0 else None
        if above_floor > 3.0 and (fraction is None or fraction < MIN_EXPLAINED_FRACTION):
            why = (f"best candidate {best} (delta BIC {evidence:.1f}) removes only "
                   f"{100 * (fraction or 0.0):.1f} % of the gap's excess over the floor "
                   f"(needs {100 * MIN_EXPLAINED_FRACTION:g} %): a symptom of something the "
                   "vocabulary lacks, not a finding")
            stop = {"reason": why, "best_candidate": best, "evidence": round(evidence, 2),
                    "explained_fraction": fraction,
                    "gap_scatters_above_floor": round(above_floor, 2),
                    "contradicting": contradicting}
            rejected[:] = [(m, w) for m, w in rejected if m != best] + [
                (best, f"it would remove only {100 * (fraction or 0.0):.1f} % of the excess")]
            say("stop: " + why)
            break
        alternatives = []
        best_full = _full_evidence(frames, fit.model, dev_now, k, ln_n)
        for name, (ev, dc, kk, f) in sorted(named.items(), key=lambda t: -t[1][0]):
            if name == best or ev < max(threshold, ALTERNATIVE_RATIO * evidence):
                continue
            params, errors = _params_report(f, name, lab.readnoise)
            alternatives.append({
                "effect": name, "evidence": round(ev, 2), "params": params,
                "evidence_with_variance": round(_full_evidence(frames, f.model, dev_now, kk,
                                                               ln_n), 2),
                "uncertainties": errors,
                "separated_by": SEPARATION.get(frozenset({best, name}),
                                               "the stacked windows per signal bin")})
        final_fit, model, parts = refit, refit.model, new_parts
        for name, values, worth in dropped:
            pruned.append({"effect": name, "after_step": len(steps) + 1, "replaced_by": best,
                           "params_before": values, "evidence": round(worth, 2),
                           "reason": f"after {best} joined and every parameter was refitted, "
                                     f"keeping {name} was worth delta BIC {worth:.1f} "
                                     f"(threshold {threshold:g}): {best} does its work"})
            say(f"dropped {name}: keeping it was worth delta BIC {worth:.1f}")
        params, errors = _params_report(final_fit, best, lab.readnoise)
        steps.append({"effect": best, "params": params, "uncertainties": errors,
                      "gap_before": current_gap, "gap_after": gap_after,
                      "explained_fraction": fraction,
                      "evidence": evidence, "evidence_kind": "delta_BIC",
                      "evidence_with_variance": best_full,
                      "delta_chi2": delta, "n_params": k,
                      "refitted_with": _partners(best, fit.model),
                      "pruned": [name for name, _, _ in dropped],
                      "floor_before": floor, "floor_sigma_before": floor_sigma,
                      "alternatives": alternatives,
                      "candidates": {n: round(t[0], 2) for n, t in trials.items()},
                      "contradicting": contradicting,
                      "without_signature": sorted(set(trials) - set(named)
                                                  - set(contradicting))})
        say(f"added {best}: delta BIC {evidence:.1f}, gap {current_gap:.4f} -> {gap_after:.4f}"
            + (f" ({100 * fraction:.0f} % of the excess)" if fraction is not None else ""))
        current_gap = gap_after
    floor, floor_sigma, floor_bins = frames.floor(model, rng, floor_simulations, parts)
    final = _diagnostics(frames, model, probes, masks, parts)
    final["floor_chi2_vs_signal"] = floor_bins
    complete = bool(abs(current_gap - floor) <= COMPLETE_SIGMAS * floor_sigma)
    unexplained = [] if complete else describe_unexplained(final, rejected, list(model.effects))
    final_params = {}
    final_errors = {}
    if final_fit is not None:
        for e in model.effects:
            final_params[e], final_errors[e] = _params_report(final_fit, e, lab.readnoise)
    report = {
        "input": lab.path,
        "readnoise": lab.readnoise,
        "shot_noise": lab.shot_noise,
        "ipclaw": lab.law,
        "gap_statistic": "mean over valid pixels of ((MEASURED - mean)/sd)^2, mean and sd "
                         "the model's prediction of SCENE with shot and read noise propagated",
        "n_pixels": frames.n,
        "n_pairs": len(lab.pairs),
        "baseline_gap": baseline["gap"],
        "gap_floor": floor,
        "gap_floor_sigma": floor_sigma,
        "floor_simulations": floor_simulations,
        "steps": steps,
        "missing_effects": [s["effect"] for s in steps if s["effect"] in model.effects],
        "pruned": pruned,
        "final_gap": current_gap,
        "complete": complete,
        "unexplained": unexplained,
        "final_model": {"law": model.ipc_law().describe(), "effects": final_params,
                        "uncertainties": final_errors},
        "stop": stop,
        "evidence_threshold": {"delta_bic": threshold,
                               "min_explained_fraction": MIN_EXPLAINED_FRACTION,
                               "complete_within_floor_sigmas": COMPLETE_SIGMAS},
        "chain_order": list(CHAIN_ORDER),
        "diagnostics": {"signal_bins": [b if b < 1e8 else None for b in SIGNAL_BINS],
                        "n_probes": int(sum(len(p) for p in probes)),
                        "baseline": _json_diag(baseline), "final": _json_diag(final)},
    }
    gaps = [baseline["gap"]] + [s["gap_after"] for s in steps]
    return Discovery(report, model, baseline, final, gaps)

"""Fitting the parameters of a detector model to a lab file.

Mean parameters (:func:`fit_parameters`) are fitted by least squares with the
variance held fixed; noise parameters (:func:`fit_noise`) by the Gaussian
likelihood with the mean held fixed. :func:`refit_all` alternates the two;
:func:`prune` drops an effect whose work a later one does; :func:`fit_candidate`
fits one effect of the vocabulary (with its near-degenerate partners already
in the model) and returns its evidence, ``delta BIC = -2 delta lnL - k ln n``
(a :class:`Trial`); :func:`join` refits a named candidate with the rest of
the model and lets go what it replaces (a :class:`Joined`).

Uncertainties are from the Gauss-Newton covariance ``(J^T J)^-1`` of the
whitened residuals, inflated by the reduced chi-square when it exceeds 1
(mean effects), or from the curvature of the likelihood (noise effects).
"""

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares, minimize

from ..errors import GeometryError, LawError
from .blocks import PairBlocks
from .diagnostics import gap
from .effects import EFFECTS, contradiction, implausible
from .model import DetectorModel, noise_terms
from .pairs import DEGENERATE

__all__ = ["FitResult", "Trial", "Joined", "fit_parameters", "fit_noise", "refit_all", "prune",
           "fit_candidate", "join", "full_evidence", "params_report", "sds_of", "chi2_of",
           "candidates", "partners", "is_noise_effect", "only_with_smooth_light",
           "spots_refused", "judged_without_spots", "EVIDENCE_THRESHOLD", "FRAGILE",
           "WITHOUT_SPOTS"]

EVIDENCE_THRESHOLD = 25.0  # delta BIC; null simulations give < 0 (see docs/discover.md)
# what an effect that only_with_smooth_light finds is (the report's words for it)
FRAGILE = ("needed only while the pixel-total SCENE's light is taken as smooth across pixels "
           "(the spline shift): it absorbs the error of that picture, not a detector effect")
# how a brighter-fatter was fitted when the pixel-total picture of single-pixel
# sources refuses it (judged_without_spots; the report's words for it)
WITHOUT_SPOTS = ("fitted and judged without the isolated single-pixel sources of the pixel-total "
                 "SCENEs and their 8 neighbours: whether a spot's light lies at its pixel's "
                 "centre or across it decides how much a moved boundary takes from it, and a "
                 "pixel-total SCENE does not say")
_FAILED = 1e6  # whitened residual returned for a parameter set the engine rejects


def is_noise_effect(name):
    return EFFECTS[name].stage == "variance"



@dataclass
class FitResult:
    """A fit: the fitted model, its chi-square (the deviance for noise
    parameters), the fitted ``values`` and ``errors`` per ``(effect,
    parameter)`` key, their covariance in ``keys`` order, and the number of
    model evaluations."""

    model: DetectorModel
    chi2: float
    values: dict            # {(effect, param): value}
    errors: dict            # {(effect, param): 1-sigma}
    cov: np.ndarray
    keys: list
    nfev: int = 0
    picture: str = ""  # WITHOUT_SPOTS when fitted without the single-pixel sources


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
    base_read = model.read_variance() - noise_terms(model.effects)[1]
    x0 = np.array([model.effects[e][n] for e, n in keys]) / scale

    def dev(z):
        effects = {e: dict(p) for e, p in model.effects.items()}
        for (e, n), value in zip(keys, z * scale):
            effects[e][n] = value
        u, extra = noise_terms(effects)
        return frames.deviance(model, parts, u, max(base_read + extra, 1e-6))

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


def sds_of(model, parts):
    return [np.sqrt(v) for v in PairBlocks.total_variance(model, parts)]


def chi2_of(frames, model, sds):
    r = frames.whitened(model, sds)
    return float(r @ r)



def candidates(model):
    out = []
    for name in EFFECTS:
        if name in model.effects:
            continue
        if not EFFECTS[name].offered(model.law):
            continue
        out.append(name)
    return out


def partners(name, model):
    """Effects in the model that are near-degenerate with ``name`` (refitted with it)."""
    return [e for e in model.effects if frozenset({name, e}) in DEGENERATE
            and is_noise_effect(e) == is_noise_effect(name)]



def refit_all(frames, model, passes=2):
    """Refit every parameter of the model: the mean parameters with the
    variance fixed, then the noise parameters with the mean fixed, updating
    the propagated variance between passes."""
    mean_keys = [(e, p.name) for e in model.effects for p in EFFECTS[e].params
                 if not is_noise_effect(e)]
    noise_keys = [(e, p.name) for e in model.effects for p in EFFECTS[e].params
                  if is_noise_effect(e)]
    results = []
    for _ in range(passes):
        results = []
        parts = frames.predict(model)
        if mean_keys:
            r = fit_parameters(frames, model, mean_keys, sds_of(model, parts), max_nfev=60)
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
    likelihood (:meth:`PairBlocks.deviance`, mean and variance recomputed) of
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


def only_with_smooth_light(frames, model, threshold=EVIDENCE_THRESHOLD):
    """The effects that only one picture of a pixel-total SCENE's light needs.

    A pixel-total SCENE does not say how its light lies within each pixel,
    and a shift depends on it: the search shifts pixel totals as light
    smooth across pixels (a spline), wrong for single-pixel spots and sharp
    edges, whose light is uniform within the pixel (a linear shift, exact
    for them). An effect that a model with ``misregistration`` keeps under
    the smooth picture but that :func:`prune` drops once the model is
    refitted with the uniform one (:data:`~.model.WITHIN_PIXEL`) is absorbing
    the error of the picture, not doing work the data need (on GalSim's
    silicon with everything displaced 0.4 px, a 0.023 px "diffusion" did).

    Returns ``[(effect, params under the uniform picture, delta BIC of
    keeping it there)]``; empty when every SCENE is oversampled or the model
    has no shift (the two pictures are then the same model). The report's
    words for such an effect are :data:`FRAGILE`.
    """
    if not any(EFFECTS[e].picture_dependent for e in model.effects) \
            or all(b.oversample > 1 for b in frames.blocks):
        return []
    uniform = refit_all(frames, replace(model, within_pixel="uniform")).model
    return prune(frames, uniform, threshold)[1]


def params_report(result, effect, readnoise=None):
    record = EFFECTS[effect]
    params, errors, cov = record.own(result)
    extra, extra_err = record.derived(params, cov=cov, readnoise=readnoise)
    params.update(extra)
    errors.update(extra_err)
    return params, errors



def full_evidence(frames, fitted, dev_now, k, ln_n):
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


@dataclass(frozen=True)
class Trial:
    """A candidate fitted (:func:`fit_candidate`): its ``evidence`` (delta BIC),
    the drop ``delta`` of the chi-square (or deviance) it buys, its number of
    new parameters ``n_params`` and the ``fit``."""

    evidence: float
    delta: float
    n_params: int
    fit: FitResult


def fit_candidate(frames, model, name, parts, sds, chi2_now, dev_now, ln_n):
    """Fit one candidate (with its near-degenerate partners): a :class:`Trial`."""
    trial = model.with_effects({name: model.starting_params(name)})
    keys = [(name, p.name) for p in EFFECTS[name].params]
    k = len(keys)
    keys += [(e, p.name) for e in partners(name, model) for p in EFFECTS[e].params]
    if is_noise_effect(name):
        fit = fit_noise(frames, trial, keys, parts)
        delta = dev_now - fit.chi2
    else:
        fit = fit_parameters(frames, trial, keys, sds)
        delta = chi2_now - fit.chi2
    return Trial(delta - k * ln_n, delta, k, fit)


def spots_refused(fit):
    """Why an effect of a fit (a :class:`FitResult`) judged again without the
    single-pixel sources (:attr:`~.record.Effect.spots_aside`: brighter-fatter)
    contradicts the effect or lies outside its physical range (judged with the
    fit's covariance, :func:`~.effects.implausible`); ``None`` when each holds or
    none is there."""
    for name, params in fit.model.effects.items():
        if not EFFECTS[name].spots_aside:
            continue
        keys = [(name, p.name) for p in EFFECTS[name].params]
        cov = None
        if all(k in fit.keys for k in keys):
            idx = [fit.keys.index(k) for k in keys]
            cov = fit.cov[np.ix_(idx, idx)]
        why = contradiction(name, params) or implausible(name, params, None, cov)
        if why:
            return why
    return None


def judged_without_spots(frames, model, trial, sds, chi2_now, ln_n):
    """A candidate's :class:`Trial` whose fit leaves ``brighter_fatter``
    refused (:func:`spots_refused`), fitted again without the pixel-total SCENEs'
    single-pixel sources (:meth:`~.blocks.PairBlocks.without_single_pixel_sources`):
    the boundary-shift picture takes each pixel's light as uniform across it,
    and a spot whose light lies at its pixel's centre (a pinhole, a point-like
    hot pixel) is hardly moved by a real sensor; fitted there, the effect's
    kernel is pushed to shrink the neighbours instead of the charged pixel
    (GalSim's silicon sensor with pinhole spots: a centre of -4e-8 and nearest
    terms of -8e-7 per electron; without them the sensor's, as with
    ``OVERSAMP``). The new trial's evidence is the drop of the chi-square over
    *every* pixel (``sds`` and ``chi2_now`` the current model's), so it stays
    comparable with the other candidates'; its fit carries ``picture`` =
    :data:`WITHOUT_SPOTS`. The trial itself comes back when nothing can be
    taken out or the effect is refused there too.
    """
    if not spots_refused(trial.fit):
        return trial
    masked = frames.without_single_pixel_sources()
    if masked is None:
        return trial
    start = model.with_effects({e: (model.starting_params(e) if e not in model.effects
                                    else model.effects[e]) for e, _ in trial.fit.keys})
    fit = fit_parameters(masked, start, trial.fit.keys, sds_of(start, masked.predict(start)))
    if spots_refused(fit):
        return trial
    fit = replace(fit, picture=WITHOUT_SPOTS)
    delta = chi2_now - chi2_of(frames, fit.model, sds)
    return Trial(delta - trial.n_params * ln_n, delta, trial.n_params, fit)


def _refit_judged(frames, model):
    """:func:`refit_all` of ``model``; where that leaves ``brighter_fatter``
    refused and the pixel-total SCENEs hold single-pixel sources, the refit
    without them when it holds there (:func:`judged_without_spots`). Returns
    the fit and the blocks it was made on."""
    refit = refit_all(frames, model)
    if not spots_refused(refit):
        return refit, frames
    masked = frames.without_single_pixel_sources()
    if masked is None:
        return refit, frames
    alt = refit_all(masked, model)
    if spots_refused(alt):
        return refit, frames
    return replace(alt, picture=WITHOUT_SPOTS), masked


@dataclass(frozen=True)
class Joined:
    """A candidate joined to the model (:func:`join`): the joint refit
    ``fit``, its prediction ``parts`` and gap ``gap_after``; ``dropped`` the
    earlier effects whose work it now does and ``fragile`` those only the
    smooth picture of pixel-total light needed, each ``(effect, params,
    delta BIC of keeping it)``."""

    fit: FitResult
    parts: list
    gap_after: float
    dropped: tuple = ()
    fragile: tuple = ()

    @property
    def gone(self):
        """The names of the ``fragile`` effects."""
        return {name for name, _, _ in self.fragile}


def join(frames, model, name, threshold=EVIDENCE_THRESHOLD):
    """``model`` (a candidate ``name``'s fit) with every parameter refitted
    (:func:`refit_all`), less what that lets go: an earlier effect whose work
    the newcomer now does (:func:`prune`: its parameters fall back to "off" or
    to values the data no longer need), and with pixel-total scenes what only
    the smooth picture of their light needs (:func:`only_with_smooth_light`;
    when that is ``name`` itself, nothing is taken out). Returns a :class:`Joined`.
    """
    refit, used = _refit_judged(frames, model)
    kept, dropped = prune(used, refit.model, threshold, keep=(name,))
    if dropped:
        refit, used = _refit_judged(frames, kept)
    fragile = only_with_smooth_light(frames, refit.model, threshold)
    gone = {e for e, _, _ in fragile}
    if fragile and name not in gone:
        smooth = refit.model.effects
        fragile = [(e, dict(smooth[e]), worth) for e, _, worth in fragile]
        refit = refit_all(frames, replace(refit.model, effects={
            e: p for e, p in smooth.items() if e not in gone}))
    parts = frames.predict(refit.model)
    return Joined(refit, parts, gap(frames.residuals(refit.model, parts)[0]), tuple(dropped),
                  tuple(fragile))


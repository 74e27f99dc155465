"""The law fitted to what was measured: geometry weights and a symmetric alpha(S, N).

Inputs are points ``(S, N, direction) -> w(direction) alpha(S, N)`` with
errors: hot pixels give ``N`` = their dark background (``alpha(S, 0)``, a row
of the law), flats give ``N = S`` (``alpha(S, S)``, its diagonal).

1. **Geometry.** The weights are ratios between directions, assumed the same
   at every signal (the model's geometry multiplies one law): for each
   direction the weighted mean of ``value / mean(x, y)`` over all points;
   ``x`` and ``y`` are scaled so that their mean is 1 (alpha is then the mean
   nearest-neighbour coupling). A weight that comes out negative is set to 0
   and said in the result.
2. **Law.** The nearest-neighbour points divided by their weights are fitted
   by each form:

   - ``constant``: one number;
   - ``smooth(dh, dd)``: a tabulated symmetric law built from two smooth
     curves, polynomials of degree ``dh`` and ``dd`` in ``log10 S``:
     ``h(S) = alpha(S, 0)`` and ``d(S) = alpha(S, S)``, joined by the
     asymmetry ``t = |S-N| / (S+N)``:
     ``alpha(S, N) = (1 - t) d((S+N)/2) + t h(S+N)``. Symmetric by
     construction, exact on both cross-sections, free to rise or fall;
   - ``total(deg)``: ``P(S + N) + c t``, the coupling of a pair set by its
     total charge, so both cross-sections constrain one curve;
   - ``donlon2018_free``: the paper's family ``a exp(-|S-N|/s_d) +
     b exp(-sqrt(S^2+N^2)/s_l) + c`` with free amplitudes of either sign and
     free scales, fitted and scored but never chosen (:data:`SCORED_ONLY`).

   The form is chosen by **held-out evidence** (:func:`choose_law`): each
   form is fitted on all folds of the data but one (hot pixels by position,
   flat-ramp blocks, stripes of one-level flats) and scored on the fold left
   out. The constant is kept unless some form predicts the held-out points
   better by :data:`MARGIN` standard errors; then the form that predicts
   them best is chosen, monotone where it is well measured unless a
   non-monotone one wins by the same margin. Chi^2 on the fitted points (and
   BIC) are reported, not used: with errors that are too small they reward
   wiggles. Each curve is held at its end value beyond the range of its
   well-measured points, and outside the measured ``S + N`` the result says
   the law is held.

   With only one cross-section measured, the other is assumed to follow the
   same function of ``S + N`` (``alpha(S, S) = alpha(2S, 0)``), and the result
   says so. The paper's own law is scored too (no free parameter), for
   comparison.
"""

import math

import numpy as np
from scipy.optimize import least_squares

from ..geometry import Geometry
from ..laws import ParametricLaw, TabulatedLaw, donlon2018

__all__ = ["FORMS", "MARGIN", "geometry_weights", "choose_law", "fit_law", "fit_forms",
           "model_of", "smooth_law", "SmoothLaw"]

FORMS = ("constant", "donlon2018_free", "smooth")
_AXES = ("x", "y", "diagonal", "second_x", "second_y")


def _points(hot_rows, flat_rows):
    """Rows of (S, N, {axis: (value, error)}, source)."""
    pts = []
    for r in hot_rows or ():
        vals = {a: (r[a]["value"], r[a]["error"]) for a in _AXES if a in r}
        pts.append((r["signal"], max(r.get("background", 0.0), 0.0), vals, "hot"))
    for r in flat_rows or ():
        if not r.get("terms"):
            continue
        vals = {a: (r["terms"][a]["value"], r["terms"][a]["error"]) for a in _AXES}
        pts.append((r["level"], r["level"], vals, "flat"))
    return [p for p in pts if all(np.isfinite(v[0]) and np.isfinite(v[1]) and v[1] > 0
                                  for k, v in p[2].items() if k in ("x", "y"))]


def geometry_weights(points):
    """Weights per direction (mean of x and y = 1) with errors and notes."""
    notes = []
    weights, errors = {}, {}
    for axis in _AXES:
        num, den = 0.0, 0.0
        for _, _, vals, _ in points:
            a = 0.5 * (vals["x"][0] + vals["y"][0])
            if a <= 0 or axis not in vals or not np.isfinite(vals[axis][1]):
                continue
            r, e = vals[axis][0] / a, vals[axis][1] / a
            w = 1.0 / max(e, 1e-12) ** 2
            num += w * r
            den += w
        weights[axis] = num / den if den else 0.0
        errors[axis] = 1.0 / math.sqrt(den) if den else float("nan")
    if not (weights["x"] > 0 and weights["y"] > 0):  # no coupling to divide by
        raise ValueError("no interpixel coupling measured: the nearest-neighbour alpha is not "
                         "above zero along both x and y (a detector or simulation without "
                         "IPC, or too few measured points)")
    scale = 0.5 * (weights["x"] + weights["y"])
    for axis in _AXES:
        weights[axis] /= scale
        errors[axis] /= scale
        if weights[axis] < 0:
            notes.append(f"{axis} weight measured {weights[axis]:.3g} < 0, set to 0")
            weights[axis] = 0.0
    return weights, errors, notes


def _nn_alpha(points, weights):
    """alpha = the x and y values over their weights, combined by their errors."""
    S, N, A, E, src = [], [], [], [], []
    for s, n, vals, source in points:
        ax, ex = vals["x"][0] / weights["x"], vals["x"][1] / weights["x"]
        ay, ey = vals["y"][0] / weights["y"], vals["y"][1] / weights["y"]
        wx, wy = 1 / ex ** 2, 1 / ey ** 2
        S.append(s)
        N.append(n)
        A.append((wx * ax + wy * ay) / (wx + wy))
        E.append(1 / math.sqrt(wx + wy))
        src.append(source)
    return np.array(S), np.array(N), np.array(A), np.array(E), np.array(src)


class SmoothLaw:
    """``alpha(S,N) = (1-t) d((S+N)/2) + t h(S+N) + c t``, ``t = |S-N|/(S+N)``,
    with ``h`` and ``d`` polynomials in ``log10`` of the signal, held constant
    outside their ranges. ``h`` or ``d`` may be None (then the other is used
    for both, as a function of ``S + N``); ``c`` is ``asymmetry`` (0 but in
    the ``total`` forms)."""

    def __init__(self, h=None, d=None, h_range=None, d_range=None, asymmetry=0.0):
        self.h, self.d, self.h_range, self.d_range = h, d, h_range, d_range
        self.asymmetry = float(asymmetry)

    @staticmethod
    def _poly(coef, rng, s):
        u = np.log10(np.clip(np.asarray(s, float), rng[0], rng[1]))
        return np.polyval(coef, u - math.log10(rng[0]))

    def curve_h(self, total):
        if self.h is None:
            return self._poly(self.d, self.d_range, 0.5 * np.asarray(total, float))
        return self._poly(self.h, self.h_range, total)

    def curve_d(self, level):
        if self.d is None:
            return self._poly(self.h, self.h_range, 2.0 * np.asarray(level, float))
        return self._poly(self.d, self.d_range, level)

    def __call__(self, s, n):
        s = np.maximum(np.asarray(s, float), 0.0)
        n = np.maximum(np.asarray(n, float), 0.0)
        total = s + n
        t = np.where(total > 0, np.abs(s - n) / np.where(total > 0, total, 1.0), 0.0)
        return (1 - t) * self.curve_d(0.5 * total) + t * self.curve_h(total) + self.asymmetry * t


def _design(S, deg, rng):
    u = np.log10(np.clip(S, rng[0], rng[1])) - math.log10(rng[0])
    return np.stack([u ** (deg - j) for j in range(deg + 1)], axis=1)


def _well_measured(S, E, sel):
    """Signal range of the points of ``sel`` whose errors are within 3x their
    median: a curve is held constant beyond it (one noisy point at the end
    of the range must not bend a polynomial)."""
    if not sel.any():
        return None
    well = sel & (E <= 3.0 * np.median(E[sel]))
    return (max(float(S[well].min()), 1.0), float(S[well].max()))


def _fit_smooth(S, N, A, E, src, dh, dd):
    hot, flat = src == "hot", src == "flat"
    h_range = _well_measured(S, E, hot)
    d_range = _well_measured(S, E, flat)
    total = S + N
    t = np.where(total > 0, np.abs(S - N) / total, 0.0)
    cols = []
    if hot.any():
        cols.append(t[:, None] * _design(total, dh, h_range) if flat.any()
                    else _design(total, dh, h_range))
    if flat.any():
        cols.append((1 - t)[:, None] * _design(0.5 * total, dd, d_range) if hot.any()
                    else _design(0.5 * total, dd, d_range))
    X = np.concatenate(cols, axis=1) / E[:, None]
    y = A / E
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    cov = np.linalg.pinv(X.T @ X)
    nh = dh + 1 if hot.any() else 0
    law = SmoothLaw(coef[:nh] if hot.any() else None, coef[nh:] if flat.any() else None,
                    h_range, d_range)
    model = law(S, N)
    # error of the model at each point, from the coefficients' covariance
    Xraw = X * E[:, None]
    model_err = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", Xraw, cov, Xraw), 0, None))
    return law, coef.size, model, model_err, {"h_coefficients": coef[:nh].tolist(),
                                              "d_coefficients": coef[nh:].tolist(),
                                              "h_range": h_range, "d_range": d_range,
                                              "coefficient_errors": np.sqrt(np.diag(cov)).tolist()}


def _fit_total(S, N, A, E, degree):
    """The ``total(deg)`` form: ``alpha = P(S + N) + c t``, a polynomial of
    degree ``deg`` in ``log10(S + N)`` plus a constant step between the
    diagonal (``t = 0``) and the edge (``t = 1``): the coupling of a pair set
    by its total charge. Both cross-sections then constrain one curve."""
    total = S + N
    t = np.where(total > 0, np.abs(S - N) / total, 0.0)
    rng = _well_measured(total, E, np.ones(S.size, bool))
    X = np.concatenate([_design(total, degree, rng), t[:, None]], axis=1) / E[:, None]
    coef, *_ = np.linalg.lstsq(X, A / E, rcond=None)
    cov = np.linalg.pinv(X.T @ X)
    law = SmoothLaw(coef[:-1], None, rng, None, asymmetry=coef[-1])
    Xraw = X * E[:, None]
    model_err = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", Xraw, cov, Xraw), 0, None))
    return law, coef.size, law(S, N), model_err, {
        "total_coefficients": coef[:-1].tolist(), "asymmetry": float(coef[-1]),
        "total_range": rng, "coefficient_errors": np.sqrt(np.diag(cov)).tolist()}


def _fit_donlon(S, N, A, E):
    def alpha(p, s, n):
        a, sd, b, sl, c = p
        return (a * np.exp(-np.abs(s - n) / sd) + b * np.exp(-np.sqrt(s * s + n * n) / sl) + c)

    def resid(p):
        r = (alpha(p, S, N) - A) / E
        penalty = min(p[0], 0) + min(p[2], 0) + p[4]
        return np.append(r, 1e6 * min(penalty, 0.0))

    best = None
    c0 = float(np.median(A))
    for sd in (3e3, 2e4, 1e5):
        for sl in (3e3, 3e4, 2e5):
            for sign in (1.0, -1.0):
                p0 = [sign * 0.2 * c0, sd, -sign * 0.2 * c0, sl, c0]
                try:
                    fit = least_squares(resid, p0, bounds=([-1, 100, -1, 100, 0],
                                                           [1, 1e7, 1, 1e7, 1]),
                                        x_scale=[1e-3, sd, 1e-3, sl, 1e-3])
                except ValueError:
                    continue
                if best is None or fit.cost < best.cost:
                    best = fit
    p = best.x
    try:
        cov = np.linalg.pinv(best.jac[:-1].T @ best.jac[:-1])
        perr = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        cov, perr = None, np.full(5, np.nan)
    model = alpha(p, S, N)
    if cov is not None:
        J = best.jac[:-1] * E[:, None]
        model_err = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", J, cov, J), 0, None))
    else:
        model_err = np.full_like(model, np.nan)
    a, sd, b, sl, c = (float(v) for v in p)
    if min(a, 0) + min(b, 0) + c < 0:
        c = -(min(a, 0) + min(b, 0))
    law = ParametricLaw(a, sd, b, sl, c, name="calibrated:donlon2018_free")
    return law, 5, model, model_err, {"parameters": dict(zip(
        ("amp_diff", "scale_diff", "amp_level", "scale_level", "floor"), p.tolist())),
        "parameter_errors": perr.tolist()}


def smooth_law(law, signal_max, n=161, name="calibrated:smooth"):
    """The :class:`SmoothLaw` sampled onto a :class:`TabulatedLaw` grid from 0 to ``signal_max``."""
    return TabulatedLaw.from_callable(law, signal_range=(0.0, float(signal_max)), n=n, name=name)


MARGIN = 2.0
"""A richer law must beat a simpler one on held-out points by this many
standard errors of the difference (:func:`choose_law`)."""


FEW_FOLDS = 5
"""Below this many scored folds the held-out comparison also uses the
scatter over points (:meth:`_HeldOut.margin`)."""


def _held(func, lo, hi):
    """``func`` held outside ``lo <= S + N <= hi``: the arguments are scaled
    along their ray so their sum is clipped into the range (the law is not
    extrapolated where nothing was measured)."""
    def held(s, n):
        s, n = np.asarray(s, float), np.asarray(n, float)
        total = s + n
        safe = np.where(total > 0, total, 1.0)
        scale = np.clip(safe, lo, hi) / safe
        return func(np.where(total > 0, s * scale, 0.5 * lo),
                    np.where(total > 0, n * scale, 0.5 * lo))
    return held


SCORED_ONLY = "donlon2018_free"
"""Forms fitted and scored beside the others but never chosen: the paper's
family fixes the law between the two measured cross-sections by the paper's
own invented shape, where the ``smooth`` forms make one stated assumption
(linear in the asymmetry ``t``)."""

def _monotone(func, S, N, E, src):
    """Whether each measured cross-section of ``func`` is monotone where it is
    well measured (points with errors within 3x the median): a turn back
    smaller than the median error there, or one that follows a single point
    of large error at the end of the range, is not a wiggle the data demand."""
    for kind in ("hot", "flat"):
        sel = src == kind
        if not sel.any():
            continue
        well = sel & (E <= 3.0 * np.median(E[sel]))
        grid = np.geomspace(max(S[well].min(), 1.0), max(S[well].max(), 2.0), 64)
        neighbour = np.full_like(grid, float(np.median(N[sel]))) if kind == "hot" else grid
        f = np.asarray(func(grid, neighbour), float)
        trend = f if f[-1] >= f[0] else -f
        turned_back = float(np.max(np.maximum.accumulate(trend) - trend))
        if turned_back > float(np.median(E[well])):
            return False
    return True


def fit_forms(hot_rows, flat_rows, max_degree=3):
    """Every form fitted to the points of ``hot_rows`` and ``flat_rows``.

    Returns
    -------
    dict or None
        ``weights``, ``weight_errors``, ``notes``, the points (``S``, ``N``,
        ``A``, ``E``, ``src``) and ``forms``: name -> ``{"k", "alpha"
        (callable, held outside the measured range), "model", "model_error",
        "info", "monotone"}``; None when there is no point.
    """
    points = _points(hot_rows, flat_rows)
    if not points:
        return None
    weights, werr, notes = geometry_weights(points)
    S, N, A, E, src = _nn_alpha(points, weights)
    n = len(S)
    total = S + N
    lo, hi = max(float(total.min()), 1.0), float(total.max())
    forms = {}
    c = float(np.sum(A / E ** 2) / np.sum(1 / E ** 2))
    ce = 1 / math.sqrt(np.sum(1 / E ** 2))
    forms["constant"] = {"k": 1, "alpha": lambda s, n, c=c: np.full(np.broadcast(s, n).shape, c),
                         "model": np.full(n, c), "model_error": np.full(n, ce),
                         "info": {"alpha": c, "alpha_error": ce}}
    if n >= 6:
        law, k, model, merr, info = _fit_donlon(S, N, A, E)
        forms["donlon2018_free"] = {"k": k, "alpha": _held(law.alpha, lo, hi), "model": model,
                                    "model_error": merr, "info": info}
    hot, flat = (src == "hot").any(), (src == "flat").any()
    for dh in range(0, max_degree + 1 if hot else 1):
        for dd in range(0, max_degree + 1 if flat else 1):
            law, k, model, merr, info = _fit_smooth(S, N, A, E, src, dh, dd)
            if k >= n:
                continue
            forms[f"smooth({dh},{dd})"] = {"k": k, "alpha": law, "model": model,
                                           "model_error": merr, "info": info}
    if hot and flat:
        for degree in range(0, max_degree + 1):
            law, k, model, merr, info = _fit_total(S, N, A, E, degree)
            if k < n:
                forms[f"total({degree})"] = {"k": k, "alpha": law, "model": model,
                                             "model_error": merr, "info": info}
    for form in forms.values():
        form["monotone"] = _monotone(form["alpha"], S, N, E, src)
    return {"weights": weights, "weight_errors": werr, "notes": notes, "S": S, "N": N, "A": A,
            "E": E, "src": src, "forms": forms, "total_range": (lo, hi)}


class _HeldOut:
    """Held-out chi^2 of every form: per fold (``folds[name]``, inf where the
    form could not be fitted, NaN for every form where the fold held no
    point) and per held-out point (``points[name][f]``)."""

    def __init__(self, points_for, folds, names):
        self.folds = {name: np.full(folds, np.nan) for name in names}
        self.points = {name: [None] * folds for name in names}
        self.fits = {name: [] for name in names}
        self.counts = np.zeros(folds, int)
        for f in range(folds):
            train = fit_forms(*points_for([g for g in range(folds) if g != f]))
            test_points = _points(*points_for([f]))
            if train is None or not test_points:
                continue
            S, N, A, E, _ = _nn_alpha(test_points, train["weights"])
            self.counts[f] = S.size
            for name in names:
                self.folds[name][f] = np.inf  # unless the form could be fitted
                if name in train["forms"]:
                    z2 = ((A - train["forms"][name]["alpha"](S, N)) / E) ** 2
                    self.folds[name][f] = float(np.sum(z2))
                    self.points[name][f] = z2
                    self.fits[name].append(train["forms"][name]["alpha"])

    def total(self, name):
        return float(np.nansum(self.folds[name]))

    def margin(self, a, b):
        """How many standard errors form ``a`` predicts the held-out points
        better than ``b`` by. The error is the scatter of the difference over
        folds; with fewer than :data:`FEW_FOLDS` folds that scatter is itself
        too uncertain, and the larger of it and the scatter over points (each
        point is held out once) is used."""
        fa, fb = self.folds[a], self.folds[b]
        scored = ~np.isnan(fa) & ~np.isnan(fb)
        if scored.sum() < 2 or not (np.isfinite(fa[scored]).all()
                                    and np.isfinite(fb[scored]).all()):
            return float("nan")
        d_fold = fb[scored] - fa[scored]
        d_point = np.concatenate([self.points[b][f] - self.points[a][f]
                                  for f in np.flatnonzero(scored)])
        se = math.sqrt(d_fold.size * np.var(d_fold, ddof=1))
        if d_fold.size < FEW_FOLDS and d_point.size > 1:
            se = max(se, math.sqrt(d_point.size * np.var(d_point, ddof=1)))
        total = float(d_fold.sum())
        return total / se if se > 0 else (float("inf") if total > 0 else 0.0)


def _band(fits, full_alpha, grid, neighbour):
    """The law and its 1-sigma band along ``(grid, neighbour)``: delete-a-fold
    jackknife of the fits on the other folds."""
    centre = np.asarray(full_alpha(grid, neighbour), float)
    if len(fits) < 2:
        return centre, np.full_like(centre, np.nan)
    values = np.array([np.asarray(f(grid, neighbour), float) for f in fits])
    k = len(fits)
    err = np.sqrt((k - 1) / k * np.sum((values - values.mean(axis=0)) ** 2, axis=0))
    return centre, err


def model_of(fitted, name):
    """``(geometry, law)`` of form ``name`` of a :func:`fit_forms` result:
    the constant as a parametric law, every other form sampled onto a table
    (held outside the measured range)."""
    form = fitted["forms"][name]
    w = fitted["weights"]
    geometry = Geometry.terms(horizontal=w["x"], vertical=w["y"], diagonal=w["diagonal"],
                              second_horizontal=w["second_x"], second_vertical=w["second_y"])
    if name == "constant":
        c = form["info"]["alpha"]
        return geometry, ParametricLaw(0.0, 1.0, 0.0, 1.0, c, name=f"calibrated:constant:{c:.6g}")
    smax = max(1.1 * float(np.max(fitted["S"] + fitted["N"])), 65536.0)
    return geometry, smooth_law(form["alpha"], smax, name=f"calibrated:{name}")


def _choose(forms, held, margins):
    """The constant, unless some form predicts held-out points better by
    :data:`MARGIN` standard errors; then the monotone form that predicts
    them best (a non-monotone one only if it beats that by :data:`MARGIN`)."""
    candidates = [n for n, m in margins.items() if m >= MARGIN and not n.startswith(SCORED_ONLY)]
    if not candidates:
        return "constant"
    monotone = [n for n in candidates if forms[n]["monotone"]]
    best = min(candidates, key=held.total)
    if monotone:
        best_monotone = min(monotone, key=held.total)
        if not held.margin(best, best_monotone) >= MARGIN:
            best = best_monotone
    return best


def choose_law(points_for, folds=5, max_degree=3):
    """Fit the geometry and every law form; choose by held-out evidence.

    Each form is fitted on all folds but one and scored (chi^2) on the fold
    left out, in turn. The constant is kept unless a form predicts the
    held-out points better by :data:`MARGIN` standard errors of the
    difference, so a signal dependence is written only where held-out data
    demand it; then the form that predicts them best is chosen (forms whose
    measured cross-sections are monotone preferred: a non-monotone one must
    beat the best monotone one by :data:`MARGIN`).

    Parameters
    ----------
    points_for : callable
        ``points_for(folds)`` -> ``(hot_rows, flat_rows)`` measured on the
        given fold indices only (``None``: all the data).
    folds : int
        Number of folds (hot pixels by position, flat-ramp blocks).
    max_degree : int
        Highest polynomial degree of the ``smooth`` forms.

    Returns
    -------
    geometry : Geometry
    law : ParametricLaw or TabulatedLaw
    fit : dict
        ``chosen``, ``forms`` (per form: ``k``, ``chi2``, ``bic``,
        ``held_out`` chi^2, ``monotone``, its fit's parameters), the
        ``law_choice`` record (``held_out`` per form, margins against the
        constant, ``constant_fits_as_well``), ``band`` (the law and its
        error along ``(S, 0)`` and ``(S, S)``), ``weights``, ``points`` (per
        measured point: source, S, N, measured, model, pull), ``assumed``,
        ``held_outside``, ``notes``.
    """
    full = fit_forms(*points_for(None), max_degree=max_degree)
    if full is None:
        raise ValueError("nothing to fit: no measured point (no isolated hot pixel and no "
                         "usable flat level)")
    S, N, A, E, src = full["S"], full["N"], full["A"], full["E"], full["src"]
    forms = full["forms"]
    held = _HeldOut(points_for, folds, list(forms))
    margins = {name: held.margin(name, "constant") for name in forms if name != "constant"}
    chosen = _choose(forms, held, margins)
    form = forms[chosen]
    geometry, law = model_of(full, chosen)
    grid = np.geomspace(max(float(S.min()) * 0.5, 10.0), float(S.max()) * 1.5, 48)
    band = {"signal": grid.tolist()}
    for key, neighbour in (("alpha_s0", 0.0 * grid), ("alpha_ss", grid)):
        centre, err = _band(held.fits[chosen], form["alpha"], grid, neighbour)
        band[key] = centre.tolist()
        band[key + "_error"] = err.tolist()
    best_other = min((n for n in forms if n != "constant"), key=held.total, default=None)
    constant_as_well = chosen == "constant" or not held.margin(chosen, "constant") >= MARGIN
    choice = {"chosen": chosen, "folds": int(folds), "margin": MARGIN,
              "held_out_points": held.counts.tolist(),
              "held_out": {n: {"score": held.total(n), "per_fold": held.folds[n].tolist()}
                           for n in forms},
              "margin_against_constant": margins,
              "best_richer_form": best_other,
              "constant_fits_as_well": bool(constant_as_well)}
    table = {}
    for name, f in forms.items():
        chi2 = float(np.sum(((f["model"] - A) / E) ** 2))
        table[name] = {"k": f["k"], "chi2": chi2, "bic": chi2 + f["k"] * math.log(len(S)),
                       "held_out": held.total(name), "monotone": f["monotone"],
                       **f["info"]}
    paper = donlon2018().alpha(S, N)
    table["donlon2018 (the paper's law, not fitted)"] = {
        "k": 0, "chi2": float(np.sum(((paper - A) / E) ** 2))}
    assumed = []
    if not (src == "flat").any():
        assumed.append("no flat measured: alpha(S,S) assumed equal to alpha(2S,0) "
                       "(the law taken as a function of S+N)")
    if not (src == "hot").any():
        assumed.append("no hot pixel measured: alpha(S,0) assumed equal to alpha(S/2,S/2) "
                       "(the law taken as a function of S+N)")
    lo, hi = full["total_range"]
    held = {"total_signal_range": [lo, hi],
            "note": f"outside {lo:.4g} <= S+N <= {hi:.4g} e- nothing was measured: the law is "
                    "held at its value at the end of the range, not extrapolated"}
    model = form["model"]
    rows = [{"source": src[i], "signal": float(S[i]), "neighbour": float(N[i]),
             "alpha_measured": float(A[i]), "error": float(E[i]),
             "alpha_model": float(model[i]), "model_error": float(form["model_error"][i]),
             "pull": float((A[i] - model[i]) / E[i])} for i in range(len(S))]
    fit = {"chosen": chosen, "law": law.describe(), "forms": table, "law_choice": choice,
           "band": band, "weights": full["weights"], "weight_errors": full["weight_errors"],
           "points": rows, "assumed": assumed, "held_outside": held, "notes": full["notes"],
           "chi2_per_point": float(table[chosen]["chi2"] / len(S)), "n_points": len(S)}
    return geometry, law, fit


def fit_law(hot_rows, flat_rows, max_degree=3):
    """:func:`choose_law` on points without a fold structure of their own:
    the rows are split into two interleaved folds (by their order, i.e. by
    signal), which tests whether a dependence on signal predicts the
    neighbouring points."""
    def points_for(folds):
        if folds is None:
            return hot_rows, flat_rows
        keep = set(folds)
        return ([r for i, r in enumerate(hot_rows or ()) if i % 2 in keep],
                [r for i, r in enumerate(flat_rows or ()) if i % 2 in keep])
    return choose_law(points_for, folds=2, max_degree=max_degree)

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
   by each form, and the forms are compared by the Bayesian information
   criterion ``BIC = chi^2 + k ln n`` (the lowest wins):

   - ``constant``: one number;
   - ``donlon2018_free``: the paper's family ``a exp(-|S-N|/s_d) +
     b exp(-sqrt(S^2+N^2)/s_l) + c`` with free amplitudes of either sign
     and free scales (alpha >= 0 enforced: ``min(a,0) + min(b,0) + c >= 0``);
   - ``smooth(dh, dd)``: a tabulated symmetric law built from two smooth
     curves, polynomials of degree ``dh`` and ``dd`` in ``log10 S``:
     ``h(S) = alpha(S, 0)`` and ``d(S) = alpha(S, S)``, joined by the
     asymmetry ``t = |S-N| / (S+N)``:
     ``alpha(S, N) = (1 - t) d((S+N)/2) + t h(S+N)``. Symmetric by
     construction, exact on both cross-sections, free to rise or fall;
     outside the measured signals each curve is held at its end value.

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

__all__ = ["FORMS", "geometry_weights", "fit_law", "smooth_law", "SmoothLaw"]

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
    """``alpha(S,N) = (1-t) d((S+N)/2) + t h(S+N)``, ``t = |S-N|/(S+N)``, with ``h``
    and ``d`` polynomials in ``log10`` of the signal, held constant outside
    their ranges. ``h`` or ``d`` may be None (then the other is used for both,
    as a function of ``S + N``)."""

    def __init__(self, h=None, d=None, h_range=None, d_range=None):
        self.h, self.d, self.h_range, self.d_range = h, d, h_range, d_range

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
        return (1 - t) * self.curve_d(0.5 * total) + t * self.curve_h(total)


def _design(S, deg, rng):
    u = np.log10(np.clip(S, rng[0], rng[1])) - math.log10(rng[0])
    return np.stack([u ** (deg - j) for j in range(deg + 1)], axis=1)


def _fit_smooth(S, N, A, E, src, dh, dd):
    hot, flat = src == "hot", src == "flat"
    h_range = (max(S[hot].min(), 1.0), S[hot].max()) if hot.any() else None
    d_range = (max(S[flat].min(), 1.0), S[flat].max()) if flat.any() else None
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


def fit_law(hot_rows, flat_rows, max_degree=3):
    """Fit the geometry and every law form; choose by BIC.

    Returns
    -------
    geometry : Geometry
    law : ParametricLaw or TabulatedLaw
    fit : dict
        ``chosen``, ``forms`` (each: ``k``, ``chi2``, ``bic``), ``weights``,
        ``weight_errors``, ``points`` (per measured point: source, S, N, measured,
        model, model error, pull), ``assumed``, ``notes``.
    """
    points = _points(hot_rows, flat_rows)
    if not points:
        raise ValueError("nothing to fit: no measured point (no isolated hot pixel and no "
                         "usable flat level)")
    weights, werr, notes = geometry_weights(points)
    S, N, A, E, src = _nn_alpha(points, weights)
    n = len(S)
    candidates = []
    c = float(np.sum(A / E ** 2) / np.sum(1 / E ** 2))
    candidates.append(("constant", 1, np.full(n, c), np.full(n, 1 / math.sqrt(np.sum(1 / E ** 2))),
                       {"alpha": c}, lambda: ParametricLaw(0.0, 1.0, 0.0, 1.0, c,
                                                           name=f"calibrated:constant:{c:.6g}")))
    if n >= 6:
        law, k, model, merr, info = _fit_donlon(S, N, A, E)
        candidates.append(("donlon2018_free", k, model, merr, info, lambda law=law: law))
    smax = 1.1 * float(np.max(S + N))
    for dh in range(0, max_degree + 1):
        for dd in range(0, max_degree + 1):
            if (src == "hot").any() and not (src == "flat").any() and dd:
                continue
            if (src == "flat").any() and not (src == "hot").any() and dh:
                continue
            law, k, model, merr, info = _fit_smooth(S, N, A, E, src, dh, dd)
            if k >= n:
                continue
            candidates.append((f"smooth({dh},{dd})", k, model, merr, info,
                               lambda law=law: smooth_law(law, max(smax, 65536.0))))
    forms = {}
    for name, k, model, _merr, info, _ in candidates:
        chi2 = float(np.sum(((model - A) / E) ** 2))
        forms[name] = {"k": k, "chi2": chi2, "bic": chi2 + k * math.log(n), **info}
    paper = donlon2018().alpha(S, N)
    forms["donlon2018 (the paper's law, not fitted)"] = {
        "k": 0, "chi2": float(np.sum(((paper - A) / E) ** 2))}
    chosen = min((c for c in candidates), key=lambda c: forms[c[0]]["bic"])
    name, k, model, merr, info, make = chosen
    law = make()
    geometry = Geometry.terms(horizontal=weights["x"], vertical=weights["y"],
                              diagonal=weights["diagonal"],
                              second_horizontal=weights["second_x"],
                              second_vertical=weights["second_y"])
    assumed = []
    if not (src == "flat").any():
        assumed.append("no flat measured: alpha(S,S) assumed equal to alpha(2S,0) "
                       "(the law taken as a function of S+N)")
    if not (src == "hot").any():
        assumed.append("no hot pixel measured: alpha(S,0) assumed equal to alpha(S/2,S/2) "
                       "(the law taken as a function of S+N)")
    rows = []
    for i in range(n):
        rows.append({"source": src[i], "signal": float(S[i]), "neighbour": float(N[i]),
                     "alpha_measured": float(A[i]), "error": float(E[i]),
                     "alpha_model": float(model[i]), "model_error": float(merr[i]),
                     "pull": float((A[i] - model[i]) / E[i])})
    fit = {"chosen": name, "law": law.describe(), "forms": forms, "weights": weights,
           "weight_errors": werr, "points": rows, "assumed": assumed, "notes": notes,
           "chi2_per_point": float(forms[name]["chi2"] / n), "n_points": n}
    return geometry, law, fit

"""The joint fit of flat ramps' covariances, its jackknife errors and its reports.

The model is :class:`~.rampmodel.RampCovariance`; the data are the sums of
:mod:`.rampsums`, per spatial block, held by :class:`.ramps.FlatRamps`, which
calls :func:`fit_increments` on all blocks and on each leave-one-out subset.
The errors are the jackknife over those fits (:func:`jackknife`), never a
formula. The reports turn the fits into the measured quantities with their
significance (detection: :data:`DETECTION` sigma); the per-level points
(:func:`level_point`) solve the covariances of one level, everything but the
IPC term removed, for the kernel at that level.
"""

import numpy as np
from scipy import special
from scipy.optimize import least_squares

from ..errors import IPCInputError
from .flats import TERMS, solve_kernel
from .rampmodel import (
    SYMMETRIC_LAGS,
    TERM_CLASSES,
    RampCovariance,
    kernel_from_symmetric,
    mean_ramp,
    with_zero_sum,
)

__all__ = ["fit_increments", "jackknife", "jackknife_errors", "DETECTION", "read_noise_report",
           "ipc_report", "nonlinearity_report", "nonlinear_ipc_report", "bf_report",
           "public_params", "internal_params", "level_note", "level_point"]

DETECTION = 5.0
"""Significance (sigma) at or above which an effect is reported detected."""

_SCALES = {"r": 1.0, "s2": 100.0, "k0": 1e-2, "k1": 1e-6, "a": 1e-6, "common": 10.0}


# ---------------------------------------------------------------------- fit helpers
def jackknife(samples):
    """Jackknife covariance of leave-one-out estimates (samples, ...)."""
    s = np.asarray(samples, dtype=np.float64)
    n = s.shape[0]
    dev = (s - s.mean(axis=0)).reshape(n, -1)
    return (n - 1.0) / n * dev.T @ dev


def _sigma_from_chi2(chi2, dof):
    """Gaussian-equivalent significance of a chi^2 with ``dof`` degrees of freedom."""
    from scipy.stats import chi2 as chi2_dist

    x = max(float(chi2), 0.0)
    logp = chi2_dist.logsf(x, dof)
    if not np.isfinite(logp):  # far tail: the leading term of the asymptotic series
        logp = -x / 2 + (dof / 2 - 1) * np.log(x / 2) - special.gammaln(dof / 2)
    return float(-special.ndtri_exp(logp)) if logp < np.log(0.5) else 0.0


def _start(cov, current, nints):
    """Starting parameters from the data."""
    g = cov.shape[-1]
    diag0 = np.diagonal(cov[0])
    s2 = max(-np.mean(np.diagonal(cov[0], offset=1)), 0.0) if g > 1 else 0.0
    shot = max(np.mean(diag0) - 2 * s2, 1e-3 * current)
    k0 = np.array([np.mean(np.diagonal(cov[c])) / (2 * shot) for c in TERM_CLASSES])
    return {"r": current / shot, "s2": s2, "k0": k0, "k1": np.zeros(5), "a": np.zeros(9),
            "common": np.zeros(18) if nints == 1 else None}


def _pack(p, fixed, nints):
    """Free parameter names (name, index) and their scaled start vector."""
    names = []
    for name, size in (("r", None), ("s2", None), ("k0", 5), ("k1", 5)):
        if name not in fixed:
            names += [(name, None)] if size is None else [(name, i) for i in range(size)]
    if "a" not in fixed:
        names += [("a", i) for i in range(1, 9)]  # a(0,0) from sum a = 0
    if nints == 1:
        names += [("common", i) for i in range(18)]
    x0 = np.array([(p[n] if i is None else p[n][i]) / _SCALES[n] for n, i in names])
    return names, x0


def _unpack(x, names, p0, fixed):
    """Parameters from the scaled vector."""
    p = {k: (np.array(v, dtype=np.float64) if isinstance(v, np.ndarray) else v)
         for k, v in p0.items()}
    p.update({k: (np.array(v) if isinstance(v, np.ndarray) else v) for k, v in fixed.items()})
    for value, (name, i) in zip(x, names, strict=True):
        if i is None:
            p[name] = value * _SCALES[name]
        else:
            p[name][i] = value * _SCALES[name]
    p["a"] = with_zero_sum(p["a"])
    return p


def jackknife_errors(jack):
    """``errors(name, index=None)``: jackknife standard error of a parameter."""
    def errors(name, index=None):
        if len(jack) < 3:
            return None
        vals = [j[name] if index is None else j[name][index] for j in jack]
        return float(np.sqrt(jackknife(vals)[0, 0]))
    return errors


def _scaled(value, factor):
    return None if value is None else float(value * factor)


def _significance(value, error):
    return None if error is None or not error > 0 else float(value / error)


# ---------------------------------------------------------------------- the fit
def fit_increments(data, fixed, n_groups, n_integrations, steps=None, start=None,
                   read_noise=None):
    """Weighted least squares of the increment covariances.

    Parameters
    ----------
    data : tuple
        Summed statistics of some blocks: symmetric covariances (9, G', G'),
        counts (9,), the mean increments' sums (nints, G'), pixels (what
        :class:`.ramps.FlatRamps` sums for them).
    fixed : dict
        Parameters held fixed (:func:`~.rampmodel.variant_fixed`, a given
        brighter-fatter kernel).
    n_groups, n_integrations : int
    steps : int or None
        Collection steps per group (:class:`~.rampmodel.RampCovariance`).
    start : dict, optional
        Starting parameters (default: from the data).
    read_noise : float, optional
        Read noise per read [e-], held fixed when given.

    Returns
    -------
    dict
        The parameters (``r``, ``s2``, ``k0``, ``k1``, ``a``, ``common``) with
        ``current``, ``beta``, ``steps`` and ``chi2_per_dof``.
    """
    cov, counts, incs, npix = data
    current, beta = mean_ramp(incs.sum(axis=0), npix * n_integrations)
    model = RampCovariance(n_groups, current, beta, steps)
    iu = np.triu_indices(n_groups - 1)
    target = cov[:, iu[0], iu[1]]
    diag = np.diagonal(cov[0])
    # independent products: a lag other than 0 between two different
    # increments is seen in both orders; the pattern subtraction costs 1/n
    orders = np.ones((9, iu[0].size))
    orders[1:, iu[0] != iu[1]] = 2.0
    kept = (n_integrations - 1.0) / n_integrations if n_integrations > 1 else 1.0
    sigma = np.sqrt(((diag[iu[0]] * diag[iu[1]])[None, :] + target ** 2)
                    / (kept * counts[:, None] * orders))
    p0 = start if start is not None else _start(cov, current, n_integrations)
    if read_noise is not None:
        p0 = dict(p0, s2=float(read_noise) ** 2)
        fixed = dict(fixed, s2=p0["s2"])
    names, x0 = _pack(p0, fixed, n_integrations)

    def residual(x):
        p = _unpack(x, names, p0, fixed)
        return ((model.increments(p)[iu[0], iu[1], :].T - target) / sigma).ravel()

    fit = least_squares(residual, x0, method="lm", x_scale=1.0, xtol=1e-12, ftol=1e-12)
    p = _unpack(fit.x, names, p0, fixed)
    dof = max(target.size - len(fit.x), 1)
    p.update(current=float(current), beta=float(beta), steps=steps,
             chi2_per_dof=float(2 * fit.cost / dof))
    return p


# ---------------------------------------------------------------------- reports
def read_noise_report(full, errors, given):
    """The read noise per read [e-]: ``given`` (not None), or fitted with its
    jackknife error (``errors``: :func:`jackknife_errors`)."""
    sigma = np.sqrt(max(full["s2"], 0.0))
    s_err = errors("s2")
    return {
        "value": float(sigma),
        "error": None if given is not None else (
            float(s_err / (2 * sigma)) if sigma > 0 and s_err is not None else s_err),
        "source": "given" if given is not None else
        "fitted (covariance of consecutive increments)"}


def ipc_report(full, errors):
    """The five IPC terms at zero charge and their slopes per 10 ke-, with their
    jackknife errors."""
    return {"terms": {t: {"value": float(full["k0"][i]),
                          "error": errors("k0", i),
                          "slope_per_10ke": float(1e4 * full["k1"][i]),
                          "slope_error": _scaled(errors("k1", i), 1e4)}
                      for i, t in enumerate(TERMS)}}


def nonlinearity_report(full, jack, errors, integration_betas):
    """Classical non-linearity ``beta`` with its error: the larger of the jackknife
    (``errors``) and the scatter of ``integration_betas`` (or None)."""
    err = errors("beta")
    if integration_betas is not None and err is not None:
        n = integration_betas.size
        err = max(err, float(np.std(integration_betas, ddof=1) / np.sqrt(n)))
    sig = _significance(full["beta"], err)
    return {"measured": err is not None, "beta": float(full["beta"]), "error": err,
            "significance": sig, "detected": bool(sig is not None and abs(sig) >= DETECTION),
            "form": "M = Q - beta Q^2 (Q collected, M measured, e-)",
            "note": "from the curvature of the mean ramp; error: the larger of the jackknife "
                    "over blocks and the scatter between integrations"}


def nonlinear_ipc_report(full, jack, nints):
    """Non-linear IPC: the slope of the nearest terms ``x + y`` per 10 ke-, its
    jackknife error over the fits ``jack`` and whether it is detected."""
    value = float(full["k1"][0] + full["k1"][1]) * 1e4
    err = None
    if len(jack) >= 3:
        err = float(np.sqrt(jackknife([1e4 * (j["k1"][0] + j["k1"][1]) for j in jack])[0, 0]))
    sig = _significance(value, err)
    detected = bool(sig is not None and abs(sig) >= DETECTION)
    note = (f"slope of the nearest terms x + y: {value:+.3g} per 10 ke-"
            + ("" if err is None else f" +- {err:.2g}") + ", fitted beside "
            + ("brighter-fatter" if nints > 1 else "the common brighter-fatter and pattern term"))
    return {"detected": detected, "significance": sig, "slope_per_10ke": value, "error": err,
            "note": note + (": detected" if detected else ": not detected")}


def bf_report(full, jack, nints):
    """Brighter-fatter: its kernel with jackknife errors, the significance of the
    nearest terms and the chi^2 of the kernel (not measured with one integration)."""
    if nints < 2:
        return {"measured": False, "detected": False, "significance": None, "kernel": None,
                "kernel_error": None,
                "note": "brighter-fatter not measured: at least two integrations at one "
                        "illumination are needed to tell it from the fixed pattern (their "
                        "common term was fitted beside the IPC terms and removed)"}
    kernel = kernel_from_symmetric(full["a"]).tolist()
    if len(jack) < 3:
        return {"measured": True, "detected": False, "significance": None, "kernel": kernel,
                "kernel_error": None, "note": "fewer than 3 blocks: no error"}
    cov = jackknife([j["a"] for j in jack])
    err = np.sqrt(np.diag(cov))
    nearest = float(full["a"][1] + full["a"][2])
    nearest_err = float(np.sqrt(jackknife([j["a"][1] + j["a"][2] for j in jack])[0, 0]))
    sig = _significance(nearest, nearest_err)
    free = cov[1:, 1:]
    try:
        chi2 = float(full["a"][1:] @ np.linalg.solve(free, full["a"][1:]))
    except np.linalg.LinAlgError:
        chi2 = float("nan")
    detected = bool(sig is not None and sig >= DETECTION)
    return {"measured": True, "detected": detected, "significance": sig,
            "significance_kind": "nearest terms a(0,1) + a(1,0) over their jackknife error",
            "chi2": chi2, "chi2_sigma": _sigma_from_chi2(chi2, 8) if np.isfinite(chi2) else None,
            "kernel": kernel, "kernel_error": kernel_from_symmetric(err).tolist(),
            "note": "per electron; pixel area 1 + sum_d a(d) Q(p+d); symmetric part: "
                    + ("detected" if detected else "not detected")}


def public_params(p, n_groups):
    """Fit parameters as plain numbers (for :meth:`.ramps.FlatRamps.predict` and JSON)."""
    return {"n_groups": int(n_groups), "current": float(p["current"]),
            "beta": float(p["beta"]), "gain_ratio": float(p["r"]),
            "read_noise_variance": float(p["s2"]),
            "k0": dict(zip(TERMS, map(float, p["k0"]), strict=True)),
            "k1_per_electron": dict(zip(TERMS, map(float, p["k1"]), strict=True)),
            "brighter_fatter": [float(v) for v in p["a"]],
            "common": None if p.get("common") is None else [float(v) for v in p["common"]],
            "collection_steps": p["steps"]}


def internal_params(params):
    """The fit parameters of :func:`public_params`' plain numbers (arrays again)."""
    return {"current": params["current"], "beta": params["beta"], "r": params["gain_ratio"],
            "s2": params["read_noise_variance"],
            "k0": np.array([params["k0"][t] for t in TERMS]),
            "k1": np.array([params["k1_per_electron"][t] for t in TERMS]),
            "a": np.array(params["brighter_fatter"], dtype=np.float64),
            "common": None if params.get("common") is None else np.array(params["common"]),
            "steps": params.get("collection_steps")}


# ---------------------------------------------------------------------- levels
def level_note(nints, given):
    """The sentence saying what was removed from the per-level points."""
    if nints < 2:
        return ("one integration: brighter-fatter not measured and not told from the fixed "
                "pattern; their common term, fitted from the pairs of different increments, "
                "was removed")
    if given:
        return "brighter-fatter removed with the kernel given"
    return "brighter-fatter removed with the kernel measured from the ramps"


def level_point(data, p, n_groups, inc, method):
    """``(V, terms)`` of one level, brighter-fatter and read noise removed.

    ``difference``: ``Cov(M_b - M_0)`` with ``b = inc.size``; ``increments``:
    the mean same-increment covariance of the increments ``inc``.
    """
    cov, counts = data[0], data[1]
    model = RampCovariance(n_groups, p["current"], p["beta"], p["steps"])
    if method == "difference":
        b = inc.size
        clean = cov[:, :b, :b].sum(axis=(1, 2)) - model.excess_of_difference(p, b)
        n = counts
    else:
        same = np.diagonal(cov, axis1=1, axis2=2)[:, inc]
        clean = (same - model.excess_of_increments(p)[:, inc]).mean(axis=1)
        n = counts * inc.size
    err = np.sqrt((clean[0] ** 2 + clean ** 2) / n)
    entries = {f"{dy},{dx}": {"cov": float(clean[c]), "error": float(err[c])}
               for c, (dy, dx) in enumerate(SYMMETRIC_LAGS)}
    entries["1,-1"] = entries["1,1"]
    try:
        solved = solve_kernel(entries, 0.0)
    except IPCInputError:
        return None
    return solved["V"], np.array([solved["terms"][t]["value"] for t in TERMS])

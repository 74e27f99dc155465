"""Flat fields: alpha(S, S) per axis from the covariance of their noise.

In a flat of level ``S`` the collected charge of each pixel is ``S`` plus
independent shot noise of variance ``V`` (``V = S`` in electrons). Coupling
moves charge between neighbours; for a noise fluctuation ``n`` the measured
change of neighbour ``q`` is ``dM_q/dS_p n_p`` with

    dM_q / dS_p = w(d) [alpha(S, S) + (S_p - S_q) d1 alpha] = w(d) alpha(S, S)

on a flat (``S_p = S_q``; the law's symmetry makes even the kink of an
``|S - N|`` term drop out). So the noise of a flat is the shot noise
convolved with the constant kernel ``K`` whose off-centre entries are
``k(d) = w(d) alpha(S, S)`` and whose centre is ``1 - sum(k)``: a flat
measures the diagonal of the law, ``alpha(S, S)``.

The covariance at lag ``l`` is then exactly (no small-alpha approximation)

    C(l) = V sum_j K[j] K[j + l]  (+ sigma_read^2 at l = 0),

which this module solves for ``V`` and the five independent entries of a
symmetric 5x5 kernel: ``x`` (0, +-1), ``y`` (+-1, 0), ``diagonal``
(+-1, +-1), ``second_x`` (0, +-2), ``second_y`` (+-2, 0), from the measured
``C(0,0)``, ``C(0,1)``, ``C(1,0)``, ``C(1,1)`` (with ``C(1,-1)``),
``C(0,2)``, ``C(2,0)``. (To first order ``C(0,1) = 2 k_x V``: the "covariance
is twice alpha times the variance" rule.)

The fixed pattern of the flat (pixel response, a few percent) would swamp the
covariance of a single frame; it is cancelled by using, at each level, each
frame's difference from the per-pixel mean of the frames at that level
(scaled by ``n / (n - 1)``), which keeps only the noise. Masked (DQ) and
non-finite pixels are left out of every product they touch. The read noise
(uncoupled, it adds to ``C(0,0)`` only) comes from the darks or is given;
when it is unknown it is taken as 0 and the report says so.

Brighter-fatter (charge pushed away by the accumulated charge) also makes
flat covariances grow with signal, more at longer lags; it is not part of the
coupling law, so it is reported (the slope of each lag with signal), not
absorbed.
"""

import numpy as np
from scipy.optimize import least_squares

from ..errors import IPCInputError

__all__ = ["LAGS", "TERMS", "flat_covariances", "kernel_autocorrelation", "solve_kernel",
           "measure_level", "growth_with_signal", "weighted_slope"]

LAGS = ((0, 0), (0, 1), (1, 0), (1, 1), (1, -1), (0, 2), (2, 0))
"""Lags ``(dy, dx)`` whose covariances are measured."""

TERMS = ("x", "y", "diagonal", "second_x", "second_y")
"""The five independent entries of a symmetric 5x5 coupling kernel."""


def _kernel(k):
    kx, ky, kd, k2x, k2y = k
    K = np.zeros((5, 5))
    K[2, 1] = K[2, 3] = kx
    K[1, 2] = K[3, 2] = ky
    K[1, 1] = K[1, 3] = K[3, 1] = K[3, 3] = kd
    K[2, 0] = K[2, 4] = k2x
    K[0, 2] = K[4, 2] = k2y
    K[2, 2] = 1.0 - K.sum()
    return K


def kernel_autocorrelation(k, lag):
    """``sum_j K[j] K[j + lag]`` for the symmetric kernel of the five terms ``k``."""
    K = _kernel(k)
    dy, dx = lag
    a = K[max(dy, 0):5 + min(dy, 0), max(dx, 0):5 + min(dx, 0)]
    b = K[max(-dy, 0):5 + min(-dy, 0), max(-dx, 0):5 + min(-dx, 0)]
    return float(np.sum(a * b))


def flat_covariances(frames, mask=None, border=2, cancel_pattern=True):
    """Noise covariances of flats at one level, at :data:`LAGS`.

    Parameters
    ----------
    frames : ndarray, (n, ny, nx), n >= 2
        Flats at one illumination level [e-].
    mask : ndarray of bool, (ny, nx) or (n, ny, nx), optional
        Pixels not to trust; non-finite pixels are added. A pixel masked in
        any frame is left out.
    border : int
        Pixels dropped at each edge (the edge of the coupling).
    cancel_pattern : bool
        Subtract the per-pixel mean of the frames (cancels the fixed pattern;
        needs >= 2 frames). False subtracts each frame's own mean only: for
        flats known to have no fixed pattern (simulations), one frame will do.

    Returns
    -------
    dict
        ``level`` (mean [e-]), ``n_frames``, ``n_pixels`` (used), and per lag
        ``"dy,dx"``: ``{"cov", "error"}`` (error of the mean of the products).
    """
    stack = np.array(frames, dtype=np.float64)
    if stack.ndim == 2 and not cancel_pattern:
        stack = stack[None]
    if stack.ndim != 3 or (cancel_pattern and stack.shape[0] < 2):
        raise IPCInputError(f"flats at one level need >= 2 frames (n, ny, nx) to cancel the "
                            f"fixed pattern, got shape {stack.shape}")
    bad = ~np.isfinite(stack)
    if mask is not None:
        m = np.asarray(mask, bool)
        bad |= m if m.ndim == 3 else m[None]
    good = ~bad.any(axis=0)
    b = int(border)
    if b:
        good[:b] = good[-b:] = False
        good[:, :b] = good[:, -b:] = False
    n = stack.shape[0]
    if good.sum() < 100:
        raise IPCInputError(f"flats: only {int(good.sum())} usable pixels (masked, NaN or "
                            "border)")
    stack = np.where(good[None], stack, 0.0)
    level = float(stack[:, good].mean())
    if cancel_pattern:
        resid = (stack - stack.sum(axis=0) / n) * np.sqrt(n / (n - 1.0))
    else:
        resid = stack.copy()
    for r in resid:
        r -= r[good].mean()
        r[~good] = 0.0
    ny, nx = good.shape
    out = {"level": level, "n_frames": int(n), "n_pixels": int(good.sum())}
    for dy, dx in LAGS:
        ya, yb = slice(max(dy, 0), ny + min(dy, 0)), slice(max(-dy, 0), ny + min(-dy, 0))
        xa, xb = slice(max(dx, 0), nx + min(dx, 0)), slice(max(-dx, 0), nx + min(-dx, 0))
        both = good[ya, xa] & good[yb, xb]
        prod = (resid[:, ya, xa] * resid[:, yb, xb])[:, both]
        count = prod.size
        cov = float(prod.sum() / count)
        err = float(prod.std() / np.sqrt(count))
        out[f"{dy},{dx}"] = {"cov": cov, "error": err}
    return out


def solve_kernel(cov, read_noise=0.0):
    """``V`` and the five kernel terms from the covariances of :func:`flat_covariances`.

    Solves ``C(l) = V sum_j K[j] K[j + l] (+ read_noise^2 at l = 0)`` exactly
    (weighted least squares on 6 equations in 6 unknowns; ``C(1,1)`` and
    ``C(1,-1)`` are averaged).

    Returns
    -------
    dict
        ``V``, ``terms`` ``{name: {"value", "error"}}``, ``shot_variance``
        (``C(0,0) - read_noise^2``).
    """
    names = ("0,0", "0,1", "1,0", "1,1", "0,2", "2,0")
    c = {k: cov[k]["cov"] for k in ("0,0", "0,1", "1,0", "0,2", "2,0")}
    e = {k: cov[k]["error"] for k in ("0,0", "0,1", "1,0", "0,2", "2,0")}
    c["1,1"] = 0.5 * (cov["1,1"]["cov"] + cov["1,-1"]["cov"])
    e["1,1"] = 0.5 * np.hypot(cov["1,1"]["error"], cov["1,-1"]["error"])
    shot = c["0,0"] - float(read_noise) ** 2
    if not shot > 0:
        raise IPCInputError(f"flats: no shot noise left (variance {c['0,0']:.4g} e-^2 <= read "
                            f"noise^2 {float(read_noise) ** 2:.4g}): saturated or not a flat")
    target = np.array([c[k] for k in names])
    sigma = np.array([max(e[k], 1e-12 * abs(shot)) for k in names])
    lags = [tuple(int(v) for v in k.split(",")) for k in names]

    def residual(p):
        V, k = p[0] * shot, p[1:]
        model = np.array([V * kernel_autocorrelation(k, lag) for lag in lags])
        model[0] += float(read_noise) ** 2
        return (model - target) / sigma

    first = [c["0,1"] / (2 * shot), c["1,0"] / (2 * shot), c["1,1"] / (2 * shot),
             c["0,2"] / (2 * shot), c["2,0"] / (2 * shot)]
    fit = least_squares(residual, np.array([1.0] + first), method="lm", xtol=1e-14,
                        ftol=1e-14)
    J = fit.jac
    try:
        covp = np.linalg.inv(J.T @ J)
        errs = np.sqrt(np.clip(np.diag(covp), 0, None))
    except np.linalg.LinAlgError:
        errs = np.full(6, np.nan)
    terms = {name: {"value": float(fit.x[1 + i]), "error": float(errs[1 + i])}
             for i, name in enumerate(TERMS)}
    return {"V": float(fit.x[0] * shot), "terms": terms, "shot_variance": float(shot)}


def measure_level(frames, mask=None, read_noise=None, border=2, saturation=None):
    """One flat level: covariances, the kernel, and whether it can be trusted.

    Parameters
    ----------
    frames, mask, border :
        See :func:`flat_covariances`.
    read_noise : float or None
        [e-]; None: taken as 0 (said in ``notes``).
    saturation : float, optional
        Charge [e-] at which pixels saturate; pixels at or above it are masked.

    Returns
    -------
    dict
        ``level``, ``covariances``, ``V``, ``terms`` (or ``None`` with
        ``problem`` when the level cannot be measured), ``poisson_ratio``
        (``V / level``: 1 for Poisson noise in electrons; far below 1 means
        clipped or saturated data, far above a wrong gain), ``notes``.
    """
    stack = np.asarray(frames, dtype=np.float64)
    notes = []
    if saturation is not None:
        sat = stack >= float(saturation)
        mask = sat if mask is None else (np.asarray(mask, bool) | sat)
        if sat.mean() > 0.5:
            return {"level": float(np.nanmean(stack)), "terms": None,
                    "problem": f"{100 * sat.mean():.0f} % of the pixels are saturated",
                    "notes": notes}
    cov = flat_covariances(stack, mask, border)
    rn = 0.0 if read_noise is None else float(read_noise)
    if read_noise is None:
        notes.append("read noise unknown, taken as 0 (biases the terms by ~read^2/V)")
    try:
        solved = solve_kernel(cov, rn)
    except IPCInputError as exc:
        return {"level": cov["level"], "covariances": cov, "terms": None,
                "problem": str(exc), "notes": notes}
    ratio = solved["V"] / cov["level"] if cov["level"] > 0 else float("nan")
    row = {"level": cov["level"], "covariances": cov, "V": solved["V"],
           "terms": solved["terms"], "poisson_ratio": ratio, "notes": notes}
    if not ratio > 0.2:
        row["terms"] = None
        row["problem"] = (f"shot variance {solved['V']:.4g} e-^2 is {ratio:.2g} x the level "
                          f"{cov['level']:.4g} e-: saturated, clipped or not in electrons")
    elif not 0.7 < ratio < 1.3:
        notes.append(f"shot variance is {ratio:.3g} x the level (1 for Poisson noise in "
                     "electrons): check the gain")
    return row


def growth_with_signal(levels):
    """How each kernel term changes with signal across levels (brighter-fatter check).

    Returns
    -------
    dict
        Per term: ``slope_per_10ke`` (weighted linear fit), its ``error`` and
        ``significance`` (slope / error). Non-linear IPC and brighter-fatter
        both raise the nearest terms; brighter-fatter also raises the longer
        lags (diagonal, second) in proportion, IPC need not.
    """
    rows = [r for r in levels if r.get("terms")]
    out = {}
    if len(rows) < 2:
        return out
    s = np.array([r["level"] for r in rows]) / 1e4
    for name in TERMS:
        v = np.array([r["terms"][name]["value"] for r in rows])
        e = np.array([r["terms"][name]["error"] for r in rows])
        out[name] = weighted_slope(s, v, e)
    return out


def weighted_slope(x, values, errors):
    """Weighted straight-line fit: ``{"slope_per_10ke", "error", "significance"}``
    (``x`` in units of 10 ke-)."""
    w = 1.0 / np.maximum(np.asarray(errors, float), 1e-12) ** 2
    A = np.stack([np.ones_like(x), x], axis=1)
    covp = np.linalg.inv(A.T @ (A * w[:, None]))
    coef = covp @ (A.T @ (w * np.asarray(values, float)))
    err = float(np.sqrt(covp[1, 1]))
    return {"slope_per_10ke": float(coef[1]), "error": err,
            "significance": float(coef[1] / err) if err > 0 else float("nan")}

"""The covariance model of flat ramps, its joint fit and its per-level points.

Used by :class:`.ramps.FlatRamps` (which holds the sums of the data; the
physics of the three effects is in its module text).

Noise model (linear response about the flat; no expansion in ``a``). A
fluctuation ``dQ`` of the collected charge obeys ``d(dQ)/dt = I a * dQ +
(Poisson noise of rate I)``; in Fourier space each mode ``f`` grows at
``g(f) = r I a(f)``, so reads ``i <= j`` (times ``T = i, j`` in groups) have::

    S_ij(f) = (I / r) exp(g (T_j - T_i)) (exp(2 g T_i) - 1) / (2 g)
            = (I / r) T_i + I^2 a(f) T_i T_j + O(a^2),
    Cov(M_i, M_j)(f) = J_i(f) J_j(f) S_ij(f) + sigma^2 [i = j],

with ``r`` the gain ratio (true electrons per electron of the data: the true
gain is the assumed one times ``r``) and ``sigma`` the read noise per read.
The increments ``d_k = M_{k+1} - M_k`` then have the covariance
``C_kl = C(k+1, l+1) - C(k+1, l) - C(k, l+1) + C(k, l)``, transformed back to
the nine symmetric lags :data:`SYMMETRIC_LAGS`. To first order this is:
the same increment ``C_kk = (I/r) J_{k+1}*J_{k+1} + I^2
J*J*a + 2 sigma^2 [lag 0]``, a later one ``C_kl = (I/r) (J_{l+1} - J_l) *
J_{k+1} + I^2 J*J*a - sigma^2 [lag 0, l = k + 1]``. So brighter-fatter adds
the same ``I^2 KKa`` to every pair of increments whatever the level,
non-linear IPC changes the same-increment covariances with the level at a
fixed interval, and ``beta`` (measured from the curvature of the mean ramp,
``M_k = c + I k - beta (I k)^2``; IPC and brighter-fatter leave a flat's mean
alone) enters through ``J``. The model is exact in ``K``, in ``a`` (the
exponential) and in the differences ``J_{l+1} - J_l``; it neglects the
second moment of the charge in the non-linear terms (``beta^2 Var(Q)``) and
charge spreading during collection other than brighter-fatter.

Simulators that collect each group in a few discrete steps, each at the rate
set by the charge at its start (solid-waffle's ``SUBSTEPS``), respond less to
brighter-fatter within a step than a detector: ``collection_steps`` makes the
model follow them step by step (with 2 steps, the continuous model reads the
nearest IPC terms ~2 % low on solid-waffle's ramps with its infrared kernel).
"""

import numpy as np
from scipy import special

from ..errors import IPCInputError
from .flats import TERMS, solve_kernel

__all__ = ["LAGS", "SYMMETRIC_LAGS", "VARIANTS", "kernel_from_symmetric",
           "symmetric_from_kernel"]

LAGS = ((0, 0), (0, 1), (1, 0), (1, 1), (1, -1), (0, 2), (2, 0), (1, 2), (1, -2), (2, 1),
        (2, -1), (2, 2), (2, -2))
"""Lags ``(dy, dx)`` of the sums; with both orders of each pair they cover every
offset of a 5x5 box."""

SYMMETRIC_LAGS = ((0, 0), (0, 1), (1, 0), (1, 1), (0, 2), (2, 0), (1, 2), (2, 1), (2, 2))
"""The nine lags of a kernel symmetric in ``dy`` and in ``dx``; also the order of
the symmetric values of a brighter-fatter kernel."""

VARIANTS = ("ipc_only", "nonlinear_ipc", "brighter_fatter", "full")
"""Model variants: constant IPC; IPC with its signal dependence; constant IPC
plus brighter-fatter; everything."""

_CLASS = np.array([SYMMETRIC_LAGS.index((abs(dy), abs(dx))) for dy, dx in LAGS])
_MULT = np.array([(1 if dy == 0 else 2) * (1 if dx == 0 else 2) for dy, dx in SYMMETRIC_LAGS])
_TERM_CLASS = np.arange(1, 6)  # TERMS x, y, diagonal, second_x, second_y = classes 1..5
_GRID = 20
_MARGIN = 2
_SCALES = {"r": 1.0, "s2": 100.0, "k0": 1e-2, "k1": 1e-6, "a": 1e-6, "common": 10.0}
_DETECTION = 5.0


def kernel_from_symmetric(values):
    """The 5x5 kernel ``[2 + dy][2 + dx]`` of the nine symmetric values.

    Parameters
    ----------
    values : sequence of 9 float
        Values at :data:`SYMMETRIC_LAGS`.

    Returns
    -------
    ndarray, (5, 5)
    """
    kernel = np.zeros((5, 5))
    for v, (dy, dx) in zip(values, SYMMETRIC_LAGS, strict=True):
        for sy in (-1, 1):
            for sx in (-1, 1):
                kernel[2 + sy * dy, 2 + sx * dx] = v
    return kernel


def symmetric_from_kernel(kernel):
    """The nine symmetric values (averages over the four reflections) of a 5x5 kernel."""
    k = np.asarray(kernel, dtype=np.float64)
    if k.shape != (5, 5):
        raise IPCInputError(f"a brighter-fatter kernel is 5x5, got shape {k.shape}")
    avg = (k + k[::-1] + k[:, ::-1] + k[::-1, ::-1]) / 4.0
    return np.array([avg[2 + dy, 2 + dx] for dy, dx in SYMMETRIC_LAGS])


def _fourier_basis(n=_GRID):
    """Modes of a periodic ``n x n`` grid folded by the kernels' symmetry.

    Returns ``basis`` (9, modes): the transform of a unit symmetric value at
    each class of :data:`SYMMETRIC_LAGS`; ``inverse`` (modes, 9): back to the
    lags (weights included).
    """
    m = np.arange(n // 2 + 1)
    f = 2 * np.pi * m / n
    w = np.where((m == 0) | (m == n // 2), 1.0, 2.0)
    fy, fx = (v.ravel() for v in np.meshgrid(f, f, indexing="ij"))
    wy, wx = (v.ravel() for v in np.meshgrid(w, w, indexing="ij"))
    basis = np.empty((9, fy.size))
    inverse = np.empty((fy.size, 9))
    for c, (dy, dx) in enumerate(SYMMETRIC_LAGS):
        cy, cx = np.cos(fy * dy), np.cos(fx * dx)
        basis[c] = (cy if dy == 0 else 2 * cy) * (cx if dx == 0 else 2 * cx)
        inverse[:, c] = wy * wx * cy * cx / n ** 2
    return basis, inverse


_BASIS, _INVERSE = _fourier_basis()


class _Model:
    """Covariances of the increments of flat ramps (see the module docstring).

    Parameters: ``r``, ``s2`` (sigma^2 [e-^2]), ``k0`` (5), ``k1`` (5, per e-),
    ``a`` (9 symmetric values, per e-), ``common`` (one integration only, else
    None: 18 values [e-^2], ``A`` then ``B`` at the nine lags, the term
    ``A + B (k + l + 1)`` added to every pair of increments).
    """

    def __init__(self, n_groups, current, beta, steps=None):
        self.time = np.arange(n_groups, dtype=np.float64)
        self.current, self.beta = float(current), float(beta)
        self.level = self.current * self.time
        self.steps = steps

    def jacobian(self, p):
        """``J_i(f)`` (reads, modes)."""
        k = p["k0"][None, :] + p["k1"][None, :] * self.level[:, None]
        offcentre = (_MULT[_TERM_CLASS, None] - _BASIS[_TERM_CLASS])
        kernel = 1.0 - k @ offcentre
        return (1.0 - 2.0 * self.beta * self.level)[:, None] * kernel

    def collected(self, p, poisson=True):
        """``S_ij(f)``: covariance of collected charge (reads, reads, modes);
        ``poisson=False`` keeps only the brighter-fatter part.

        Continuous collection: ``S_ij = (I/r) exp(g dt) expm1(2 g t) / (2 g)``
        (``t = min(T_i, T_j)``, ``dt = |T_i - T_j|``). In ``steps`` discrete steps
        per group, each collecting at the rate set by the charge at its start
        (simulators): the same with ``exp(g)`` replaced by ``(1 + g / steps)^steps``
        and ``2 g`` by ``steps ((1 + g / steps)^2 - 1)``.
        """
        r, cur, t = p["r"], self.current, self.time
        g = r * cur * (p["a"] @ _BASIS)
        if self.steps:
            rate = self.steps * np.log1p(g / self.steps)
            den = g * (2.0 + g / self.steps)
        else:
            rate, den = g, 2.0 * g
        tmin = np.minimum(t[:, None], t[None, :])[..., None]
        tdiff = np.abs(t[:, None] - t[None, :])[..., None]
        x = 2.0 * rate * tmin
        small = np.abs(rate) < 1e-12
        growth = np.where(small, tmin, np.expm1(x) / np.where(small, 1.0, den))
        return (cur / r) * (np.exp(rate * tdiff) * growth - (0.0 if poisson else tmin))

    def reads(self, p):
        """``Cov(M_i, M_j)(f)`` (reads, reads, modes)."""
        jac = self.jacobian(p)
        c = jac[:, None, :] * jac[None, :, :] * self.collected(p)
        idx = np.arange(self.time.size)
        c[idx, idx] += p["s2"]
        return c

    def increments(self, p):
        """``C_kl(delta)`` (increments, increments, :data:`SYMMETRIC_LAGS`)."""
        c = self.reads(p)
        d = (c[1:, 1:] - c[1:, :-1] - c[:-1, 1:] + c[:-1, :-1]) @ _INVERSE
        if p.get("common") is not None:
            k = np.arange(d.shape[0], dtype=np.float64)
            d += p["common"][:9] + (k[:, None] + k[None, :] + 1.0)[..., None] * p["common"][9:]
        return d

    def excess_of_increments(self, p):
        """Everything in the same-increment covariances but ``(I/r) J_{k+1}*J_{k+1}``
        (brighter-fatter or the common term, read noise, ``k (J_{k+1} - J_k)^2``),
        at the lags (9, increments)."""
        jac = self.jacobian(p)[1:]
        ipc = (self.current / p["r"]) * jac ** 2 @ _INVERSE
        return (np.diagonal(self.increments(p)).T - ipc).T

    def excess_of_difference(self, p, b):
        """Everything in ``Cov(M_b - M_0)`` but ``(I/r) b J_b*J_b`` (brighter-fatter
        or the common term, ``2 sigma^2``), at the lags (9,)."""
        ipc = (self.current / p["r"]) * self.time[b] * self.jacobian(p)[b] ** 2 @ _INVERSE
        return self.increments(p)[:b, :b].sum(axis=(0, 1)) - ipc


def _mean_ramp(increment_sums, n_pixels):
    """``I`` and ``beta`` from the mean increments ``I - beta I^2 (2k + 1)``.

    ``increment_sums`` (..., increments) summed over ``n_pixels`` pixels.
    """
    mean = increment_sums / n_pixels
    k = np.arange(mean.shape[-1], dtype=np.float64)
    design = np.stack([np.ones_like(k), 2 * k + 1], axis=1)
    coef = np.linalg.lstsq(design, mean.T if mean.ndim > 1 else mean, rcond=None)[0]
    current = coef[0]
    return current, -coef[1] / current ** 2


def _jackknife(samples):
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


# ---------------------------------------------------------------------- fit helpers
def _start(cov, current, nints):
    """Starting parameters from the data."""
    g = cov.shape[-1]
    diag0 = np.diagonal(cov[0])
    s2 = max(-np.mean(np.diagonal(cov[0], offset=1)), 0.0) if g > 1 else 0.0
    shot = max(np.mean(diag0) - 2 * s2, 1e-3 * current)
    k0 = np.array([np.mean(np.diagonal(cov[c])) / (2 * shot) for c in _TERM_CLASS])
    return {"r": current / shot, "s2": s2, "k0": k0, "k1": np.zeros(5), "a": np.zeros(9),
            "common": np.zeros(18) if nints == 1 else None}


def _variant_fixed(variant, nints):
    """Parameters held fixed in a variant (and by one integration)."""
    fixed = {}
    if variant in ("ipc_only", "brighter_fatter"):
        fixed["k1"] = np.zeros(5)
    if variant in ("ipc_only", "nonlinear_ipc") or nints == 1:
        fixed["a"] = np.zeros(9)
    return fixed


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
    p["a"][0] = -(p["a"][1:] @ _MULT[1:])
    return p


def _errors(jack):
    """``errors(name, index=None)``: jackknife standard error of a parameter."""
    def errors(name, index=None):
        if len(jack) < 3:
            return None
        vals = [j[name] if index is None else j[name][index] for j in jack]
        return float(np.sqrt(_jackknife(vals)[0, 0]))
    return errors


def _scaled(value, factor):
    return None if value is None else float(value * factor)


def _significance(value, error):
    return None if error is None or not error > 0 else float(value / error)


def _nonlinearity_report(full, jack, errors, integration_betas):
    err = errors("beta")
    if integration_betas is not None and err is not None:
        n = integration_betas.size
        err = max(err, float(np.std(integration_betas, ddof=1) / np.sqrt(n)))
    sig = _significance(full["beta"], err)
    return {"measured": err is not None, "beta": float(full["beta"]), "error": err,
            "significance": sig, "detected": bool(sig is not None and abs(sig) >= _DETECTION),
            "form": "M = Q - beta Q^2 (Q collected, M measured, e-)",
            "note": "from the curvature of the mean ramp; error: the larger of the jackknife "
                    "over blocks and the scatter between integrations"}


def _nonlinear_ipc_report(full, jack, nints):
    value = float(full["k1"][0] + full["k1"][1]) * 1e4
    err = None
    if len(jack) >= 3:
        err = float(np.sqrt(_jackknife([1e4 * (j["k1"][0] + j["k1"][1]) for j in jack])[0, 0]))
    sig = _significance(value, err)
    detected = bool(sig is not None and abs(sig) >= _DETECTION)
    note = (f"slope of the nearest terms x + y: {value:+.3g} per 10 ke-"
            + ("" if err is None else f" +- {err:.2g}") + ", fitted beside "
            + ("brighter-fatter" if nints > 1 else "the common brighter-fatter and pattern term"))
    return {"detected": detected, "significance": sig, "slope_per_10ke": value, "error": err,
            "note": note + (": detected" if detected else ": not detected")}


def _bf_report(full, jack, nints):
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
    cov = _jackknife([j["a"] for j in jack])
    err = np.sqrt(np.diag(cov))
    nearest = float(full["a"][1] + full["a"][2])
    nearest_err = float(np.sqrt(_jackknife([j["a"][1] + j["a"][2] for j in jack])[0, 0]))
    sig = _significance(nearest, nearest_err)
    free = cov[1:, 1:]
    try:
        chi2 = float(full["a"][1:] @ np.linalg.solve(free, full["a"][1:]))
    except np.linalg.LinAlgError:
        chi2 = float("nan")
    detected = bool(sig is not None and sig >= _DETECTION)
    return {"measured": True, "detected": detected, "significance": sig,
            "significance_kind": "nearest terms a(0,1) + a(1,0) over their jackknife error",
            "chi2": chi2, "chi2_sigma": _sigma_from_chi2(chi2, 8) if np.isfinite(chi2) else None,
            "kernel": kernel, "kernel_error": kernel_from_symmetric(err).tolist(),
            "note": "per electron; pixel area 1 + sum_d a(d) Q(p+d); symmetric part: "
                    + ("detected" if detected else "not detected")}


def _public_params(p, n_groups):
    """Fit parameters as plain numbers (for :meth:`FlatRamps.predict` and JSON)."""
    return {"n_groups": int(n_groups), "current": float(p["current"]),
            "beta": float(p["beta"]), "gain_ratio": float(p["r"]),
            "read_noise_variance": float(p["s2"]),
            "k0": dict(zip(TERMS, map(float, p["k0"]), strict=True)),
            "k1_per_electron": dict(zip(TERMS, map(float, p["k1"]), strict=True)),
            "brighter_fatter": [float(v) for v in p["a"]],
            "common": None if p.get("common") is None else [float(v) for v in p["common"]],
            "collection_steps": p["steps"]}


def _internal_params(params):
    return {"current": params["current"], "beta": params["beta"], "r": params["gain_ratio"],
            "s2": params["read_noise_variance"],
            "k0": np.array([params["k0"][t] for t in TERMS]),
            "k1": np.array([params["k1_per_electron"][t] for t in TERMS]),
            "a": np.array(params["brighter_fatter"], dtype=np.float64),
            "common": None if params.get("common") is None else np.array(params["common"]),
            "steps": params.get("collection_steps")}


# ---------------------------------------------------------------------- levels
def _level_note(nints, given):
    if nints < 2:
        return ("one integration: brighter-fatter not measured and not told from the fixed "
                "pattern; their common term, fitted from the pairs of different increments, "
                "was removed")
    if given:
        return "brighter-fatter removed with the kernel given"
    return "brighter-fatter removed with the kernel measured from the ramps"


def _level_point(data, p, n_groups, inc, method):
    """``(V, terms)`` of one level, brighter-fatter and read noise removed.

    ``difference``: ``Cov(M_b - M_0)`` with ``b = inc.size``; ``increments``:
    the mean same-increment covariance of the increments ``inc``.
    """
    cov, counts = data[0], data[1]
    model = _Model(n_groups, p["current"], p["beta"], p["steps"])
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

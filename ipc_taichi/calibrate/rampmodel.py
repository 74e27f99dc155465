"""The covariance model of flat ramps: what the increments' covariances are, given
the parameters.

Used by :mod:`.rampfit` (the joint fit of the sums of :mod:`.rampsums`) and by
:class:`.ramps.FlatRamps` (the orchestration; the physics of the three effects
is in its module text).

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

from ..errors import IPCInputError

__all__ = ["LAGS", "SYMMETRIC_LAGS", "VARIANTS", "REFLECTIONS", "LAG_CLASSES", "TERM_CLASSES",
           "kernel_from_symmetric", "symmetric_from_kernel", "with_zero_sum", "RampCovariance",
           "mean_ramp", "variant_fixed"]

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

LAG_CLASSES = np.array([SYMMETRIC_LAGS.index((abs(dy), abs(dx))) for dy, dx in LAGS])
"""The class in :data:`SYMMETRIC_LAGS` of each of :data:`LAGS`."""

REFLECTIONS = np.array([(1 if dy == 0 else 2) * (1 if dx == 0 else 2)
                        for dy, dx in SYMMETRIC_LAGS])
"""How many offsets of a 5x5 box each of :data:`SYMMETRIC_LAGS` stands for (its
distinct reflections)."""

TERM_CLASSES = np.arange(1, 6)
"""The classes of :data:`SYMMETRIC_LAGS` of the five IPC terms
(:data:`~ipc_taichi.calibrate.flats.TERMS` x, y, diagonal, second_x, second_y)."""

_GRID = 20


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



def with_zero_sum(values):
    """The nine symmetric values of a brighter-fatter kernel with ``a(0, 0)`` set
    so that the kernel sums to zero (charge is moved, not made)."""
    a = np.array(values, dtype=np.float64)
    a[0] = -(a[1:] @ REFLECTIONS[1:])
    return a


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


class RampCovariance:
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
        offcentre = (REFLECTIONS[TERM_CLASSES, None] - _BASIS[TERM_CLASSES])
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


def mean_ramp(increment_sums, n_pixels):
    """``I`` and ``beta`` from the mean increments ``I - beta I^2 (2k + 1)``.

    ``increment_sums`` (..., increments) summed over ``n_pixels`` pixels.
    """
    mean = increment_sums / n_pixels
    k = np.arange(mean.shape[-1], dtype=np.float64)
    design = np.stack([np.ones_like(k), 2 * k + 1], axis=1)
    coef = np.linalg.lstsq(design, mean.T if mean.ndim > 1 else mean, rcond=None)[0]
    current = coef[0]
    return current, -coef[1] / current ** 2


def variant_fixed(variant, nints):
    """Parameters held fixed in a variant (and by one integration)."""
    fixed = {}
    if variant in ("ipc_only", "brighter_fatter"):
        fixed["k1"] = np.zeros(5)
    if variant in ("ipc_only", "nonlinear_ipc") or nints == 1:
        fixed["a"] = np.zeros(9)
    return fixed

"""The cross-read part of the ramp gap (``docs/discover.md``, "Ramps"): the
products of a pixel's whitened increments at two different reads, with its
own and its neighbours' (:func:`cross_products`), what brighter-fatter makes
of them (:class:`CrossResponse`), and brighter-fatter's feedback in a
simulated ramp (:func:`collect_reads`).

In a uniform flat brighter-fatter moves no mean charge: it makes a pixel's
later increments depend on the charge it and its neighbours already hold.
With ``A_p = 1 + sum_d a(d) Q(p + d)`` (the kernel of
:func:`~ipc_taichi.brighterfatter.kernel_from_deflection`), the increment
``d_j`` of pixel ``p`` and the earlier ``d_i`` (``i < j``) of pixel ``p - d``
share ``Cov(d_i(p - d), d_j(p)) = a(d) mu_j(p) s_i(p - d)`` (``mu`` the
expected increments, ``s`` their shot variances; to first order in ``a``;
:class:`CrossResponse` takes the flat-ramp model's exact covariance), so the
whitened increments' products at reads ``i < j`` have a mean ``~ I dt a(d)``
per pair instead of zero.
"""


import numpy as np

from ..brighterfatter import kernel_from_deflection
from ..calibrate.rampmodel import SYMMETRIC_LAGS, RampCovariance, symmetric_from_kernel
from ..detector import collect

__all__ = ["CROSS_LAGS", "CROSS_Z", "BF_SUBSTEPS", "bf_kernel_of", "collect_reads",
           "cross_products", "cross_read_excess", "CrossResponse", "pixel_pairs"]

CROSS_Z = 3.0  # a cross-read product beyond this many floor scatters leaves the model incomplete
BF_SUBSTEPS = 2  # a simulated read collects in this many steps, each at the rate its start sets
CROSS_LAGS = {"self": ((0, 0),), "x": ((0, 1),), "y": ((1, 0),), "diagonal": ((1, 1), (1, -1))}
"""The cross-read products (:func:`~.ramps.ramp_gap`): a pixel's whitened
increment at read ``i`` times that of the pixel at each offset ``(dy, dx)``
(and its mirror) at every later read ``j > i``."""


def bf_kernel_of(frame):
    """The 5x5 brighter-fatter kernel (per electron) of a frame model's
    ``brighter_fatter`` (:func:`~ipc_taichi.brighterfatter.kernel_from_deflection`),
    or ``None`` without it."""
    p = frame.effects.get("brighter_fatter")
    if not p:
        return None
    return kernel_from_deflection(p["deflection_x_at_50ke"], p["deflection_y_at_50ke"],
                                  p["reach"], p["upwind"])


def collect_reads(c, rng, kernel):
    """The charge at each read of expected charges ``c``: independent Poisson
    increments summed, or with ``kernel`` collected in :data:`BF_SUBSTEPS`
    steps per read, each scaled by ``1 + sum_d a(d) dQ`` of the charge's
    excess ``dQ`` over its expectation at the step's start (module docstring)."""
    steps = np.diff(c, axis=0, prepend=0.0)
    if kernel is None or rng is None:
        return np.cumsum(collect(steps, rng), axis=0)
    from scipy.ndimage import correlate

    c = np.nan_to_num(c)
    steps = np.nan_to_num(steps) / BF_SUBSTEPS
    q, before, out = np.zeros(c.shape[1:]), np.zeros(c.shape[1:]), []
    for step in steps:
        for _ in range(BF_SUBSTEPS):
            factor = 1.0 + correlate(q - before, kernel, mode="nearest")
            q = q + collect(step * factor, rng)
            before = before + step
        out.append(q)
    return np.array(out)


def cross_products(w, valid):
    """``{name: (mean, number)}`` of the cross-read products of whitened
    increments ``w`` (:data:`CROSS_LAGS`, both orders of each neighbour pair)."""
    n = w.shape[0]
    if n < 2:
        return {name: (0.0, 0) for name in CROSS_LAGS}
    full = np.full((n,) + valid.shape, np.nan)
    full[:, valid] = w
    earlier = np.cumsum(full, axis=0)[:-1]  # sum of reads i < j, for j = 1...
    later = full[1:]
    out = {}
    for name, lags in CROSS_LAGS.items():
        per_pixel = np.concatenate([np.sum(earlier[(slice(None),) + p] * later[(slice(None),) + q],
                                           axis=0).ravel()
                                    for p, q in pixel_pairs(valid.shape, lags)])
        per_pixel = per_pixel[np.isfinite(per_pixel)]
        npairs = n * (n - 1) // 2
        out[name] = (float(np.mean(per_pixel)) / npairs if per_pixel.size else 0.0,
                     per_pixel.size * npairs)
    return out


def pixel_pairs(shape, lags):
    """The index pairs ``(earlier pixel, later pixel)`` of an image of ``shape``
    at each offset of ``lags`` and its mirror (once for ``(0, 0)``)."""
    ny, nx = shape
    out = []
    for dy, dx in lags:
        ya, yb = slice(0, ny - dy), slice(dy, ny)
        xa, xb = (slice(0, nx - dx), slice(dx, nx)) if dx >= 0 else (
            slice(-dx, nx), slice(0, nx + dx))
        a, b = (ya, xa), (yb, xb)
        out += [(a, b)] if (dy, dx) == (0, 0) else [(a, b), (b, a)]
    return out


def cross_read_excess(stats, z=CROSS_Z):
    """``{name: z-score}`` of the cross-read products (``stats`` a
    :func:`ramp_gap` result) farther than ``z`` floor scatters from their floor."""
    out = {}
    for name, value in stats["cross_read"].items():
        m, s = stats["cross_read_floor"][name]
        if abs(value - m) > z * s:
            out[name] = (value - m) / s
    return out




def _later_sums(l_inv):
    """``sum_{j > i} L^{-1}[j, :]`` for each ``i`` (the rows the later reads of a pair add)."""
    rev = np.cumsum(l_inv[..., ::-1, :], axis=-2)[..., ::-1, :]
    return np.concatenate([rev[..., 1:, :], np.zeros_like(rev[..., :1, :])], axis=-2)


class CrossResponse:
    """What a brighter-fatter kernel adds to the cross-read products of ramps
    whitened by a model's covariance (:meth:`expected`).

    Per ramp and class of :data:`CROSS_LAGS` the weights ``W_kl``, the mean
    over pixel pairs ``(p, p + d)`` of ``sum_{i < j} L_p^{-1}[i, k]
    L_{p+d}^{-1}[j, l]`` divided by the pairs of reads, so that the product's
    expectation is ``sum_kl W_kl C_kl(d)`` for an increments' covariance
    ``C``; brighter-fatter's ``C`` is the flat-ramp model's
    (:class:`~ipc_taichi.calibrate.rampmodel.RampCovariance`: exact in the
    kernel, the feedback compounding over the reads, :data:`BF_SUBSTEPS`
    steps per read) at the ramp's mean expected increment, times the shot
    variance's share of it (what the read-out coupling leaves)."""

    def __init__(self):
        self.ramps = []

    def add(self, chol, mu, s, valid):
        """One ramp: Cholesky factors ``(npix, NREADS, NREADS)`` of the valid
        pixels, expected increments ``mu`` and shot variances ``s``
        (``(NREADS, npix)``)."""
        n = chol.shape[-1]
        if n < 2:
            return
        full = np.full(valid.shape + (n, n), np.nan)
        full[valid] = np.linalg.solve(chol, np.broadcast_to(np.eye(n), chol.shape))
        later = _later_sums(full)
        weights = {}
        for name, lags in CROSS_LAGS.items():
            total, count = np.zeros((n, n)), 0
            for p, q in pixel_pairs(valid.shape, lags):
                terms = np.einsum("...ik,...il->...kl", full[p], later[q])
                ok = np.all(np.isfinite(terms), axis=(-1, -2))
                total += terms[ok].sum(axis=0)
                count += int(ok.sum())
            weights[name] = (total / max(count, 1) / (n * (n - 1) // 2), count)
        current = float(np.mean(mu))
        share = float(np.mean(s)) / current if current > 0 else 0.0
        self.ramps.append((weights, current, share, n))

    def expected(self, kernel):
        """``{name: value}``: the kernel's addition to each cross-read product,
        weighted over the ramps like :func:`cross_products`."""
        a = symmetric_from_kernel(kernel)
        sums = {name: [0.0, 0] for name in CROSS_LAGS}
        for weights, current, share, n in self.ramps:
            model = RampCovariance(n + 1, current, 0.0, steps=BF_SUBSTEPS)
            p = {"r": 1.0, "s2": 0.0, "k0": np.zeros(5), "k1": np.zeros(5), "common": None}
            c = share * (model.increments({**p, "a": a}) - model.increments({**p, "a": 0 * a}))
            for name, lags in CROSS_LAGS.items():
                w, count = weights[name]
                lag = SYMMETRIC_LAGS.index(tuple(abs(v) for v in lags[0]))
                sums[name][0] += float(np.sum(w * c[:, :, lag])) * count
                sums[name][1] += count
        return {name: v / max(c, 1) for name, (v, c) in sums.items()}

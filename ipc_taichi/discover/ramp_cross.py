"""The cross-read part of the ramp gap (``docs/discover.md``, "Ramps"): the
products of a pixel's whitened increments at two different reads, with its
own and its neighbours' (:func:`cross_products`), what brighter-fatter makes
of them (:func:`cross_response`), and brighter-fatter's feedback in a
simulated ramp (:func:`collect_reads`).

In a uniform flat brighter-fatter moves no mean charge: it makes a pixel's
later increments depend on the charge it and its neighbours already hold.
With ``A_p = 1 + sum_d a(d) Q(p + d)`` (the kernel of
:func:`~ipc_taichi.brighterfatter.kernel_from_deflection`), the increment
``d_j`` of pixel ``p`` and the earlier ``d_i`` (``i < j``) of pixel ``p - d``
share ``Cov(d_i(p - d), d_j(p)) = a(d) mu_j(p) s_i(p - d)`` (``mu`` the
expected increments, ``s`` their shot variances; to first order in ``a``),
so the whitened increments' products at reads ``i < j`` have a mean
``~ I dt a(d)`` per pair instead of zero.
"""


import numpy as np

from ..brighterfatter import kernel_from_deflection
from ..detector import collect

__all__ = ["CROSS_LAGS", "CROSS_Z", "BF_SUBSTEPS", "bf_kernel_of", "collect_reads",
           "cross_products", "cross_read_excess", "cross_response", "kernel_at_lags",
           "pixel_pairs"]

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




def kernel_at_lags(kernel):
    """``{name: a}``: the kernel's mean value at each class of :data:`CROSS_LAGS`
    (both signs of each offset)."""
    k = np.asarray(kernel)
    return {name: float(np.mean([k[2 + s * dy, 2 + s * dx] for dy, dx in lags for s in (1, -1)]))
            for name, lags in CROSS_LAGS.items()}


def _pair_response(la, lb, mu_a, s_a, mu_b, s_b, n):
    """Per pixel pair: the mean over ``i < j`` of ``E[w_i(a) w_j(b)]`` per unit
    kernel value (module docstring; ``la``, ``lb`` the inverse Cholesky
    factors, ``mu``, ``s`` the increments' means and shot variances, reads last)."""
    upper = np.triu(np.ones((n, n)), 1)
    within = 1.0 - 1.0 / BF_SUBSTEPS  # a read's own steps feed each other
    b = (s_a[..., :, None] * mu_b[..., None, :] * upper
         + mu_a[..., :, None] * s_b[..., None, :] * upper.T
         + within * np.eye(n) * (s_a * mu_b)[..., None, :])
    m = la @ b @ np.swapaxes(lb, -1, -2)
    return np.sum(m * upper, axis=(-1, -2)) / (n * (n - 1) // 2)


def cross_response(chol, mu, s, valid):
    """``{name: (g, number)}``: what a kernel value ``a`` at the lags of each
    class of :data:`CROSS_LAGS` adds to its cross-read product, ``a g``, for
    increments whitened by ``chol`` (``(npix, NREADS, NREADS)``, the valid
    pixels) with expected increments ``mu`` and shot variances ``s``
    (``(NREADS, npix)``), to first order (module docstring); ``number`` the
    pixel pairs (the weights of :func:`cross_products`)."""
    n = chol.shape[-1]
    if n < 2:
        return {name: (0.0, 0) for name in CROSS_LAGS}
    eye = np.broadcast_to(np.eye(n), chol.shape)
    full = np.full(valid.shape + (n, n), np.nan)
    full[valid] = np.linalg.solve(chol, eye)
    means, shots = (np.full(valid.shape + (n,), np.nan) for _ in range(2))
    means[valid], shots[valid] = mu.T, s.T
    out = {}
    for name, lags in CROSS_LAGS.items():
        values = []
        for p, q in pixel_pairs(valid.shape, lags):
            g = _pair_response(full[p], full[q], means[p], shots[p], means[q], shots[q], n)
            values.append(g[np.isfinite(g)])
        values = np.concatenate(values)
        out[name] = (float(np.mean(values)) if values.size else 0.0, values.size)
    return out

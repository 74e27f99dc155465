"""Plain-NumPy reference implementation of the coupling and the decoupler.

Written independently of the Taichi kernels: instead of gathering per pixel
over a half stencil, it computes for each directed offset ``d`` the charge
*transfer* array ``T_d[p] = w(d) alpha(S_p, S_{p+d}) S_p`` on a zero-padded
frame and moves it with an array shift. It is vectorised (one pass over the
frame per offset). Same conventions as :mod:`ipc_taichi.coupling` (edges, bad
pixels, geometry). :func:`decouple_reference` writes the stopping and
divergence rules out again on purpose (an independent twin of
:mod:`ipc_taichi.iteration`).

:func:`decouple_numpy` is the benchmark's NumPy peer: the fastest plain-NumPy
decoupler we could write for the paper's case (nearest neighbours, zero edge,
a parametric law), pair-symmetric and in place.
"""

import numpy as np

from . import iteration
from .laws import donlon2018
from .model import CouplingModel

__all__ = ["couple_reference", "decouple_reference", "flow_reference", "decouple_numpy"]


def flow_reference(signal, law=None, geometry=None, edge=None, *, model=None):
    """Net charge each pixel gains by coupling: ``couple(S) - S`` (2-D, float64).

    ``law``, ``geometry``, ``edge`` and ``model`` as for :func:`ipc_taichi.couple`.
    Non-finite pixels are bad: excluded from coupling, NaN in the result.
    """
    return _flow(signal, CouplingModel.resolve(law, geometry, edge, model=model))


def _flow(signal, model):
    law, geometry, edge = model.law, model.geometry, model.edge
    s = np.asarray(signal, dtype=np.float64)
    factors = _bond_factors(model, s.shape)
    valid = np.isfinite(s)
    r = geometry.reach
    ny, nx = s.shape
    padded = np.zeros((ny + 2 * r, nx + 2 * r))
    padded[r:r + ny, r:r + nx] = np.where(valid, s, 0.0)
    source_ok = np.zeros(padded.shape, dtype=bool)
    source_ok[r:r + ny, r:r + nx] = valid
    # where charge may land: good pixels, and, with the zero edge, the outside
    target_ok = np.full(padded.shape, edge == "zero")
    target_ok[r:r + ny, r:r + nx] = valid
    gain = np.zeros(padded.shape)
    for (dy, dx), w in geometry.weights:
        neighbour = np.roll(padded, (-dy, -dx), axis=(0, 1))  # neighbour[p] = S[p + d]
        lands = np.roll(target_ok, (-dy, -dx), axis=(0, 1))
        transfer = np.where(source_ok & lands, w * law.alpha(padded, neighbour) * padded, 0.0)
        if factors is not None:
            transfer *= factors[(dy, dx)]
        gain -= transfer
        gain += np.roll(transfer, (dy, dx), axis=(0, 1))  # arrives at p + d
    out = gain[r:r + ny, r:r + nx]
    out[~valid] = np.nan
    return out


def _bond_factors(model, shape):
    """For each directed offset ``d``, the factor of the bond ``p -- p+d`` at
    every padded position ``p`` (``None`` for a uniform model): the half-stencil
    array for ``d = u``, the same array moved by ``u`` for ``d = -u`` (the bond
    ``p -- p-u`` is stored at ``p-u``)."""
    bonds = model.bonds
    if bonds is None:
        return None
    bonds.check(model.geometry, shape)
    padded = bonds.padded(model.geometry.reach)
    factors = {}
    for k, (dy, dx) in enumerate(bonds.offsets):
        factors[(dy, dx)] = padded[k]
        factors[(-dy, -dx)] = np.roll(padded[k], (dy, dx), axis=(0, 1))
    return factors


def couple_reference(signal, law=None, geometry=None, edge=None, *, model=None):
    """Reference forward model for one 2-D frame (float64); arguments as for
    :func:`flow_reference`."""
    s = np.asarray(signal, dtype=np.float64)
    return s + flow_reference(s, law, geometry, edge, model=model)


def decouple_reference(measured, law=None, geometry=None, edge=None,
                       max_iter=iteration.MAX_ITER, tol=iteration.TOL, *, model=None):
    """Reference Jacobi decoupler for one 2-D frame.

    Returns ``(signal, iterations, converged, max_delta)`` with the same
    stopping rule as :func:`ipc_taichi.decouple`.
    """
    model = CouplingModel.resolve(law, geometry, edge, model=model)
    m = np.asarray(measured, dtype=np.float64)
    prev = m.copy()
    deltas = []
    converged = False
    for _ in range(int(max_iter)):
        nxt = m - _flow(prev, model)
        dmax = np.nanmax(np.abs(nxt - prev)) if np.isfinite(nxt).any() else 0.0
        smax = np.nanmax(np.abs(nxt)) if np.isfinite(nxt).any() else 0.0
        deltas.append(float(dmax))
        prev = nxt
        if tol > 0 and dmax <= tol * smax:
            converged = True
            break
    return prev, len(deltas), converged, deltas


def decouple_numpy(measured, law=None, max_iter=iteration.MAX_ITER, tol=iteration.TOL):
    """The Jacobi decoupler in plain vectorised NumPy, as fast as we can make it.

    Nearest neighbours with weight 1, zero edge, a :class:`ParametricLaw`.
    Like the Taichi kernels it evaluates alpha once per neighbour *pair*
    (alpha is symmetric): with ``T = alpha(S_a, S_b) (S_b - S_a)`` on every
    horizontal and vertical pair, ``flow = T[right pair] - T[left pair] +
    T[lower pair] - T[upper pair]``. Work arrays are allocated once and all
    operations write in place (alpha through the law's own NumPy formula with
    output buffers). Single-threaded, as NumPy is; the paper's stopping rule.

    Returns ``(signal, iterations, converged)``.
    """
    law = law or donlon2018()
    m = np.asarray(measured, dtype=np.float64)
    ny, nx = m.shape
    padded = np.zeros((ny + 2, nx + 2))
    padded[1:-1, 1:-1] = m
    nxt = np.empty_like(m)
    # pair arrays: horizontal (ny, nx + 1), vertical (ny + 1, nx)
    bufs = {name: [np.empty(shape) for _ in range(3)]
            for name, shape in (("h", (ny, nx + 1)), ("v", (ny + 1, nx)))}
    delta = np.empty_like(m)
    converged = False
    q = 0
    for q in range(1, int(max_iter) + 1):  # noqa: B007 (q, the count, is returned)
        flow = nxt  # reuse: nxt holds the flow until the update below
        flow[...] = 0.0
        for name, a, b in (("h", padded[1:-1, :-1], padded[1:-1, 1:]),
                           ("v", padded[:-1, 1:-1], padded[1:, 1:-1])):
            alpha, work, transfer = bufs[name]
            law.alpha(a, b, out=alpha, work=work)            # alpha of the pair
            np.subtract(b, a, out=transfer)
            np.multiply(transfer, alpha, out=transfer)       # net transfer a <- b
            if name == "h":
                flow += transfer[:, 1:]
                flow -= transfer[:, :-1]
            else:
                flow += transfer[1:, :]
                flow -= transfer[:-1, :]
        prev = padded[1:-1, 1:-1]
        np.subtract(m, flow, out=nxt)                        # S_q = M - flow(S_{q-1})
        np.subtract(nxt, prev, out=delta)
        dmax = float(np.abs(delta, out=delta).max())
        smax = float(np.abs(nxt).max())
        prev[...] = nxt
        if iteration.met(dmax, smax, tol):
            converged = True
            break
    return padded[1:-1, 1:-1].copy(), q, converged

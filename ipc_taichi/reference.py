"""Plain-NumPy reference implementation of the coupling and the decoupler.

Written independently of the Taichi kernels: instead of gathering per pixel
over a half stencil, it computes for each directed offset ``d`` the charge
*transfer* array ``T_d[p] = w(d) alpha(S_p, S_{p+d}) S_p`` on a zero-padded
frame and moves it with an array shift. It is vectorised (one pass over the
frame per offset), so it is also the honest NumPy peer in ``make bench``.
Same conventions as :mod:`ipc_taichi.coupling` (edges, bad pixels, geometry).
"""

import numpy as np

from .geometry import Geometry
from .laws import get_law

__all__ = ["couple_reference", "decouple_reference", "flow_reference"]


def flow_reference(signal, law="donlon2018", geometry=None, edge="zero"):
    """Net charge each pixel gains by coupling: ``couple(S) - S`` (2-D, float64).

    Non-finite pixels are bad: excluded from coupling, NaN in the result.
    """
    law = get_law(law)
    geometry = geometry if isinstance(geometry, Geometry) else (
        Geometry.nearest() if geometry is None else Geometry(geometry))
    s = np.asarray(signal, dtype=np.float64)
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
        gain -= transfer
        gain += np.roll(transfer, (dy, dx), axis=(0, 1))  # arrives at p + d
    out = gain[r:r + ny, r:r + nx]
    out[~valid] = np.nan
    return out


def couple_reference(signal, law="donlon2018", geometry=None, edge="zero"):
    """Reference forward model for one 2-D frame (float64)."""
    s = np.asarray(signal, dtype=np.float64)
    return s + flow_reference(s, law, geometry, edge)


def decouple_reference(measured, law="donlon2018", geometry=None, edge="zero", max_iter=20,
                       tol=1e-5):
    """Reference Jacobi decoupler for one 2-D frame.

    Returns ``(signal, iterations, converged, max_delta)`` with the same
    stopping rule as :func:`ipc_taichi.decouple`.
    """
    m = np.asarray(measured, dtype=np.float64)
    prev = m.copy()
    deltas = []
    converged = False
    for q in range(1, int(max_iter) + 1):
        nxt = m - flow_reference(prev, law, geometry, edge)
        dmax = np.nanmax(np.abs(nxt - prev)) if np.isfinite(nxt).any() else 0.0
        smax = np.nanmax(np.abs(nxt)) if np.isfinite(nxt).any() else 0.0
        deltas.append(float(dmax))
        prev = nxt
        if tol > 0 and dmax <= tol * smax:
            converged = True
            break
    return prev, q, converged, deltas

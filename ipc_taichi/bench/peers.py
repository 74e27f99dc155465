"""The peers the benchmark times beside Taichi: the plain-NumPy decoupler
(:func:`ipc_taichi.reference.decouple_numpy`, the fastest NumPy we could
write) and a CuPy peer on CUDA (:class:`CupyPeer`). Neither is a dependency
of the library."""

import numpy as np

from .. import iteration, laws
from ..reference import decouple_numpy

__all__ = ["CupyPeer", "PEER_SOURCE", "decouple_numpy"]


# The CuPy peer: one Jacobi step of the paper's decoupler as a plain CUDA
# kernel (one thread per pixel, 4 alphas, zero signal outside the frame),
# driven from CuPy with the same stopping and divergence rules
# (ipc_taichi.iteration) and CuPy's own max-reductions. Written for this
# benchmark; CuPy is only a peer here, never a dependency.
PEER_SOURCE = r"""
extern "C" __global__ void jacobi_step(const REAL* __restrict__ s, const REAL* __restrict__ m,
                                       REAL* __restrict__ out, const int ny, const int nx,
                                       const REAL amp_diff, const REAL inv_diff,
                                       const REAL amp_level, const REAL inv_level,
                                       const REAL floor_) {
    const int x = blockIdx.x * blockDim.x + threadIdx.x;
    const int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= nx || y >= ny) return;
    const long i = (long)y * nx + x;
    const REAL c = s[i];
    REAL nb[4];
    nb[0] = x > 0 ? s[i - 1] : (REAL)0;
    nb[1] = x + 1 < nx ? s[i + 1] : (REAL)0;
    nb[2] = y > 0 ? s[i - nx] : (REAL)0;
    nb[3] = y + 1 < ny ? s[i + nx] : (REAL)0;
    REAL flow = 0;
#pragma unroll
    for (int k = 0; k < 4; ++k) {
        const REAL n = nb[k];
        const REAL a = amp_diff * exp(-fabs(c - n) * inv_diff)
                     + amp_level * exp(-sqrt(c * c + n * n) * inv_level) + floor_;
        flow += a * (n - c);
    }
    out[i] = m[i] - flow;
}
"""


class CupyPeer:
    """The CuPy peer for one precision (see :data:`PEER_SOURCE`)."""

    def __init__(self, precision):
        import cupy as cp

        self.cp = cp
        self.dtype = np.float64 if precision == "f64" else np.float32
        real = "double" if precision == "f64" else "float"
        self.kernel = cp.RawKernel(f"#define REAL {real}\n" + PEER_SOURCE, "jacobi_step")
        self.params = tuple(self.dtype(v) for v in laws.donlon2018().kernel_params())

    def decouple(self, m):
        """Device-resident: ``m`` a CuPy array; returns ``(signal, iterations)``."""
        cp = self.cp
        ny, nx = m.shape
        prev, nxt = m.copy(), cp.empty_like(m)
        block = (32, 8, 1)
        grid = ((nx + 31) // 32, (ny + 7) // 8, 1)
        deltas, signals = [], []
        for q in range(1, iteration.MAX_ITER + 1):  # noqa: B007 (q is returned)
            self.kernel(grid, block, (prev, m, nxt, np.int32(ny), np.int32(nx)) + self.params)
            deltas.append(float(cp.abs(nxt - prev).max()))
            signals.append(float(cp.abs(nxt).max()))
            iteration.check_divergence(deltas, signals)
            prev, nxt = nxt, prev
            if iteration.met(deltas[-1], signals[-1], iteration.TOL):
                break
        return prev, q

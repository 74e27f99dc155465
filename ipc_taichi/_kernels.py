"""Taichi kernels: one coupling step, shared by the forward model and the decoupler.

``step`` computes, for every pixel,

    dst = base + sign * flow(src)
    flow(S)[p] = sum over neighbours q of  w(q->p) alpha(S_q, S_p) S_q  -  w(p->q) alpha(S_p, S_q) S_p

- forward model (couple):   base = S, src = S, sign = +1  ->  M
- one Jacobi iteration:      base = M, src = S_{q-1}, sign = -1  ->  S_q   (paper Eq. 6)

and fuses the stopping-rule reductions ``max|dst - src|`` and ``max|dst|``
into the same pass. Because alpha is symmetric, each neighbour pair needs a
single alpha evaluation per side: the loop runs over the geometry's half
stencil ``u`` and handles ``p+u`` and ``p-u`` together.

Compile-time (``ti.static``) choices form a frozen, hashable config: the
half-stencil offsets, the law kind, the edge rule, whether a bad-pixel mask is
present, and the precision. Law coefficients and geometry weights are run-time
ndarray arguments, so changing a number never recompiles.
"""

import functools
from dataclasses import dataclass

from . import runtime

__all__ = ["KernelConfig", "get_step_kernel"]


@dataclass(frozen=True)
class KernelConfig:
    offsets: tuple  # half-stencil offsets ((dy, dx), ...)
    law_kind: str  # "parametric" | "table"
    edge: str  # "zero" | "isolated"
    masked: bool
    precision: str  # "f64" | "f32"


@functools.lru_cache(maxsize=None)
def get_step_kernel(config):
    """Build (once per config) the Taichi kernel for one coupling step."""
    import taichi as ti

    real = ti.f64 if config.precision == "f64" else ti.f32
    offsets = config.offsets
    n_off = len(offsets)
    table_law = config.law_kind == "table"
    zero_edge = config.edge == "zero"
    masked = config.masked

    @ti.func
    def alpha(s, n, p: ti.template(), table: ti.template()):
        a = ti.cast(0.0, real)
        if ti.static(table_law):
            last = p[2]
            u = ti.min(ti.max((s - p[0]) * p[1], 0.0), last)
            v = ti.min(ti.max((n - p[0]) * p[1], 0.0), last)
            i0 = ti.min(ti.cast(ti.floor(u), ti.i32), ti.cast(last, ti.i32) - 1)
            j0 = ti.min(ti.cast(ti.floor(v), ti.i32), ti.cast(last, ti.i32) - 1)
            fu = u - i0
            fv = v - j0
            a = ((1 - fu) * ((1 - fv) * table[i0, j0] + fv * table[i0, j0 + 1])
                 + fu * ((1 - fv) * table[i0 + 1, j0] + fv * table[i0 + 1, j0 + 1]))
        else:
            a = (p[0] * ti.exp(-ti.abs(s - n) * p[1])
                 + p[2] * ti.exp(-ti.sqrt(s * s + n * n) * p[3]) + p[4])
        return a

    @ti.kernel
    def step(src: ti.types.ndarray(dtype=real, ndim=2),
             base: ti.types.ndarray(dtype=real, ndim=2),
             dst: ti.types.ndarray(dtype=real, ndim=2),
             mask: ti.types.ndarray(dtype=ti.u8, ndim=2),
             p: ti.types.ndarray(dtype=real, ndim=1),
             w: ti.types.ndarray(dtype=real, ndim=2),
             table: ti.types.ndarray(dtype=real, ndim=2),
             sign: real,
             stats: ti.types.ndarray(dtype=real, ndim=1)):
        h = src.shape[0]
        wd = src.shape[1]
        # rows in parallel, columns serial: cache-friendly, and one atomic per
        # row for the stopping-rule maxima instead of one per pixel
        for i in range(h):
            dmax = ti.cast(0.0, real)
            smax = ti.cast(0.0, real)
            for j in range(wd):
                good = True
                if ti.static(masked):
                    good = mask[i, j] != 0
                if good:
                    s = src[i, j]
                    flow = ti.cast(0.0, real)
                    for k in ti.static(range(n_off)):
                        dy, dx = ti.static(offsets[k])
                        wp = w[k, 0]  # weight of the move p -> p+u
                        wm = w[k, 1]  # weight of the move p -> p-u
                        # neighbour at p + u: it sends by -u (wm), p sends to it by +u (wp)
                        ii = i + dy
                        jj = j + dx
                        if 0 <= ii < h and 0 <= jj < wd:
                            ok = True
                            if ti.static(masked):
                                ok = mask[ii, jj] != 0
                            if ok:
                                n = src[ii, jj]
                                flow += alpha(s, n, p, table) * (wm * n - wp * s)
                        elif ti.static(zero_edge):
                            flow -= alpha(s, 0.0, p, table) * wp * s
                        # neighbour at p - u: it sends by +u (wp), p sends to it by -u (wm)
                        ii = i - dy
                        jj = j - dx
                        if 0 <= ii < h and 0 <= jj < wd:
                            ok = True
                            if ti.static(masked):
                                ok = mask[ii, jj] != 0
                            if ok:
                                n = src[ii, jj]
                                flow += alpha(s, n, p, table) * (wp * n - wm * s)
                        elif ti.static(zero_edge):
                            flow -= alpha(s, 0.0, p, table) * wm * s
                    v = base[i, j] + sign * flow
                    dst[i, j] = v
                    dmax = ti.max(dmax, ti.abs(v - s))
                    smax = ti.max(smax, ti.abs(v))
                else:
                    dst[i, j] = 0.0
            ti.atomic_max(stats[0], dmax)
            ti.atomic_max(stats[1], smax)

    return step


runtime.on_reset(get_step_kernel.cache_clear)

"""Taichi kernels: one coupling step, shared by the forward model and the decoupler,
and the kernels that bring a frame in and out of the padded working arrays.

``step`` computes, for every pixel,

    dst = base + sign * flow(src)
    flow(S)[p] = sum over neighbours q of  w(q->p) alpha(S_q, S_p) S_q
                                         - w(p->q) alpha(S_p, S_q) S_p

- forward model (couple):   base = S, src = S, sign = +1  ->  M
- one Jacobi iteration:      base = M, src = S_{q-1}, sign = -1  ->  S_q   (paper Eq. 6)

and fuses the stopping-rule reductions ``max|dst - src|`` and ``max|dst|``
into the same launch.

Arrays
------
``src`` and ``dst`` are **padded**: the frame lives inside a border of ``reach``
pixels (the geometry's furthest offset) that holds zero signal and is never
written. With the ``zero`` edge those border pixels are exactly the paper's
"outside = zero signal" pixels, so no pixel needs a bounds test. With the
``isolated`` edge, or with bad pixels, an ``ok`` byte array (1 = may couple)
zeroes every alpha that touches the border or a bad pixel. ``base`` is the
*unpadded* frame (it is read at the pixel itself only), so the measured frame
needs no padded copy. :func:`~ipc_taichi._frames.get_frame_kernels` gives ``load`` (unpadded frame
-> padded estimate, bad pixels zeroed, ``ok`` written, one flag set if any
pixel is bad) and ``store`` (padded estimate -> unpadded frame), so padding and
initialisation happen where the arrays live (on the GPU for CUDA).

The stopping-rule maxima
------------------------
Each thread (a CPU strip, a GPU column run) keeps its two running maxima in
registers and stores them, with a plain store, into its own row of a
``partials`` array of shape ``(P, 2)``; no atomic is issued. The same kernel
``pixel`` launch then reduces ``partials`` in place by a tree of
:data:`TREE_LEVELS` parallel passes, each thread taking the maximum of
:data:`FAN_IN` entries (strided, so neighbouring threads read neighbouring
addresses; indices past the end are clamped to the last entry, which repeats a
value and leaves the maximum unchanged); row 0 then holds
``(max|dst - src|, max|dst|)`` (rows ``0 .. tree_rows(P) - 1`` when ``P``
exceeds the tree's capacity: the host takes their maximum). The CPU ``sweep``
writes one row per strip (a few dozen) and the host takes their maximum: on a
CPU each extra parallel task costs a wake-up of the thread pool, more than the
few dozen comparisons. A maximum is exact in any order, so the result does not
depend on the layout or the reduction.

Three loop layouts, chosen at compile time (``KernelConfig.layout``, the name
of one of the layout objects of :mod:`ipc_taichi._layouts`, which own every
choice that depends on it): the two below, and ``lanes`` (the CPU's default),
the ``sweep`` on vectors of ``L`` pixels, SIMD, bit-identical to it
(:mod:`ipc_taichi._lanes`).

``sweep`` (CPU)
    Rows are cut into strips, one strip per task; a task sweeps its rows left
    to right. alpha is symmetric, so each neighbour *pair* is evaluated once:
    the pair with the pixel on the right (offsets ``(0, dx)``) is carried in
    registers to the next column, pairs with rows below (``dy > 0``) go into a
    small per-strip ring buffer of rows and are read back ``dy`` rows later.
    Per pixel and iteration this is one alpha per half-stencil offset instead
    of two, and all the scratch data stays in L1/L2. Taichi's CPU backend does
    not vectorise these loops (no vector types in its optimised LLVM IR),
    so the cost is the scalar transcendental math: the exponentials use an
    inlined range-reduced polynomial (:func:`make_exp`, < 1e-15 relative error),
    which makes the sweep 1.7x faster than with the libm call.
``pixel`` (CUDA)
    One thread per pixel column run: thread ``(b, x)`` walks down rows
    ``b*R .. b*R + R - 1`` of column ``x`` (``R`` = ``strip``, chosen per frame
    so that there are enough threads to fill a GPU). Neighbouring threads
    handle neighbouring columns, so every row access of a warp is coalesced.
    The alpha of each vertical pair ``(dy, 0)`` is computed once and carried
    down in registers (3 alphas per pixel instead of 4 for nearest
    neighbours); the other pairs' alphas are computed by both pixels
    (arithmetic is cheap on a GPU, memory traffic is not). The layout also
    runs on the CPU, which is how it is tested without a GPU.

A constant law without ``ok`` gating (no bad pixel, the ``zero`` edge) takes
the flow with coefficients combined once per thread
(:attr:`~ipc_taichi._layouts.StepPlan.combined`):
``sum_k a w[k, 1] S(p+u) + a w[k, 0] S(p-u) - (a sum_k (w[k, 0] + w[k, 1])) S(p)``,
two multiply-adds per offset instead of ten operations (1.2-1.4x faster per
iteration; the same values to rounding: at most one float32 unit, 4e-15
relative in f64, on the recorded cases).

A bond map (:mod:`ipc_taichi.bondmap`, :attr:`KernelConfig.mapped`) is the
``bonds`` argument: one array per half-stencil offset, padded like the frames
with the map's edge rule and read at the same index (flat: the maps one after
the other; 2-D path: ``[k, y, x]``; ``lanes``: vectors). Each pair's alpha is
multiplied by its bond's factor where it is computed (``pair``), so a carried
alpha carries it, both directions use it, and every layout reads the map in
the one place it evaluates a pair. A step without a map takes the argument and
never reads it: its code is the map-less one.

Compile-time (``ti.static``) choices form a frozen, hashable config
(:class:`KernelConfig`); its layout's :class:`~ipc_taichi._layouts.StepPlan`
adds what follows from it (where each carried alpha lives), and
:func:`~ipc_taichi._layouts.get_step_kernel` has the layout compose its kernel
(:func:`sweep_kernel`, :func:`pixel_kernel`, :func:`ipc_taichi._lanes.lanes_kernel`)
from small named device functions built on that plan
(:mod:`ipc_taichi._stepparts`). On the host the arrays are passed flat
(``KernelConfig.flat``): Taichi's CPU code reloads a 2-D array's shape and
data pointer at every access, which cost the sweep 1.3-1.5x. Law
coefficients and geometry weights are run-time ndarray arguments, so changing
a number never recompiles; frame sizes, the border width and the strip height
are run-time arguments too.
"""

import functools
from dataclasses import dataclass

from . import runtime
from ._alpha import kernel_law_kind, make_alpha, make_exp
from ._frames import MAX_FINITE, FrameKernels, get_frame_kernels
from ._stepparts import (
    access_functions,
    arg_types,
    flow_functions,
    law_functions,
    make_frame_size,
    make_larger,
    real_type,
    start_functions,
)

__all__ = ["KernelConfig", "sweep_kernel", "pixel_kernel", "get_frame_kernels",
           "get_reduce_kernel", "SPREAD", "tree_rows", "FAN_IN", "TREE_LEVELS", "MAX_FINITE",
           "FrameKernels",
           # the device law, from ._alpha
           "kernel_law_kind", "make_alpha", "make_exp"]

SPREAD = 512  # ``sweep`` layout: loop iterations per strip (see step_sweep)
FAN_IN = 32  # entries one thread reduces per tree level
TREE_LEVELS = 5  # tree passes: up to FAN_IN ** TREE_LEVELS (33.5 M) partials


@dataclass(frozen=True)
class KernelConfig:
    offsets: tuple  # half-stencil offsets ((dy, dx), ...), dy > 0 or (dy == 0 and dx > 0)
    law_kind: str  # "parametric" | "table" | "constant" (see kernel_law_kind)
    edge: str  # "zero" | "isolated"
    masked: bool
    precision: str  # "f64" | "f32"
    layout: str = "sweep"  # "sweep" | "pixel" | "lanes" (see ipc_taichi._layouts)
    # arrays passed flat (1-D, row-major) and indexed as row * width + column,
    # as the host path does (Taichi's CPU code reloads a 2-D array's shape at
    # every access); False: 2-D Taichi ndarrays, the device path
    flat: bool = True
    # a bond map multiplies each pair's alpha (the ``bonds`` argument, one
    # padded array per half-stencil offset); False: the argument is unused
    # and the step is the map-less one, unchanged
    mapped: bool = False

    @property
    def reach(self):
        return max(max(abs(dy), abs(dx)) for dy, dx in self.offsets)

    @property
    def uses_ok(self):
        """Whether alphas are gated by the ``ok`` array (bad pixels, isolated edge)."""
        return self.masked or self.edge == "isolated"

    @property
    def ring_depth(self):
        """Rows kept per ``dy > 0`` offset in the sweep's ring buffer."""
        return 1 + max(dy for dy, _ in self.offsets)

    @property
    def vertical(self):
        """Indices of the offsets with ``dy > 0`` (ring-buffered in the sweep)."""
        return tuple(k for k, (dy, _) in enumerate(self.offsets) if dy > 0)


def tree_rows(n):
    """Rows of ``partials`` that hold the maxima after the tree has reduced
    ``n`` entries: 1 up to ``FAN_IN ** TREE_LEVELS`` entries, more beyond
    (a frame wider than that many columns); the host takes their maximum."""
    return -(-n // FAN_IN ** TREE_LEVELS)


def make_tree_reduction():
    """``(shrink, passes)``: with ``n1 = shrink(n0)``, ..., ``n5 = shrink(n4)``
    worked out at the start of the kernel (its serial prologue, so that the
    passes run back to back with no serial task between them),
    ``passes(part, n0, ..., n5)`` leaves the maximum of ``part[:n0]`` (shape
    ``(P, 2)``) in ``part[0]``, by :data:`TREE_LEVELS` parallel passes of
    :data:`FAN_IN` (see the module docstring). Called at a kernel's top level,
    each pass is a parallel loop of its own, run after the previous one."""
    import taichi as ti

    @ti.func
    def level(part: ti.template(), n, g_count):
        # thread g reads g, g + G, g + 2G, ... (coalesced across threads) and
        # writes entry g < G, which no other thread of this pass reads
        for g in range(g_count):
            m0 = part[g, 0]
            m1 = part[g, 1]
            for j in ti.static(range(1, FAN_IN)):
                k = ti.min(g + j * g_count, n - 1)
                m0 = ti.max(m0, part[k, 0])
                m1 = ti.max(m1, part[k, 1])
            part[g, 0] = m0
            part[g, 1] = m1

    @ti.func
    def shrink(n):
        """Entries left after one pass over ``n``."""
        return (n + FAN_IN - 1) // FAN_IN

    @ti.func
    def passes(part: ti.template(), n0, n1, n2, n3, n4, n5):
        level(part, n0, n1)
        level(part, n1, n2)
        level(part, n2, n3)
        level(part, n3, n4)
        level(part, n4, n5)

    assert TREE_LEVELS == 5  # the passes above are written out
    return shrink, passes


@functools.cache
def get_reduce_kernel(precision):
    """A kernel running the tree reduction alone (the steps fuse it; tests
    and the benchmark call it on its own)."""
    import taichi as ti

    real = ti.f64 if precision == "f64" else ti.f32
    shrink, passes = make_tree_reduction()

    @ti.kernel
    def reduce_partials(part: ti.types.ndarray(dtype=real, ndim=2), n: ti.i32):
        n1 = shrink(n)
        n2 = shrink(n1)
        n3 = shrink(n2)
        n4 = shrink(n3)
        n5 = shrink(n4)
        passes(part, n, n1, n2, n3, n4, n5)

    return reduce_partials


def _step_parts(plan):
    """``(coefficients, pixel_flow, emit, starts)``: the device functions of
    :mod:`ipc_taichi._stepparts` a scalar step is composed of."""
    coefficients, pair, pair_of = law_functions(plan)
    pixel_flow, emit = flow_functions(plan, pair, pair_of)
    return coefficients, pixel_flow, emit, start_functions(plan, pair)


def sweep_kernel(plan):
    """The ``sweep`` layout's step (see the module docstring)."""
    import taichi as ti

    real, r = real_type(plan), plan.config.reach
    coefficients, pixel_flow, emit, starts = _step_parts(plan)
    ring_prologue, ring_row_ends, row_start, _ = starts
    frame, vector, mask, scratch, small, bond = arg_types(plan)
    cell = access_functions(plan)[0]
    frame_size = make_frame_size(plan)
    larger = make_larger()

    @ti.func
    def strip_rows(src: ti.template(), base: ti.template(), dst: ti.template(),
                   ok: ti.template(), bonds: ti.template(), coef: ti.template(),
                   table: ti.template(), sign, part: ti.template(), ring: ti.template(), s,
                   i0, i1, wd):
        """Rows i0 .. i1 - 1 of strip s, left to right; its maxima into part[s]."""
        dmax = ti.cast(0.0, real)
        smax = ti.cast(0.0, real)
        if ti.static(plan.rings):
            ring_prologue(src, ok, bonds, table, coef, ring, s, i0, wd)
        pw = wd + 2 * r
        for i in range(i0, i1):
            y = i + r
            if ti.static(plan.rings):
                ring_row_ends(src, ok, bonds, table, coef, ring, s, i, wd)
            carry = ti.Vector([0.0] * plan.carry_size, dt=real)
            if ti.static(plan.carries_row):
                row_start(src, ok, bonds, table, coef, carry, pw, y)
            for j in range(wd):
                x = j + r
                sv = cell(src, y, x, pw)
                flow = pixel_flow(src, ok, bonds, coef, table, ring, pw, s, i, y, x, sv, carry)
                v = emit(base, dst, sign, pw, i, j, flow)
                dmax = larger(dmax, ti.abs(v - sv))
                smax = larger(smax, ti.abs(v))
        part[s, 0] = dmax
        part[s, 1] = smax

    @ti.kernel
    def step_sweep(src: frame, base: frame, dst: frame, ok: mask, bonds: bond, p: vector,
                   w: small, table: frame, sign: real, part: small, ring: scratch, strip: ti.i32,
                   width: ti.i32):
        size = frame_size(src, base, width)
        h = size[0]
        wd = size[1]
        # One strip per task. Taichi 1.7's CPU backend hands out a parallel
        # range in chunks of up to 512 iterations whatever block_dim says, so a
        # loop over a few dozen strips would run on one thread: spread the
        # strips 512 iterations apart and let only the first of each do the work.
        for task in range((h + strip - 1) // strip * SPREAD):
            if task % SPREAD == 0:
                s = task // SPREAD
                coef = coefficients(p, w)
                i0 = s * strip
                strip_rows(src, base, dst, ok, bonds, coef, table, sign, part, ring, s, i0,
                           ti.min(h, i0 + strip), wd)

    return step_sweep


def pixel_kernel(plan):
    """The ``pixel`` layout's step, its maxima tree-reduced in the same launch."""
    import taichi as ti

    real, r = real_type(plan), plan.config.reach
    coefficients, pixel_flow, emit, starts = _step_parts(plan)
    column_start = starts[3]
    frame, vector, mask, scratch, small, bond = arg_types(plan)
    cell = access_functions(plan)[0]
    frame_size = make_frame_size(plan)
    larger = make_larger()
    shrink, passes = make_tree_reduction()

    @ti.kernel
    def step_pixel(src: frame, base: frame, dst: frame, ok: mask, bonds: bond, p: vector,
                   w: small, table: frame, sign: real, part: small, ring: scratch, strip: ti.i32,
                   width: ti.i32):
        size = frame_size(src, base, width)
        h = size[0]
        wd = size[1]
        pw = wd + 2 * r
        runs = (h + strip - 1) // strip
        n0 = runs * wd
        n1 = shrink(n0)
        n2 = shrink(n1)
        n3 = shrink(n2)
        n4 = shrink(n3)
        n5 = shrink(n4)
        for b, j in ti.ndrange(runs, wd):
            x = j + r
            coef = coefficients(p, w)
            i0 = b * strip
            i1 = ti.min(h, i0 + strip)
            dmax = ti.cast(0.0, real)
            smax = ti.cast(0.0, real)
            carry = ti.Vector([0.0] * plan.carry_size, dt=real)
            column_start(src, ok, bonds, table, coef, carry, pw, i0, x)
            for i in range(i0, i1):
                y = i + r
                sv = cell(src, y, x, pw)
                flow = pixel_flow(src, ok, bonds, coef, table, ring, pw, 0, i, y, x, sv, carry)
                v = emit(base, dst, sign, pw, i, j, flow)
                dmax = larger(dmax, ti.abs(v - sv))
                smax = larger(smax, ti.abs(v))
            part[b * wd + j, 0] = dmax
            part[b * wd + j, 1] = smax
        passes(part, n0, n1, n2, n3, n4, n5)

    return step_pixel


def _clear_caches():
    get_frame_kernels.cache_clear()
    get_reduce_kernel.cache_clear()


runtime.on_reset(_clear_caches)

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

Two loop layouts, chosen at compile time (``KernelConfig.layout``):

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

Compile-time (``ti.static``) choices form a frozen, hashable config
(:class:`KernelConfig`); :class:`StepPlan` adds what follows from it (where
each carried alpha lives), and :func:`get_step_kernel` composes a layout's
kernel from small named device functions built on that plan. Law
coefficients and geometry weights are run-time ndarray arguments, so changing
a number never recompiles; frame sizes, the border width and the strip height
are run-time arguments too.
"""

import functools
from dataclasses import dataclass

from . import runtime
from ._alpha import kernel_law_kind, make_alpha, make_exp
from ._frames import MAX_FINITE, FrameKernels, get_frame_kernels

__all__ = ["KernelConfig", "StepPlan", "alpha_sources", "get_step_kernel", "get_frame_kernels",
           "get_reduce_kernel", "LAYOUTS", "partials_count", "tree_rows", "FAN_IN",
           "TREE_LEVELS", "MAX_FINITE", "FrameKernels",
           # the device law, from ._alpha
           "kernel_law_kind", "make_alpha", "make_exp"]

LAYOUTS = ("sweep", "pixel")
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
    layout: str = "sweep"  # "sweep" (CPU) | "pixel" (CUDA)
    # arrays passed flat (1-D, row-major) and indexed as row * width + column,
    # as the host path does (Taichi's CPU code reloads a 2-D array's shape at
    # every access); False: 2-D Taichi ndarrays, the device path
    flat: bool = True

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


def partials_count(layout, height, width, strip):
    """Rows of the ``partials`` array a step on a ``height x width`` frame
    (unpadded) writes: one per strip (sweep) or per column run (pixel)."""
    strips = -(-height // strip)
    return strips if layout == "sweep" else strips * width


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


def alpha_sources(config):
    """Where each half-stencil offset's second alpha (``a_minus``, the pair
    with the neighbour at ``p - u``) comes from, per offset (static):

    - ``"row"``: the sweep's registers, carried along the row (``dy == 0``);
    - ``"ring"``: the sweep's ring buffer, written ``dy`` rows earlier;
    - ``"column"``: the pixel layout's registers, carried down the column (``dx == 0``);
    - ``"fresh"``: evaluated again (the pixel layout's other offsets, and every
      offset of a constant law, whose alpha is one number: nothing to carry).
    """
    if config.law_kind == "constant":
        return ("fresh",) * len(config.offsets)
    if config.layout == "sweep":
        return tuple("row" if dy == 0 else "ring" for dy, _ in config.offsets)
    return tuple("column" if dx == 0 else "fresh" for _, dx in config.offsets)


@dataclass(frozen=True)
class StepPlan:
    """The compile-time plan of one step kernel: its :class:`KernelConfig` and
    the static bookkeeping of the carried alphas, worked out once in plain
    Python (:meth:`of`); every field is a ``ti.static`` value in the kernels."""

    config: KernelConfig
    sources: tuple  # per offset: where its a_minus comes from (alpha_sources)
    carry_at: tuple  # per offset: its first row register (sweep, dy == 0)
    vcarry_at: tuple  # per offset: its first column register (pixel, dx == 0)
    ring_index: tuple  # per offset: its ring slot (dy > 0), else -1
    left_extra: tuple  # per ring slot: columns left of 0 that later rows read back
    right_extra: tuple  # per ring slot: columns right of the last that later rows read
    prologue_lo: tuple  # per ring slot: the first column of the prologue rows
    carry_size: int  # registers carried along a row (sweep) or down a column (pixel)

    @classmethod
    def of(cls, config):
        if config.layout not in LAYOUTS:
            raise ValueError(f"unknown kernel layout {config.layout!r}")
        offsets, vertical = config.offsets, config.vertical
        n_off = len(offsets)
        n_carry = max(1, sum(dx for dy, dx in offsets if dy == 0))
        n_vcarry = max(1, sum(dy for dy, dx in offsets if dx == 0))
        return cls(
            config=config, sources=alpha_sources(config),
            carry_at=tuple(sum(ddx for ddy, ddx in offsets[:k] if ddy == 0)
                           for k in range(n_off)),
            vcarry_at=tuple(sum(ddy for ddy, ddx in offsets[:k] if ddx == 0)
                            for k in range(n_off)),
            ring_index=tuple(vertical.index(k) if k in vertical else -1 for k in range(n_off)),
            left_extra=tuple(tuple(range(-offsets[k][1], 0)) for k in vertical),
            right_extra=tuple(max(0, -offsets[k][1]) for k in vertical),
            prologue_lo=tuple(min(0, -offsets[k][1]) for k in vertical),
            carry_size=n_carry if config.layout == "sweep" else n_vcarry)

    @property
    def law_at(self):
        """Where the law's 5 kernel parameters start among the coefficients."""
        return 2 * len(self.config.offsets)

    @property
    def n_coef(self):
        """Registers of ``coefficients``: two weights per offset, then the law's
        5 parameters (a constant law's alpha last)."""
        return self.law_at + 5

    @property
    def rings(self):
        return "ring" in self.sources

    @property
    def carries_row(self):
        return "row" in self.sources


def make_larger():
    """``larger(a, b)``: the larger of two values, as a compare and a select.
    For the stopping-rule maxima of values that are never NaN it is
    ``ti.max`` bit for bit (and NaN is ignored by both), without the NaN
    handling of LLVM's ``maxnum`` that sits on the maxima's loop-carried
    dependency chain (measured: that chain cost the sweep about 20 %)."""
    import taichi as ti

    @ti.func
    def larger(a, b):
        return ti.select(b > a, b, a)

    return larger


def _real(plan):
    import taichi as ti

    return ti.f64 if plan.config.precision == "f64" else ti.f32


def _access_functions(plan):
    """``(cell, put, ring_cell, ring_put)``: an array's value at row ``y``,
    column ``x`` of a frame ``width`` columns wide (and its store), and the
    sweep's ring rows (strip ``s``, slot ``kv``, frame row ``row``, column
    ``x``). With :attr:`KernelConfig.flat` the arrays are 1-D, indexed
    ``y * width + x``; else 2-D (4-D for the ring) and ``width`` is unused."""
    import taichi as ti

    flat, depth = plan.config.flat, plan.config.ring_depth
    slots = max(1, len(plan.config.vertical))  # the workspace's ring has as many

    @ti.func
    def index(y, x, width):
        return y * width + x

    @ti.func
    def cell(a: ti.template(), y, x, width):
        if ti.static(flat):
            return a[index(y, x, width)]
        else:
            return a[y, x]

    @ti.func
    def put(a: ti.template(), y, x, width, v):
        if ti.static(flat):
            a[index(y, x, width)] = v
        else:
            a[y, x] = v

    @ti.func
    def ring_cell(ring: ti.template(), s, kv: ti.template(), row, x, width):
        if ti.static(flat):
            return ring[index((s * slots + kv) * depth + row % depth, x, width)]
        else:
            return ring[s, kv, row % depth, x]

    @ti.func
    def ring_put(ring: ti.template(), s, kv: ti.template(), row, x, width, v):
        if ti.static(flat):
            ring[index((s * slots + kv) * depth + row % depth, x, width)] = v
        else:
            ring[s, kv, row % depth, x] = v

    return cell, put, ring_cell, ring_put


def _law_functions(plan):
    """``(coefficients, pair, pair_of)``: the weights and the law read into
    registers; one pair's alpha (``pair_of``: given the first pixel's signal)."""
    import taichi as ti

    config, real, n_coef, law_at = plan.config, _real(plan), plan.n_coef, plan.law_at
    constant_law = config.law_kind == "constant"
    alpha = make_alpha(config.law_kind, config.precision, fast_exp=config.layout == "sweep",
                       flat_table=config.flat)
    cell = _access_functions(plan)[0]

    @ti.func
    def coefficients(p: ti.template(), w: ti.template()):
        """The geometry's weights ``(w[k, 0], w[k, 1])`` for each offset k and,
        last, the law's parameters ``p``, read once per thread into registers
        (read from memory at every pixel, the compiler cannot keep them there:
        ``dst`` might alias them)."""
        coef = ti.Vector([0.0] * n_coef, dt=real)
        for k in ti.static(range(len(config.offsets))):
            coef[2 * k] = w[k, 0]
            coef[2 * k + 1] = w[k, 1]
        for m in ti.static(range(5)):
            coef[law_at + m] = p[m]
        return coef

    @ti.func
    def law(coef: ti.template()):
        """The law's parameters among the coefficients, as ``alpha`` reads them."""
        return ti.Vector([coef[law_at + m] for m in ti.static(range(5))], dt=real)

    @ti.func
    def pair_of(src: ti.template(), ok: ti.template(), table: ti.template(),
                coef: ti.template(), pw, sv, y, x, dy: ti.template(), dx: ti.template()):
        """alpha of the pair (y, x) -- (y + dy, x + dx), padded coordinates
        (``pw``: the padded width), ``sv`` the signal at (y, x)."""
        a = ti.cast(0.0, real)
        if ti.static(constant_law):
            a = coef[law_at + 4]  # what alpha() returns for this law, kept in a register
        else:
            a = alpha(sv, cell(src, y + dy, x + dx, pw), law(coef), table)
        if ti.static(config.uses_ok):
            a *= ti.cast(cell(ok, y, x, pw) * cell(ok, y + dy, x + dx, pw), real)
        return a

    @ti.func
    def pair(src: ti.template(), ok: ti.template(), p: ti.template(), table: ti.template(),
             coef: ti.template(), pw, y, x, dy: ti.template(), dx: ti.template()):
        """alpha of the pair (y, x) -- (y + dy, x + dx); ``p`` is unused (the
        law's parameters are among ``coef``)."""
        return pair_of(src, ok, table, coef, pw, cell(src, y, x, pw), y, x, dy, dx)

    return coefficients, pair, pair_of


def _flow_functions(plan, pair, pair_of):
    """``(pixel_flow, emit)``: one pixel's coupling term (its alphas taken
    from where :func:`alpha_sources` says), and the new value written."""
    import taichi as ti

    offsets, sources, real, r = plan.config.offsets, plan.sources, _real(plan), plan.config.reach
    cell, put, ring_cell, ring_put = _access_functions(plan)

    @ti.func
    def pair_flow(flow, src: ti.template(), coef: ti.template(), pw, y, x, sv,
                  k: ti.template(), a_plus, a_minus):
        """``flow`` plus what pixel (y, x) gains through offset k: the neighbour
        at p + u sends by -u (weight w[k, 1]), p sends to it by +u (w[k, 0]);
        likewise with the neighbour at p - u."""
        dy, dx = ti.static(offsets[k])
        wp = coef[2 * k]  # weight of the move p -> p+u
        wm = coef[2 * k + 1]  # weight of the move p -> p-u
        return (flow + a_plus * (wm * cell(src, y + dy, x + dx, pw) - wp * sv)
                + a_minus * (wp * cell(src, y - dy, x - dx, pw) - wm * sv))

    @ti.func
    def shift_in(carry: ti.template(), at: ti.template(), n: ti.template(), a):
        """Take the oldest of ``n`` carried alphas out, put ``a`` in; returns it."""
        old = carry[at]
        for m in ti.static(range(n - 1)):
            carry[at + m] = carry[at + m + 1]
        carry[at + n - 1] = a
        return old

    @ti.func
    def pixel_flow(src: ti.template(), ok: ti.template(), p: ti.template(),
                   coef: ti.template(), table: ti.template(), ring: ti.template(), pw, s, i,
                   y, x, sv, carry: ti.template()):
        """The coupling term at padded (y, x) (row ``i`` of the frame); the
        alphas it computes are carried for the pixels that reuse them."""
        flow = ti.cast(0.0, real)
        for k in ti.static(range(len(offsets))):
            dy, dx = ti.static(offsets[k])
            a_plus = pair_of(src, ok, table, coef, pw, sv, y, x, dy, dx)
            a_minus = ti.cast(0.0, real)
            if ti.static(sources[k] == "row"):
                a_minus = shift_in(carry, plan.carry_at[k], dx, a_plus)
            elif ti.static(sources[k] == "ring"):
                kv = ti.static(plan.ring_index[k])
                a_minus = ring_cell(ring, s, kv, i - dy + r, x - dx, pw)
                ring_put(ring, s, kv, i + r, x, pw, a_plus)
            elif ti.static(sources[k] == "column"):
                a_minus = shift_in(carry, plan.vcarry_at[k], dy, a_plus)
            else:
                a_minus = pair(src, ok, p, table, coef, pw, y - dy, x - dx, dy, dx)
            flow = pair_flow(flow, src, coef, pw, y, x, sv, k, a_plus, a_minus)
        return flow

    @ti.func
    def emit(base: ti.template(), dst: ti.template(), sign, pw, i, j, flow):
        """Write ``base + sign * flow`` at frame pixel (i, j); returns it."""
        v = cell(base, i, j, pw - 2 * r) + sign * flow
        put(dst, i + r, j + r, pw, v)
        return v

    return pixel_flow, emit


def _start_functions(plan, pair):
    """The alphas of pairs that start before a strip, row or column run and
    that its pixels read back: ``(ring_prologue, ring_row_ends, row_start,
    column_start)``."""
    import taichi as ti

    offsets, vertical, r = plan.config.offsets, plan.config.vertical, plan.config.reach
    ring_put = _access_functions(plan)[3]

    @ti.func
    def ring_prologue(src: ti.template(), ok: ti.template(), p: ti.template(),
                      table: ti.template(), coef: ti.template(), ring: ti.template(), s, i0,
                      wd):
        """Sweep: the pairs that start in the dy rows above the strip."""
        for kv in ti.static(range(len(vertical))):
            dy, dx = ti.static(offsets[vertical[kv]])
            for row in range(i0 - dy, i0):
                for c in range(plan.prologue_lo[kv], wd + plan.right_extra[kv]):
                    ring_put(ring, s, kv, row + r, c + r, wd + 2 * r,
                             pair(src, ok, p, table, coef, wd + 2 * r, row + r, c + r, dy, dx))

    @ti.func
    def ring_row_ends(src: ti.template(), ok: ti.template(), p: ti.template(),
                      table: ti.template(), coef: ti.template(), ring: ti.template(), s, i,
                      wd):
        """Sweep: row i's pairs starting beyond its ends that later rows read back."""
        y = i + r
        pw = wd + 2 * r
        for kv in ti.static(range(len(vertical))):
            dy, dx = ti.static(offsets[vertical[kv]])
            for c in ti.static(plan.left_extra[kv]):
                ring_put(ring, s, kv, y, c + r, pw, pair(src, ok, p, table, coef, pw, y, c + r,
                                                        dy, dx))
            for c in range(wd, wd + plan.right_extra[kv]):
                ring_put(ring, s, kv, y, c + r, pw, pair(src, ok, p, table, coef, pw, y, c + r,
                                                        dy, dx))

    @ti.func
    def row_start(src: ti.template(), ok: ti.template(), p: ti.template(),
                  table: ti.template(), coef: ti.template(), carry: ti.template(), pw, y):
        """Sweep: the horizontal pairs left of column 0, into the row registers."""
        for k in ti.static(range(len(offsets))):
            dy, dx = ti.static(offsets[k])
            if ti.static(plan.sources[k] == "row"):
                for m in ti.static(range(dx)):
                    carry[plan.carry_at[k] + m] = pair(src, ok, p, table, coef, pw, y,
                                                       r - dx + m, 0, dx)

    @ti.func
    def column_start(src: ti.template(), ok: ti.template(), p: ti.template(),
                     table: ti.template(), coef: ti.template(), carry: ti.template(), pw, i0,
                     x):
        """Pixel: the vertical pairs (dy, 0) that end in the run's first dy rows."""
        for k in ti.static(range(len(offsets))):
            dy, dx = ti.static(offsets[k])
            if ti.static(plan.sources[k] == "column"):
                for m in ti.static(range(dy)):
                    carry[plan.vcarry_at[k] + m] = pair(src, ok, p, table, coef, pw,
                                                        i0 + r - dy + m, x, dy, 0)

    return ring_prologue, ring_row_ends, row_start, column_start


def _arg_types(plan):
    """The step kernels' argument types: (frame, vector, mask, scratch, small):
    frames, the ``ok`` mask, the ring and the law's table 1-D with
    :attr:`KernelConfig.flat`; ``w`` and ``part`` (small) always 2-D."""
    import taichi as ti

    real, flat = _real(plan), plan.config.flat
    small = ti.types.ndarray(dtype=real, ndim=2)
    return (ti.types.ndarray(dtype=real, ndim=1 if flat else 2),
            ti.types.ndarray(dtype=real, ndim=1), ti.types.ndarray(dtype=ti.u8,
                                                                   ndim=1 if flat else 2),
            ti.types.ndarray(dtype=real, ndim=1 if flat else 4), small)


def _frame_size(plan):
    """``frame_size(src, base, width)``: the unpadded ``(height, width)``."""
    import taichi as ti

    flat, r = plan.config.flat, plan.config.reach

    @ti.func
    def frame_size(src: ti.template(), base: ti.template(), width):
        h = 0
        wd = 0
        if ti.static(flat):
            h = base.shape[0] // width
            wd = width
        else:
            h = src.shape[0] - 2 * r
            wd = src.shape[1] - 2 * r
        return ti.Vector([h, wd])

    return frame_size


def _sweep_kernel(plan, coefficients, pixel_flow, emit, starts):
    """The ``sweep`` layout's step (see the module docstring)."""
    import taichi as ti

    real, r = _real(plan), plan.config.reach
    ring_prologue, ring_row_ends, row_start, _ = starts
    frame, vector, mask, scratch, small = _arg_types(plan)
    cell = _access_functions(plan)[0]
    frame_size = _frame_size(plan)
    larger = make_larger()

    @ti.func
    def strip_rows(src: ti.template(), base: ti.template(), dst: ti.template(),
                   ok: ti.template(), p: ti.template(), coef: ti.template(),
                   table: ti.template(), sign, part: ti.template(), ring: ti.template(), s,
                   i0, i1, wd):
        """Rows i0 .. i1 - 1 of strip s, left to right; its maxima into part[s]."""
        dmax = ti.cast(0.0, real)
        smax = ti.cast(0.0, real)
        if ti.static(plan.rings):
            ring_prologue(src, ok, p, table, coef, ring, s, i0, wd)
        pw = wd + 2 * r
        for i in range(i0, i1):
            y = i + r
            if ti.static(plan.rings):
                ring_row_ends(src, ok, p, table, coef, ring, s, i, wd)
            carry = ti.Vector([0.0] * plan.carry_size, dt=real)
            if ti.static(plan.carries_row):
                row_start(src, ok, p, table, coef, carry, pw, y)
            for j in range(wd):
                x = j + r
                sv = cell(src, y, x, pw)
                flow = pixel_flow(src, ok, p, coef, table, ring, pw, s, i, y, x, sv, carry)
                v = emit(base, dst, sign, pw, i, j, flow)
                dmax = larger(dmax, ti.abs(v - sv))
                smax = larger(smax, ti.abs(v))
        part[s, 0] = dmax
        part[s, 1] = smax

    @ti.kernel
    def step_sweep(src: frame, base: frame, dst: frame, ok: mask, p: vector, w: small,
                   table: frame, sign: real, part: small, ring: scratch, strip: ti.i32,
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
                strip_rows(src, base, dst, ok, p, coef, table, sign, part, ring, s, i0,
                           ti.min(h, i0 + strip), wd)

    return step_sweep


def _pixel_kernel(plan, coefficients, pixel_flow, emit, starts):
    """The ``pixel`` layout's step, its maxima tree-reduced in the same launch."""
    import taichi as ti

    real, r = _real(plan), plan.config.reach
    column_start = starts[3]
    frame, vector, mask, scratch, small = _arg_types(plan)
    cell = _access_functions(plan)[0]
    frame_size = _frame_size(plan)
    larger = make_larger()
    shrink, passes = make_tree_reduction()

    @ti.kernel
    def step_pixel(src: frame, base: frame, dst: frame, ok: mask, p: vector, w: small,
                   table: frame, sign: real, part: small, ring: scratch, strip: ti.i32,
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
            column_start(src, ok, p, table, coef, carry, pw, i0, x)
            for i in range(i0, i1):
                y = i + r
                sv = cell(src, y, x, pw)
                flow = pixel_flow(src, ok, p, coef, table, ring, pw, 0, i, y, x, sv, carry)
                v = emit(base, dst, sign, pw, i, j, flow)
                dmax = larger(dmax, ti.abs(v - sv))
                smax = larger(smax, ti.abs(v))
            part[b * wd + j, 0] = dmax
            part[b * wd + j, 1] = smax
        passes(part, n0, n1, n2, n3, n4, n5)

    return step_pixel


@functools.cache
def get_step_kernel(config):
    """Build (once per config) the Taichi kernel for one coupling step.

    Both layouts are built from the same device functions of one
    :class:`StepPlan`: ``pair`` (one pair's alpha, gated by ``ok``),
    ``pixel_flow`` (the coupling term of one pixel, each offset's second alpha
    taken from where :func:`alpha_sources` says), ``emit`` (the new value
    written) and the functions that start the carried alphas; the layouts
    differ only in their loops and in what they carry.
    """
    plan = StepPlan.of(config)
    coefficients, pair, pair_of = _law_functions(plan)
    pixel_flow, emit = _flow_functions(plan, pair, pair_of)
    starts = _start_functions(plan, pair)
    build = _sweep_kernel if config.layout == "sweep" else _pixel_kernel
    return build(plan, coefficients, pixel_flow, emit, starts)


def _clear_caches():
    get_step_kernel.cache_clear()
    get_frame_kernels.cache_clear()
    get_reduce_kernel.cache_clear()


runtime.on_reset(_clear_caches)

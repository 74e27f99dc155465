"""The CPU step, ``L`` pixels at a time (the ``lanes`` layout of
:mod:`ipc_taichi._kernels`).

Taichi 1.7's CPU backend emits scalar code for the other layouts: its LLVM
vectorisers never fire, because every array's data pointer is reloaded after
each store (the pointer lives in memory a float store might alias, to LLVM).
A Taichi vector, compiled with ``real_matrix_scalarize=False`` (set by
:func:`ipc_taichi.runtime.init` on the CPU), is one LLVM vector value: an
array whose elements are vectors of ``L`` pixels is read and written by one
vector load and store, and arithmetic on it is SIMD. Measured on a 2-core
Xeon (AVX-512), one thread, 2048x2048 f32, per Jacobi iteration: constant law
8.4 -> 2.9 ms, ``donlon2018`` 52 -> 12 ms.

The width
---------
``L`` follows the CPU's widest vector unit (:func:`host_vector_unit`, from
``/proc/cpuinfo``'s flags, :func:`vector_unit`; :data:`VECTOR_BYTES`):
AVX-512 and AVX2 16 f32 / 8 f64 pixels (two 256-bit registers), SSE (any
x86-64) and NEON (64-bit ARM) 8 / 4 (two 128-bit ones); a CPU of none of
these gets the scalar ``sweep`` (:func:`ipc_taichi._layouts.default_layout`).
``$IPC_TAICHI_LANES`` (:data:`LANES_ENV`) forces a unit or a width, e.g.
``8`` (one AVX2 register) on this machine to measure it (an emulation: LLVM
still compiles for this CPU). The outputs are the same bits at every width
(the same operations lane by lane; ``tests/test_lane_width.py``).

What LLVM emits on a Zen 4 (AMD EPYC) host, from the Taichi asm dump
(``TI_PRINT_KERNEL_ASM=1``): 256-bit ``ymm`` instructions, VEX-encoded
(registers 0-15, no mask registers, no AVX-512-only instruction), for 16
lanes (a vector is two ``ymm`` registers) as for 8 (one): LLVM prefers
256-bit vectors on this target. The 16-lane step is therefore AVX2 code that
an AVX2-only CPU runs as it is.

The arrays
----------
Every frame array of the step (``src``, ``base``, ``dst``, ``ok``, the ring)
is padded by ``reach`` pixels as for the ``sweep`` layout, and its padded
rows are ``padded_width`` pixels wide: the frame's width plus both borders
rounded up to a multiple of ``L``, so that every row starts a vector and the
columns right of the border are more border (zero signal, never written
other than with zero). ``base`` is padded too (the engine copies the measured
frame into its own padded array), ``ok`` holds reals (1.0 = may couple). The
arrays must be 64-byte aligned: LLVM assumes a vector's natural alignment
(the engine allocates them so, :func:`aligned_zeros`).

The loop
--------
As in the ``sweep``: one task per strip of rows, rows left to right, one
vector (``L`` pixels) per step. A neighbour at ``(dy, dx)`` is the vector at
the same place ``dy`` rows away, shifted by ``dx`` lanes with lanes from the
vector beside it. Each pair's alpha is evaluated once: a pair along the row
``(0, dx)`` is carried to the next vector (one vector of registers), a pair
``dy > 0`` rows down goes into a ring of rows and is read back ``dy`` rows
later (shifted by ``dx`` lanes). Lanes in the border columns are computed
with the rest and written as zero, which keeps the border what it was; a
read beyond either end of the array is clamped to its end (it feeds border
lanes only). The law is the other layouts' own,
:func:`ipc_taichi._alpha.make_alpha` with ``lanes=L`` (its exponential
builds ``2**n`` lane by lane from the lane's bits; the table law reads its
corners lane by lane, in f32 a cell's four as one record from
:func:`cell_table`).

A thread's position (strip, row, vector, its index, the row's vectors and the
arrays' last indices) travels to the device functions as one record
(:func:`position_type`, a Taichi struct): the functions are inlined, so it
compiles to the same arithmetic as the seven loose values it replaced (the
recorded outputs hold bit for bit; one 1024x1024 decouple, 20 iterations, on a
shared 2-core AMD EPYC: the same time as before within the machine's noise).

Things this compilation mode does not take on a vector (they crash at compile
time): unary minus, ``ti.abs``, ``ti.exp``, casts and bit casts; the code
below uses ``0 - x``, compares and selects instead.
"""

import collections
import functools
import os
import platform

import numpy as np

from ._alpha import make_alpha
from ._stepparts import law_functions
from .errors import IPCInputError

__all__ = ["LANES_ENV", "VECTOR_BYTES", "LANE_COUNTS", "VECTOR_FLAGS", "ALIGN", "vector_unit",
           "host_vector_unit", "vector_extensions", "forget_vector_unit", "lane_count",
           "padded_width", "aligned_zeros", "reads_cells", "cell_table", "lanes_kernel",
           "position_type"]

LANES_ENV = "IPC_TAICHI_LANES"
"""The environment variable that names the vector unit to compile for
(``avx512``, ``avx2``, ``sse``, ``neon``; ``none``: no ``lanes`` step, the
``sweep`` instead; unset or ``auto``: this CPU's, :func:`host_vector_unit`),
or a width in f32 lanes (:data:`LANE_COUNTS`)."""

VECTOR_BYTES = {"avx512": 64, "avx2": 64, "sse": 32, "neon": 32}
"""Bytes of one ``lanes`` vector for each vector unit: two 256-bit registers
on AVX2 and AVX-512 (16 f32 / 8 f64 pixels), two 128-bit ones on SSE and NEON
(8 / 4). Two, not one: on a Zen 4 host LLVM compiles the 16-lane vectors as
two ``ymm`` registers with AVX2 instructions, and the two independent chains
hide the exponential's latency: ``donlon2018`` costs 11.2-11.5 ms of CPU per
iteration at 2048x2048 f32 with 16 lanes, 16.3-17.6 ms with 8 (one ``ymm``),
the table law 22.7-24.6 against 21.9-23.4 ms, the constant law the same
(docs/performance.md, "Issue 39"). A number of f32 lanes (4, 8, 16) in
``$IPC_TAICHI_LANES`` forces that width."""

LANE_COUNTS = ("4", "8", "16")
"""The f32 lane counts ``$IPC_TAICHI_LANES`` may name (f64: half)."""

ALIGN = 64
"""Bytes every ``lanes`` array starts on (the widest vector's natural alignment)."""


def vector_unit(flags, machine):
    """The widest vector unit of a CPU that the ``lanes`` step is built for,
    from its feature flags (``/proc/cpuinfo``'s ``flags`` on x86, ``Features``
    on ARM) and its machine name (:func:`platform.machine`): ``"avx512"``
    (``avx512f``), ``"avx2"``, ``"sse"`` (any other x86-64: SSE2 is part of
    it), ``"neon"`` (64-bit ARM: Advanced SIMD is part of it), else ``None``
    (no ``lanes`` step: the engine runs the scalar ``sweep``)."""
    flags = {f.lower() for f in flags}
    machine = machine.lower()
    if machine in ("x86_64", "amd64", "x64"):
        if "avx512f" in flags:
            return "avx512"
        return "avx2" if "avx2" in flags else "sse"
    if machine in ("aarch64", "arm64"):
        return "neon"
    return None


def _cpu_flags():
    """This CPU's feature flags from ``/proc/cpuinfo`` (empty where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip().lower() in ("flags", "features"):
                    return value.split()
    except OSError:
        pass
    return []


VECTOR_FLAGS = ("sse2", "sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512bw",
                "asimd", "sve")
"""The feature flags :func:`vector_extensions` reports."""


def vector_extensions():
    """This CPU's vector extensions among :data:`VECTOR_FLAGS` (what a CPU
    number is recorded with)."""
    flags = set(_cpu_flags())
    return [f for f in VECTOR_FLAGS if f in flags]


@functools.cache
def host_vector_unit():
    """The vector unit the ``lanes`` step is built for in this process:
    ``$IPC_TAICHI_LANES`` where set (e.g. ``avx2`` on an AVX-512 machine, to
    measure the narrower width), else :func:`vector_unit` of this CPU. Read
    once; :func:`forget_vector_unit` (called when kernels and workspaces are
    cleared) makes the next call read it again."""
    name = os.environ.get(LANES_ENV, "").strip().lower()
    if name in ("", "auto"):
        return vector_unit(_cpu_flags(), platform.machine())
    if name == "none":
        return None
    if name not in VECTOR_BYTES and name not in LANE_COUNTS:
        raise IPCInputError(f"unknown vector unit {name!r} in ${LANES_ENV}; choose one of "
                            f"auto, {', '.join(VECTOR_BYTES)}, none, or f32 lanes "
                            f"{', '.join(LANE_COUNTS)}")
    return name


def forget_vector_unit():
    """Make :func:`host_vector_unit` read the environment and the CPU again."""
    host_vector_unit.cache_clear()


def lane_count(precision, unit=None):
    """Pixels per ``lanes`` vector in ``precision`` for ``unit`` (a vector
    unit of :data:`VECTOR_BYTES` or an f32 lane count of :data:`LANE_COUNTS`;
    default :func:`host_vector_unit`; with none, the SSE width)."""
    unit = unit or host_vector_unit() or "sse"
    size = int(unit) * 4 if unit in LANE_COUNTS else VECTOR_BYTES[unit]
    return size // (8 if precision == "f64" else 4)


def padded_width(width, reach, precision):
    """Columns of a padded row: ``width + 2 * reach`` rounded up to whole vectors."""
    lanes = lane_count(precision)
    return -(-(width + 2 * reach) // lanes) * lanes


def aligned_zeros(shape, dtype, fill=0):
    """A C-contiguous NumPy array starting on an :data:`ALIGN`-byte boundary."""
    dtype = np.dtype(dtype)
    count = int(np.prod(shape))
    raw = np.empty(count * dtype.itemsize + ALIGN, dtype=np.uint8)
    start = -raw.ctypes.data % ALIGN
    arr = raw[start:start + count * dtype.itemsize].view(dtype).reshape(shape)
    arr[...] = fill
    return arr


_cells = collections.OrderedDict()  # id(table) -> (table, its cells): one build per table


def reads_cells(precision):
    """Whether the ``lanes`` step of ``precision`` reads the table law's
    table as :func:`cell_table`'s records (f32), else flat, its corners
    read one by one (f64, where the records cost more than they save: CPU
    time per iteration at 2048x2048 on a 2-core AMD EPYC, f32 22.5 -> 21.2
    ms, f64 28.9 -> 30.4 ms)."""
    return precision == "f32"


def cell_table(table):
    """The law's ``n x n`` table (a 2-D host array, its dtype kept) as the
    ``lanes`` step reads it: one record of four values per cell, record
    ``i * (n - 1) + j`` holding the corners ``(t[i, j], t[i, j + 1],
    t[i + 1, j], t[i + 1, j + 1])`` of cell ``(i, j)``, 64-byte aligned.
    One vector load per lane then brings a pair's four corners (one index
    taken out of the index vector instead of four; the same values: the
    outputs are the same bits). ``(n - 1)**2`` records: 1 MB for a 257x257
    f32 table, four times the table. Built once per table (the engine keeps
    the table it passes; the last 8 are kept)."""
    hit = _cells.get(id(table))
    if hit is None or hit[0] is not table:
        t = np.asarray(table)
        records = aligned_zeros((max(1, (t.shape[0] - 1) * (t.shape[1] - 1)), 4), t.dtype)
        if min(t.shape) > 1:
            for c, (di, dj) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
                records[:, c] = t[di:t.shape[0] - 1 + di, dj:t.shape[1] - 1 + dj].ravel()
        hit = _cells[id(table)] = (table, records)
        while len(_cells) > 8:
            _cells.popitem(last=False)
    return hit[1]


def position_type():
    """The record of where a thread of the ``lanes`` step is (one Taichi
    struct passed to the device functions): strip ``s``, frame row ``i``,
    vector ``j`` of the row, ``c`` the index of that vector in the padded
    arrays, ``nc`` vectors per padded row, ``last`` and ``ring_last`` the last
    index of the frame arrays and of the ring."""
    import taichi as ti

    return ti.types.struct(s=ti.i32, i=ti.i32, j=ti.i32, c=ti.i32, nc=ti.i32, last=ti.i32,
                           ring_last=ti.i32)


def _pair_functions(plan):
    """``(shifted, pair, ring_row, combined_flow)``: a vector's neighbours
    ``dx`` columns away, the alphas of its pairs, where a ring row starts, and
    the coupling term with pre-combined coefficients (``pos``: a
    :func:`position_type` record)."""
    import taichi as ti

    config = plan.config
    offsets, r, vertical = config.offsets, config.reach, config.vertical
    lanes = lane_count(config.precision)
    real = ti.f64 if config.precision == "f64" else ti.f32
    slots, depth = max(1, len(vertical)), config.ring_depth
    constant, gated, mapped = config.law_kind == "constant", config.uses_ok, config.mapped
    law_at, combined_at, total_at = plan.law_at, plan.combined_at, plan.total_at
    alpha = make_alpha(config.law_kind, config.precision, lanes=lanes,
                       cells=reads_cells(config.precision))
    # the bond p -- p + d: (k of the offset u = +-d it is stored under, whether at p + d)
    bond_index = {**{u: (k, 0) for k, u in enumerate(offsets)},
                  **{(-u[0], -u[1]): (k, 1) for k, u in enumerate(offsets)}}

    @ti.func
    def shifted(arr: ti.template(), cb, dx: ti.template(), last):
        """Lanes ``q + dx`` of vector ``cb`` (and of the one beside it):
        the neighbours ``dx`` columns away of the pixels of vector ``cb``."""
        v = arr[cb]
        out = v
        if ti.static(dx > 0):
            after = arr[ti.min(cb + 1, last)]
            out = ti.Vector([v[q] for q in ti.static(range(dx, lanes))]
                            + [after[q] for q in ti.static(range(dx))], dt=real)
        elif ti.static(dx < 0):
            before = arr[ti.max(cb - 1, 0)]
            out = ti.Vector([before[q] for q in ti.static(range(lanes + dx, lanes))]
                            + [v[q] for q in ti.static(range(lanes + dx))], dt=real)
        return out

    @ti.func
    def law(coef: ti.template()):
        return ti.Vector([coef[law_at + m] for m in ti.static(range(5))], dt=real)

    @ti.func
    def bond(bonds: ti.template(), pos, plane, dy: ti.template(), dx: ti.template()):
        """The factors of the bonds (p, p + (dy, dx)) for the pixels p of vector
        ``pos.c``: the map of offset ``u = +-(dy, dx)`` (``plane`` vectors each, one
        after the other), read at p (``u``) or at p - u (``-u``, shifted)."""
        k, back = ti.static(bond_index[(dy, dx)])
        if ti.static(back == 0):
            return bonds[k * plane + pos.c]
        else:
            return shifted(bonds, k * plane + pos.c + dy * pos.nc, dx, bonds.shape[0] - 1)

    @ti.func
    def pair(src: ti.template(), ok: ti.template(), bonds: ti.template(), table: ti.template(),
             coef: ti.template(), pos, sv, okc, dy: ti.template(), dx: ti.template()):
        """alpha of the pairs (p, p + (dy, dx)) for the pixels p of vector ``pos.c``
        (``sv``: their signals, ``okc``: their ``ok``), gated by ``ok``; times
        the bonds' factors with a map (once per pair: both directions use it)."""
        a = sv * 0.0 + coef[law_at + 4]
        if ti.static(not constant):
            a = alpha(sv, shifted(src, pos.c + dy * pos.nc, dx, pos.last), law(coef), table)
        if ti.static(gated):
            a = a * (okc * shifted(ok, pos.c + dy * pos.nc, dx, pos.last))
        if ti.static(mapped):
            a = a * bond(bonds, pos, src.shape[0], dy, dx)
        return a

    @ti.func
    def ring_row(pos, kv: ti.template(), row):
        """Where frame row ``row``'s vectors of ring slot ``kv`` start (strip ``pos.s``)."""
        return ((pos.s * slots + kv) * depth + (row + r) % depth) * pos.nc

    @ti.func
    def combined_flow(src: ti.template(), coef: ti.template(), pos, sv):
        """The coupling term with pre-combined coefficients (``StepPlan.combined``)."""
        gain = sv * 0.0
        c, nc, last = pos.c, pos.nc, pos.last
        for k in ti.static(range(len(offsets))):
            dy, dx = ti.static(offsets[k])
            gain = gain + (coef[combined_at + 2 * k] * shifted(src, c + dy * nc, dx, last)
                           + coef[combined_at + 2 * k + 1] * shifted(src, c - dy * nc, -dx,
                                                                     last))
        return gain - coef[total_at] * sv

    return shifted, pair, ring_row, combined_flow


def _vector_functions(plan):
    """The device functions of the ``lanes`` step: ``(prologue, vector_flow)``
    (see :func:`lanes_kernel`)."""
    import taichi as ti

    config = plan.config
    offsets, r, vertical = config.offsets, config.reach, config.vertical
    lanes = lane_count(config.precision)
    real = ti.f64 if config.precision == "f64" else ti.f32
    gated = config.uses_ok
    shifted, pair, ring_row, combined_flow = _pair_functions(plan)
    position = position_type()

    @ti.func
    def prologue(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                 table: ti.template(), coef: ti.template(), ring: ti.template(), start):
        """The ring rows of the pairs that start in the dy rows above the strip
        (``start``: the position of the strip's first row)."""
        nc = start.nc
        for kv in ti.static(range(len(vertical))):
            dy, dx = ti.static(offsets[vertical[kv]])
            for row in range(start.i - dy, start.i):
                at = ring_row(start, kv, row)
                for j in range(nc):
                    pos = position(s=start.s, i=row, j=j, c=(row + r) * nc + j, nc=nc,
                                   last=start.last, ring_last=start.ring_last)
                    sv = src[pos.c]
                    okc = sv
                    if ti.static(gated):
                        okc = ok[pos.c]
                    ring[at + j] = pair(src, ok, bonds, table, coef, pos, sv, okc, dy, dx)

    @ti.func
    def minus_alpha(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                    table: ti.template(), coef: ti.template(), ring: ti.template(),
                    carry: ti.template(), pos, sv, okc, a_plus, k: ti.template()):
        """The alpha of the pairs (p - u, p) of offset ``k`` for vector ``pos.c``:
        where :meth:`~ipc_taichi._layouts.Layout.sources` says: fresh (constant
        law), carried along the row (``dy == 0``, one vector each) or read back
        from the ring (``dy > 0``); stores ``a_plus`` for the pixels after."""
        dy, dx = ti.static(offsets[k])
        a_minus = a_plus
        if ti.static(plan.sources[k] == "fresh"):
            a_minus = pair(src, ok, bonds, table, coef, pos, sv, okc, -dy, -dx)
        elif ti.static(plan.sources[k] == "row"):
            at = ti.static(plan.carry_at[k])
            a_minus = ti.Vector([carry[at + q] for q in ti.static(range(lanes - dx, lanes))]
                                + [a_plus[q] for q in ti.static(range(lanes - dx))], dt=real)
            for q in ti.static(range(lanes)):
                carry[at + q] = a_plus[q]
        else:
            kv = ti.static(plan.ring_index[k])
            a_minus = shifted(ring, ring_row(pos, kv, pos.i - dy) + pos.j, -dx, pos.ring_last)
            ring[ring_row(pos, kv, pos.i) + pos.j] = a_plus
        return a_minus

    @ti.func
    def vector_flow(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                    table: ti.template(), coef: ti.template(), ring: ti.template(),
                    carry: ti.template(), pos, sv):
        """The coupling term of the pixels of vector ``pos.c`` (row ``pos.i``,
        vector ``pos.j``)."""
        okc = sv
        c, nc, last = pos.c, pos.nc, pos.last
        if ti.static(gated):
            okc = ok[c]
        flow = sv * 0.0
        if ti.static(plan.combined):
            flow = combined_flow(src, coef, pos, sv)
        for k in ti.static(range(len(offsets) if not plan.combined else 0)):
            dy, dx = ti.static(offsets[k])
            a_plus = pair(src, ok, bonds, table, coef, pos, sv, okc, dy, dx)
            a_minus = minus_alpha(src, ok, bonds, table, coef, ring, carry, pos, sv, okc, a_plus,
                                  k)
            wp = coef[2 * k]  # weight of the move p -> p+u
            wm = coef[2 * k + 1]  # weight of the move p -> p-u
            flow = (flow + a_plus * (wm * shifted(src, c + dy * nc, dx, last) - wp * sv)
                    + a_minus * (wp * shifted(src, c - dy * nc, -dx, last) - wm * sv))
        return flow

    return prologue, vector_flow


def _lane_functions(lanes):
    """``(largest, magnitude)``: the largest lane of a vector, and ``|v|``
    lane by lane (compares and selects, as ``larger`` of the other layouts)."""
    import taichi as ti

    @ti.func
    def largest(m):
        """The largest lane of ``m`` (compare and select, as ``larger``)."""
        a = m[0]
        for q in ti.static(range(1, lanes)):
            a = ti.select(m[q] > a, m[q], a)
        return a

    @ti.func
    def magnitude(v):
        return ti.select(v > 0.0, v, 0.0 - v)

    return largest, magnitude


def lanes_kernel(plan, spread):
    """The ``lanes`` layout's step for a :class:`~ipc_taichi._layouts.StepPlan`
    (the arguments of the other layouts' steps, the frame arrays as vectors,
    the table flat or as :func:`cell_table`'s records, :func:`reads_cells`;
    ``width``: the frame's width,
    ``strip``: rows per task, ``spread``: see ``step_sweep`` in
    :mod:`ipc_taichi._kernels`)."""
    import taichi as ti

    config = plan.config
    r, lanes = config.reach, lane_count(config.precision)
    real = ti.f64 if config.precision == "f64" else ti.f32
    vectors = ti.types.ndarray(dtype=ti.types.vector(lanes, real), ndim=1)
    scalars = ti.types.ndarray(dtype=real, ndim=1)
    small = ti.types.ndarray(dtype=real, ndim=2)
    table_type = ti.types.ndarray(dtype=ti.types.vector(4, real), ndim=1) \
        if reads_cells(config.precision) else scalars  # cell_table's records, or flat
    coefficients = law_functions(plan)[0]
    prologue, vector_flow = _vector_functions(plan)
    largest, magnitude = _lane_functions(lanes)
    position = position_type()

    @ti.kernel
    def step_lanes(src: vectors, base: vectors, dst: vectors, ok: vectors, bonds: vectors,
                   p: scalars, w: small, table: table_type, sign: real, part: small,
                   ring: vectors, strip: ti.i32, width: ti.i32):
        nc = (width + 2 * r + lanes - 1) // lanes
        h = src.shape[0] // nc - 2 * r
        last = src.shape[0] - 1
        ring_last = ring.shape[0] - 1
        lo = ti.cast(r, real)
        hi = ti.cast(r + width, real)
        # one strip per task, spread apart (see step_sweep in _kernels)
        for task in range((h + strip - 1) // strip * spread):
            if task % spread == 0:
                s = task // spread
                coef = coefficients(p, w)
                i0 = s * strip
                i1 = ti.min(h, i0 + strip)
                if ti.static(plan.rings):
                    prologue(src, ok, bonds, table, coef, ring,
                             position(s=s, i=i0, j=0, c=(i0 + r) * nc, nc=nc, last=last,
                                      ring_last=ring_last))
                dmax = ti.Vector([0.0] * lanes, dt=real)
                smax = ti.Vector([0.0] * lanes, dt=real)
                for i in range(i0, i1):
                    carry = ti.Vector([0.0] * plan.carry_size, dt=real)
                    for j in range(nc):
                        c = (i + r) * nc + j
                        pos = position(s=s, i=i, j=j, c=c, nc=nc, last=last,
                                       ring_last=ring_last)
                        sv = src[c]
                        v = base[c] + sign * vector_flow(src, ok, bonds, table, coef, ring, carry,
                                                         pos, sv)
                        # border lanes (columns outside the frame) stay zero
                        x = ti.Vector([float(q) for q in ti.static(range(lanes))], dt=real) \
                            + ti.cast(j * lanes, real)
                        v = ti.select(x >= lo, ti.select(x < hi, v, 0.0), 0.0)
                        dst[c] = v
                        change = magnitude(v - sv)
                        dmax = ti.select(change > dmax, change, dmax)
                        size = magnitude(v)
                        smax = ti.select(size > smax, size, smax)
                part[s, 0] = largest(dmax)
                part[s, 1] = largest(smax)

    return step_lanes

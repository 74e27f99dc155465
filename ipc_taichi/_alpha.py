"""The coupling law on the device: the one Taichi evaluation of alpha(S, N)
(:func:`make_alpha`), the inlined exponential it uses on the CPU
(:func:`make_exp`), and which kernel a law needs (:func:`kernel_law_kind`:
a constant law needs no evaluation at all). The NumPy form of the same
formula is :meth:`ipc_taichi.laws.ParametricLaw.alpha`.
"""

__all__ = ["kernel_law_kind", "make_exp", "make_alpha"]


def kernel_law_kind(law):
    """The kernel's law kind for ``law``: ``"constant"`` for a parametric law
    whose amplitudes are both zero (alpha is its floor whatever the signals:
    the kernel evaluates nothing; with ``ok`` gating its results are
    bit-identical to the general kernel's, where ``0 * exp(.) + 0 * exp(.) +
    floor`` is exactly the floor; without, it sums the flow with pre-combined
    coefficients, ``StepPlan.combined``, equal to rounding), else the law's own
    kind (``"parametric"``, ``"table"``)."""
    if law.kind == "parametric" and law.amp_diff == 0 and law.amp_level == 0:
        return "constant"
    return law.kind


def make_exp(real_is_f64, vector=0):
    """An inlinable ``exp(x)`` for ``x <= 0`` (the law's arguments).

    Cody-Waite range reduction ``x = n ln2 + r`` (|r| <= ln2/2), a Taylor
    polynomial evaluated by Estrin's scheme (short dependency chains keep
    several exponentials in flight), and ``2**n`` built from its exponent bits
    with the round-to-integer "magic number" trick (no float->int conversion).
    f64: degree 12, relative error < 1e-15; f32: degree 7, < 3e-7. Inputs below
    the smallest normal result are clamped (exp(-708) ~ 3e-308 instead of 0).

    ``vector``: the lanes of a Taichi vector compiled as one (the ``lanes``
    layout, :mod:`ipc_taichi._lanes`; 0: a scalar), where a vector takes no bit
    cast: the clamp is a compare and select, and ``2**n`` is built lane by lane
    from the lane's bits as for a scalar (the same value); LLVM's SLP
    vectoriser joins the lanes into one vector shift and add (``vpslld``,
    ``vpaddd``). It replaced a product of the powers ``2**-b`` (b = 64, ...,
    1 in f32) chosen by compares: 35 vector operations per exponential, more
    than the polynomial's (``donlon2018``'s iteration at 2048x2048 f32 on a
    2-core AMD EPYC: about 28 -> 17-22 ms, loaded), the same bits.
    """
    import taichi as ti

    lowest = -708.0 if real_is_f64 else -87.0
    real = ti.f64 if real_is_f64 else ti.f32

    @ti.func
    def clamp(x):
        out = x
        if ti.static(vector):
            out = ti.select(x > lowest, x, lowest)
        else:
            out = ti.max(x, lowest)
        return out

    @ti.func
    def scalar_power(t):
        """``2**n`` of one lane from ``t`` = ``n`` plus the magic number (its low bits)."""
        scale = t
        if ti.static(real_is_f64):
            scale = ti.bit_cast((ti.bit_cast(t, ti.i64) + 1023) << 52, ti.f64)
        else:
            scale = ti.bit_cast((ti.bit_cast(t, ti.i32) + 127) << 23, ti.f32)
        return scale

    @ti.func
    def power_of_two(t, n):
        """``2**n``; ``t`` = ``n`` plus the magic number (its low bits are ``n``)."""
        scale = n * 0.0 + 1.0
        if ti.static(vector):
            # lane by lane (a vector takes no bit cast); LLVM's SLP vectoriser
            # joins the lanes into one vector shift and add
            scale = ti.Vector([scalar_power(t[q]) for q in ti.static(range(vector))], dt=real)
        else:
            scale = scalar_power(t)
        return scale

    if real_is_f64:
        @ti.func
        def exp(x):
            magic = 6755399441055744.0  # 1.5 * 2**52
            x = clamp(x)
            t = x * 1.4426950408889634 + magic
            n = t - magic
            r = x - n * 0.6931471803691238 - n * 1.9082149292705877e-10
            r2 = r * r
            r4 = r2 * r2
            r8 = r4 * r4
            d0 = (1.0 + r) + r2 * (0.5 + r * (1.0 / 6.0))
            d1 = (1.0 / 24.0 + r * (1.0 / 120.0)) + r2 * (1.0 / 720.0 + r * (1.0 / 5040.0))
            d2 = ((1.0 / 40320.0 + r * (1.0 / 362880.0))
                  + r2 * (1.0 / 3628800.0 + r * (1.0 / 39916800.0)))
            p = (d0 + r4 * d1) + r8 * (d2 + r4 * (1.0 / 479001600.0))
            return p * power_of_two(t, n)
    else:
        @ti.func
        def exp(x):
            magic = ti.f32(12582912.0)  # 1.5 * 2**23
            x = clamp(x)
            t = x * ti.f32(1.442695) + magic
            n = t - magic
            r = x - n * ti.f32(0.693145751953125) - n * ti.f32(1.428606765330187e-06)
            r2 = r * r
            r4 = r2 * r2
            d0 = (ti.f32(1.0) + r) + r2 * (ti.f32(0.5) + r * ti.f32(1.0 / 6.0))
            d1 = ((ti.f32(1.0 / 24.0) + r * ti.f32(1.0 / 120.0))
                  + r2 * (ti.f32(1.0 / 720.0) + r * ti.f32(1.0 / 5040.0)))
            p = d0 + r4 * d1
            return p * power_of_two(t, n)
    return exp


def make_alpha(law_kind, precision, fast_exp=True, flat_table=False, lanes=0, cells=False):
    """The Taichi device function ``alpha(s, n, p, table)`` of a law kind: the
    one device-side evaluation of the coupling law, used by every kernel
    layout and timed by the benchmark's floor measurement.

    ``p`` holds :meth:`ParametricLaw.kernel_params` (amplitudes, reciprocal
    scales, floor) or the table's grid for a :class:`TabulatedLaw`
    (``table``). Law kind ``"constant"`` (see :func:`kernel_law_kind`) reads
    the floor alone: no exponential. ``fast_exp`` uses the inlined :func:`make_exp` (the CPU's
    scalar code gains 1.7x); otherwise the arch's own ``exp`` (CUDA's is fast).

    The table lookup: the cell's corner is ``int(u)`` (``u >= 0`` after the
    clamp, where truncation is ``floor`` without its call); with
    ``flat_table`` the table comes as a 1-D row-major array and its four
    corners are read at ``i * n + j`` (Taichi's CPU code would reload a 2-D
    array's shape at each read).

    ``lanes``: ``s`` and ``n`` are Taichi vectors of that many pixels (the
    ``lanes`` layout, :mod:`ipc_taichi._lanes`): the same formula lane by lane
    (``parametric`` and ``bilinear`` are shared), written without what such
    vectors do not take (unary minus, ``abs``, casts: ``0 - x`` and selects,
    for scalars too, with the same values to the bit). The table's corners
    are read lane by lane from the flat table, or with ``cells`` from its
    cells (:func:`ipc_taichi._lanes.cell_table`: the four corners of cell
    ``(i, j)`` in record ``i * (n - 1) + j``), one record per lane: one index
    taken out of the index vector per lane instead of four (the same corners,
    the same bits).
    """
    import taichi as ti

    real = ti.f64 if precision == "f64" else ti.f32
    table_law = law_kind == "table"
    constant_law = law_kind == "constant"
    exp = make_exp(precision == "f64", vector=lanes) if fast_exp else ti.exp
    flat_table = flat_table or lanes > 0

    clamp, corner, bilinear, parametric = _law_parts(real, exp, flat_table)

    @ti.func
    def alpha(s, n, p: ti.template(), table: ti.template()):
        a = ti.cast(0.0, real)
        if ti.static(constant_law):
            a = p[4]  # the floor: amplitudes are zero, so the formula's value exactly
        elif ti.static(table_law):
            last = p[2]
            u = clamp((s - p[0]) * p[1], last)
            v = clamp((n - p[0]) * p[1], last)
            top = ti.cast(last, ti.i32) - 1
            i0 = ti.min(ti.cast(u, ti.i32), top)
            j0 = ti.min(ti.cast(v, ti.i32), top)
            a = bilinear(u - i0, v - j0, corner(table, i0, j0, top + 2),
                         corner(table, i0, j0 + 1, top + 2), corner(table, i0 + 1, j0, top + 2),
                         corner(table, i0 + 1, j0 + 1, top + 2))
        else:
            a = parametric(s, n, p)
        return a

    @ti.func
    def lane_alpha(s, n, p: ti.template(), table: ti.template()):
        """:func:`alpha` of two vectors of ``lanes`` signals (the table's
        corners read lane by lane, from the flat table or its cells: no vector
        casts or gathers here)."""
        a = s * 0.0 + p[4]
        if ti.static(table_law):
            last = p[2]
            u = clamp((s - p[0]) * p[1], last)
            v = clamp((n - p[0]) * p[1], last)
            top = ti.cast(last, ti.i32) - 1
            i0 = [ti.min(ti.cast(u[q], ti.i32), top) for q in ti.static(range(lanes))]
            j0 = [ti.min(ti.cast(v[q], ti.i32), top) for q in ti.static(range(lanes))]
            fu = u - ti.Vector([ti.cast(i0[q], real) for q in ti.static(range(lanes))], dt=real)
            fv = v - ti.Vector([ti.cast(j0[q], real) for q in ti.static(range(lanes))], dt=real)
            if ti.static(cells):
                # a record per lane: (t[i0, j0], t[i0, j0 + 1], t[i0 + 1, j0], t[i0 + 1, j0 + 1])
                cell = [table[i0[q] * (top + 1) + j0[q]] for q in ti.static(range(lanes))]
                t = [ti.Vector([cell[q][c] for q in ti.static(range(lanes))], dt=real)
                     for c in ti.static(range(4))]
                a = bilinear(fu, fv, t[0], t[1], t[2], t[3])
            else:
                m = top + 2
                t00 = ti.Vector([corner(table, i0[q], j0[q], m)
                                 for q in ti.static(range(lanes))], dt=real)
                t01 = ti.Vector([corner(table, i0[q], j0[q] + 1, m)
                                 for q in ti.static(range(lanes))], dt=real)
                t10 = ti.Vector([corner(table, i0[q] + 1, j0[q], m)
                                 for q in ti.static(range(lanes))], dt=real)
                t11 = ti.Vector([corner(table, i0[q] + 1, j0[q] + 1, m)
                                 for q in ti.static(range(lanes))], dt=real)
                a = bilinear(fu, fv, t00, t01, t10, t11)
        elif ti.static(not constant_law):
            a = parametric(s, n, p)
        return a

    return lane_alpha if lanes else alpha


def _law_parts(real, exp, flat_table):
    """The pieces both forms of :func:`make_alpha` are written with:
    ``(clamp, corner, bilinear, parametric)``."""
    import taichi as ti

    @ti.func
    def clamp(u, last):
        """``u`` clamped to ``[0, last]`` by compares and selects (``u`` is never NaN)."""
        c = ti.select(u > 0.0, u, 0.0)
        return ti.select(c < last, c, last)

    @ti.func
    def corner(table: ti.template(), i, j, n):
        """The table at (i, j) (``n`` columns)."""
        t = ti.cast(0.0, real)
        if ti.static(flat_table):
            t = table[i * n + j]
        else:
            t = table[i, j]
        return t

    @ti.func
    def bilinear(fu, fv, t00, t01, t10, t11):
        return (1 - fu) * ((1 - fv) * t00 + fv * t01) + fu * ((1 - fv) * t10 + fv * t11)

    @ti.func
    def parametric(s, n, p: ti.template()):
        """The formula of :meth:`ipc_taichi.laws.ParametricLaw.alpha`."""
        d = s - n
        return (p[0] * exp((0.0 - ti.select(d > 0.0, d, 0.0 - d)) * p[1])
                + p[2] * exp((0.0 - ti.sqrt(s * s + n * n)) * p[3]) + p[4])

    return clamp, corner, bilinear, parametric

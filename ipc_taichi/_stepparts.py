"""The named device functions the step kernels of :mod:`ipc_taichi._kernels`
are composed of, each built (in plain Python, once per kernel) from a
:class:`~ipc_taichi._layouts.StepPlan`: array access (flat or 2-D,
:func:`access_functions`), the law and the pair alphas (:func:`law_functions`),
one pixel's coupling term and its write (:func:`flow_functions`), the alphas
carried into a strip, row or column run (:func:`start_functions`), the maxima's
``larger`` (:func:`make_larger`) and the kernels' argument types
(:func:`arg_types`, :func:`make_frame_size`).
"""

from ._alpha import make_alpha

__all__ = ["make_larger", "access_functions", "make_bond", "law_functions", "flow_functions",
           "start_functions", "arg_types", "make_frame_size", "real_type"]


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


def real_type(plan):
    import taichi as ti

    return ti.f64 if plan.config.precision == "f64" else ti.f32


def access_functions(plan):
    """``(cell, put, ring_cell, ring_put)``: an array's value at row ``y``,
    column ``x`` of a frame ``width`` columns wide (and its store), and the
    sweep's ring rows (strip ``s``, slot ``kv``, frame row ``row``, column
    ``x``). With :attr:`~ipc_taichi._kernels.KernelConfig.flat` the arrays are 1-D, indexed
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


def make_bond(plan):
    """``bond(bonds, src, y, x, pw, dy, dx)``: the factor of the bond (y, x) --
    (y + dy, x + dx) (padded coordinates), read from the padded map of its
    half-stencil offset ``u = +-(dy, dx)``, stored at the end where ``u``
    starts (see :mod:`ipc_taichi.bondmap`). Flat: the maps one after the
    other, each as long as the flat padded frame ``src``; else 3-D ``[k, y, x]``."""
    import taichi as ti

    offsets, flat = plan.config.offsets, plan.config.flat
    # the map of the bond p -- p + d: the offset u = +-d it is stored under
    # (k, whether it is stored at the other end, p + d)
    bond_index = {**{u: (k, 0) for k, u in enumerate(offsets)},
                  **{(-u[0], -u[1]): (k, 1) for k, u in enumerate(offsets)}}

    @ti.func
    def bond(bonds: ti.template(), src: ti.template(), y, x, pw, dy: ti.template(),
             dx: ti.template()):
        k, back = ti.static(bond_index[(dy, dx)])
        if ti.static(flat):
            return bonds[k * src.shape[0] + (y + back * dy) * pw + x + back * dx]
        else:
            return bonds[k, y + back * dy, x + back * dx]

    return bond


def law_functions(plan):
    """``(coefficients, pair, pair_of)``: the weights and the law read into
    registers; one pair's alpha (``pair_of``: given the first pixel's signal)."""
    import taichi as ti

    config, real, n_coef, law_at = plan.config, real_type(plan), plan.n_coef, plan.law_at
    constant_law = config.law_kind == "constant"
    alpha = make_alpha(config.law_kind, config.precision, fast_exp=plan.layout.fast_exp,
                       flat_table=config.flat)
    cell = access_functions(plan)[0]
    bond = make_bond(plan)
    total_at = plan.total_at

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
        if ti.static(plan.combined):
            a = coef[law_at + 4]
            total = ti.cast(0.0, real)
            for k in ti.static(range(len(config.offsets))):
                coef[plan.combined_at + 2 * k] = a * coef[2 * k + 1]
                coef[plan.combined_at + 2 * k + 1] = a * coef[2 * k]
                total += coef[2 * k] + coef[2 * k + 1]
            coef[total_at] = a * total
        return coef

    @ti.func
    def law(coef: ti.template()):
        """The law's parameters among the coefficients, as ``alpha`` reads them."""
        return ti.Vector([coef[law_at + m] for m in ti.static(range(5))], dt=real)

    @ti.func
    def pair_of(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                table: ti.template(), coef: ti.template(), pw, sv, y, x, dy: ti.template(),
                dx: ti.template()):
        """alpha of the pair (y, x) -- (y + dy, x + dx), padded coordinates
        (``pw``: the padded width), ``sv`` the signal at (y, x); times the
        bond's factor with a map (once per pair: both directions use it)."""
        a = ti.cast(0.0, real)
        if ti.static(constant_law):
            a = coef[law_at + 4]  # what alpha() returns for this law, kept in a register
        else:
            a = alpha(sv, cell(src, y + dy, x + dx, pw), law(coef), table)
        if ti.static(config.uses_ok):
            a *= ti.cast(cell(ok, y, x, pw) * cell(ok, y + dy, x + dx, pw), real)
        if ti.static(config.mapped):
            a *= bond(bonds, src, y, x, pw, dy, dx)
        return a

    @ti.func
    def pair(src: ti.template(), ok: ti.template(), bonds: ti.template(), table: ti.template(),
             coef: ti.template(), pw, y, x, dy: ti.template(), dx: ti.template()):
        """alpha of the pair (y, x) -- (y + dy, x + dx) (the law's parameters
        are among ``coef``)."""
        return pair_of(src, ok, bonds, table, coef, pw, cell(src, y, x, pw), y, x, dy, dx)

    return coefficients, pair, pair_of


def flow_functions(plan, pair, pair_of):
    """``(pixel_flow, emit)``: one pixel's coupling term (its alphas taken
    from where :meth:`~ipc_taichi._layouts.Layout.sources` says), and the new value written."""
    import taichi as ti

    offsets, sources, real = plan.config.offsets, plan.sources, real_type(plan)
    r = plan.config.reach
    cell, put, ring_cell, ring_put = access_functions(plan)
    total_at = plan.total_at

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
    def combined_flow(src: ti.template(), coef: ti.template(), pw, y, x, sv):
        """The coupling term of a constant law without ``ok`` gating, from the
        pre-combined coefficients (see :attr:`~ipc_taichi._layouts.StepPlan.combined`)."""
        at = ti.static(plan.combined_at)
        gain = ti.cast(0.0, real)
        for k in ti.static(range(len(offsets))):
            dy, dx = ti.static(offsets[k])
            gain += (coef[at + 2 * k] * cell(src, y + dy, x + dx, pw)
                     + coef[at + 2 * k + 1] * cell(src, y - dy, x - dx, pw))
        return gain - coef[total_at] * sv

    @ti.func
    def shift_in(carry: ti.template(), at: ti.template(), n: ti.template(), a):
        """Take the oldest of ``n`` carried alphas out, put ``a`` in; returns it."""
        old = carry[at]
        for m in ti.static(range(n - 1)):
            carry[at + m] = carry[at + m + 1]
        carry[at + n - 1] = a
        return old

    @ti.func
    def pixel_flow(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                   coef: ti.template(), table: ti.template(), ring: ti.template(), pw, s, i,
                   y, x, sv, carry: ti.template()):
        """The coupling term at padded (y, x) (row ``i`` of the frame); the
        alphas it computes are carried for the pixels that reuse them."""
        flow = ti.cast(0.0, real)
        if ti.static(plan.combined):
            flow = combined_flow(src, coef, pw, y, x, sv)
        for k in ti.static(range(len(offsets) if not plan.combined else 0)):
            dy, dx = ti.static(offsets[k])
            a_plus = pair_of(src, ok, bonds, table, coef, pw, sv, y, x, dy, dx)
            a_minus = ti.cast(0.0, real)
            if ti.static(sources[k] == "row"):
                a_minus = shift_in(carry, plan.carry_at[k], dx, a_plus)
            elif ti.static(sources[k] == "ring"):
                kv = ti.static(plan.ring_index[k])
                a_minus = ring_cell(ring, s, kv, i - dy + r, x - dx, pw)
                ring_put(ring, s, kv, i + r, x, pw, a_plus)
            elif ti.static(sources[k] == "column"):
                a_minus = shift_in(carry, plan.carry_at[k], dy, a_plus)
            else:
                a_minus = pair(src, ok, bonds, table, coef, pw, y - dy, x - dx, dy, dx)
            flow = pair_flow(flow, src, coef, pw, y, x, sv, k, a_plus, a_minus)
        return flow

    @ti.func
    def emit(base: ti.template(), dst: ti.template(), sign, pw, i, j, flow):
        """Write ``base + sign * flow`` at frame pixel (i, j); returns it."""
        v = cell(base, i, j, pw - 2 * r) + sign * flow
        put(dst, i + r, j + r, pw, v)
        return v

    return pixel_flow, emit


def start_functions(plan, pair):
    """The alphas of pairs that start before a strip, row or column run and
    that its pixels read back: ``(ring_prologue, ring_row_ends, row_start,
    column_start)``."""
    import taichi as ti

    offsets, vertical, r = plan.config.offsets, plan.config.vertical, plan.config.reach
    ring_put = access_functions(plan)[3]

    @ti.func
    def ring_prologue(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                      table: ti.template(), coef: ti.template(), ring: ti.template(), s, i0,
                      wd):
        """Sweep: the pairs that start in the dy rows above the strip."""
        for kv in ti.static(range(len(vertical))):
            dy, dx = ti.static(offsets[vertical[kv]])
            for row in range(i0 - dy, i0):
                for c in range(plan.prologue_lo[kv], wd + plan.right_extra[kv]):
                    ring_put(ring, s, kv, row + r, c + r, wd + 2 * r,
                             pair(src, ok, bonds, table, coef, wd + 2 * r, row + r, c + r,
                                  dy, dx))

    @ti.func
    def ring_row_ends(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                      table: ti.template(), coef: ti.template(), ring: ti.template(), s, i,
                      wd):
        """Sweep: row i's pairs starting beyond its ends that later rows read back."""
        y = i + r
        pw = wd + 2 * r
        for kv in ti.static(range(len(vertical))):
            dy, dx = ti.static(offsets[vertical[kv]])
            for c in ti.static(plan.left_extra[kv]):
                ring_put(ring, s, kv, y, c + r, pw, pair(src, ok, bonds, table, coef, pw, y,
                                                        c + r, dy, dx))
            for c in range(wd, wd + plan.right_extra[kv]):
                ring_put(ring, s, kv, y, c + r, pw, pair(src, ok, bonds, table, coef, pw, y,
                                                        c + r, dy, dx))

    @ti.func
    def row_start(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                  table: ti.template(), coef: ti.template(), carry: ti.template(), pw, y):
        """Sweep: the horizontal pairs left of column 0, into the row registers."""
        for k in ti.static(range(len(offsets))):
            dy, dx = ti.static(offsets[k])
            if ti.static(plan.sources[k] == "row"):
                for m in ti.static(range(dx)):
                    carry[plan.carry_at[k] + m] = pair(src, ok, bonds, table, coef, pw, y,
                                                       r - dx + m, 0, dx)

    @ti.func
    def column_start(src: ti.template(), ok: ti.template(), bonds: ti.template(),
                     table: ti.template(), coef: ti.template(), carry: ti.template(), pw, i0,
                     x):
        """Pixel: the vertical pairs (dy, 0) that end in the run's first dy rows."""
        for k in ti.static(range(len(offsets))):
            dy, dx = ti.static(offsets[k])
            if ti.static(plan.sources[k] == "column"):
                for m in ti.static(range(dy)):
                    carry[plan.carry_at[k] + m] = pair(src, ok, bonds, table, coef, pw,
                                                        i0 + r - dy + m, x, dy, 0)

    return ring_prologue, ring_row_ends, row_start, column_start


def arg_types(plan):
    """The step kernels' argument types: (frame, vector, mask, scratch, small,
    bond): frames, the ``ok`` mask, the ring, the law's table and the bond maps
    1-D with :attr:`~ipc_taichi._kernels.KernelConfig.flat` (else the maps 3-D,
    ``[k, y, x]``); ``w`` and ``part`` (small) always 2-D."""
    import taichi as ti

    real, flat = real_type(plan), plan.config.flat
    small = ti.types.ndarray(dtype=real, ndim=2)
    return (ti.types.ndarray(dtype=real, ndim=1 if flat else 2),
            ti.types.ndarray(dtype=real, ndim=1), ti.types.ndarray(dtype=ti.u8,
                                                                   ndim=1 if flat else 2),
            ti.types.ndarray(dtype=real, ndim=1 if flat else 4), small,
            ti.types.ndarray(dtype=real, ndim=1 if flat else 3))


def make_frame_size(plan):
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

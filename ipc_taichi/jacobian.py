"""The coupling's Jacobian and the rows of its inverse, behind :mod:`ipc_taichi.noise`.

The Jacobian of the forward model is kept as a stencil; the rows of its inverse
``G = J^{-1}`` are probed by a lattice colouring and truncated Neumann (Jacobi)
solves. The method and its error bounds are described in :mod:`ipc_taichi.noise`
and ``docs/noise.md``.
"""

import numpy as np

from .errors import LawError

_BAND = 256
"""Rows of a frame linearised at once (with a halo): bounds the memory."""

_BATCH = 5
"""Colours solved together (memory: about 3 x this many frames of float64)."""


def _derivative_step(s, n):
    """Central-difference step for alpha's partial derivatives (electrons)."""
    return 1e-6 * np.maximum(1.0, np.maximum(np.abs(s), np.abs(n)))


def jacobian(charge, model, valid):
    """The coupling's Jacobian ``J[o][p] = dC(x)_p / dx_(p+o)`` as a stencil.

    Parameters
    ----------
    charge : ndarray (ny, nx)
        Signal on the node, electrons (finite where ``valid``).
    model : CouplingModel
    valid : ndarray of bool (ny, nx)
        Pixels that couple (unmasked, finite); the others have identity rows.

    Returns
    -------
    dict
        Offset ``(dy, dx)`` -> array (ny, nx); ``(0, 0)`` is the diagonal.
    """
    law, r = model.law, model.geometry.reach
    ny, nx = charge.shape
    shape = (ny + 2 * r, nx + 2 * r)
    inner = (slice(r, r + ny), slice(r, r + nx))
    x = np.zeros(shape)
    x[inner] = np.where(valid, charge, 0.0)
    ok = np.zeros(shape, bool)
    ok[inner] = valid
    outside = np.ones(shape, bool)
    outside[inner] = False
    acc = {(0, 0): np.ones(shape)}
    for (uy, ux), (w_fwd, w_back) in model.geometry.half_stencil():
        p, q = _pair_windows(shape, uy, ux)
        sp, sq = x[p], x[q]
        a = law.alpha(sp, sq)
        h = _derivative_step(sp, sq)
        a1 = _partial(law, sp, sq, h, 0)
        a2 = _partial(law, sp, sq, h, 1)
        active = ok[p] & ok[q]
        if model.edge == "zero":
            active |= (ok[p] & outside[q]) | (outside[p] & ok[q])
        # net charge p -> q: (w_fwd S_p - w_back S_q) alpha(S_p, S_q) (alpha symmetric)
        net = w_fwd * sp - w_back * sq
        d_p = np.multiply(net, a1, out=a1)           # d net / d S_p
        d_p += w_fwd * a
        d_p *= active
        d_q = np.multiply(net, a2, out=a2)           # d net / d S_q
        d_q -= w_back * a
        d_q *= active
        for key in ((uy, ux), (-uy, -ux)):
            acc.setdefault(key, np.zeros(shape))
        acc[(0, 0)][p] -= d_p
        acc[(0, 0)][q] += d_q
        acc[(uy, ux)][p] -= d_q
        acc[(-uy, -ux)][q] += d_p
    return {o: _inside_only(a[inner], o) for o, a in acc.items()}


def _partial(law, s, n, h, which):
    """Central difference of alpha in its first (``which=0``) or second argument."""
    if which == 0:
        out = law.alpha(s + h, n)
        out -= law.alpha(s - h, n)
    else:
        out = law.alpha(s, n + h)
        out -= law.alpha(s, n - h)
    out /= 2 * h
    return out


def _inside_only(a, offset):
    """Zero the entries ``a[p]`` whose column ``p + offset`` lies outside the frame
    (the zero edge's outside is not a variable)."""
    oy, ox = offset
    if oy > 0:
        a[-oy:] = 0.0
    elif oy < 0:
        a[:-oy] = 0.0
    if ox > 0:
        a[:, -ox:] = 0.0
    elif ox < 0:
        a[:, :-ox] = 0.0
    return a


def _pair_windows(shape, uy, ux):
    """Windows ``p`` and ``q = p + (uy, ux)`` of a padded array (same size)."""
    h, w = shape[0] - abs(uy), shape[1] - abs(ux)

    def at(oy, ox):
        return (slice(oy, oy + h), slice(ox, ox + w))

    return at(max(-uy, 0), max(-ux, 0)), at(max(uy, 0), max(ux, 0))


def colouring(steps, reach):
    """A lattice colouring ``c = (x + a y) mod n`` whose same-colour pixels are
    more than ``2 reach`` coupling steps apart.

    Parameters
    ----------
    steps : iterable of (dy, dx)
        The offsets of one coupling step (the Jacobian's off-diagonals).
    reach : int
        Rows of ``G`` are kept exactly out to this many steps.

    Returns
    -------
    n, a : int
    offsets : list of (dy, dx)
        One offset per colour, the fewest steps from the pixel first: the
        entries of ``G`` each colour probes.
    """
    steps = [tuple(s) for s in steps]
    box = 2 * reach * max(max(abs(dy), abs(dx)) for dy, dx in steps) + 1
    dist = _step_distances(steps, box, 2 * reach)
    near = [o for o, d in dist.items() if 0 < d <= 2 * reach]
    ball = sum(1 for d in dist.values() if d <= reach)
    for n in range(ball, 1000):
        for a in range(n):
            if all((ox + a * oy) % n for oy, ox in near):
                return n, a, _representatives(n, a, steps, n)
    raise LawError(f"no colouring found for geometry steps {steps}")  # pragma: no cover


def _step_distances(steps, box, limit):
    """Fewest steps to each offset within ``box`` (breadth first, up to ``limit``)."""
    dist = {(0, 0): 0}
    frontier = [(0, 0)]
    for d in range(1, limit + 1):
        nxt = []
        for oy, ox in frontier:
            for sy, sx in steps:
                o = (oy + sy, ox + sx)
                if o not in dist and max(abs(o[0]), abs(o[1])) <= box:
                    dist[o] = d
                    nxt.append(o)
        frontier = nxt
    return dist


def _representatives(n, a, steps, box):
    """For each colour, the offset of that colour fewest steps (then nearest) away."""
    dist = _step_distances(steps, box, 4 * box)
    best = {}
    for (oy, ox), d in dist.items():
        key = (d, oy * oy + ox * ox, oy, ox)
        c = (ox + a * oy) % n
        if c not in best or key < best[c][0]:
            best[c] = (key, (oy, ox))
    return [best[c][1] for c in sorted(best)]


def rows_of_g(charge, model, valid, reach, tol):
    """The rows of ``G`` band by band (``_BAND`` rows with a halo the Neumann
    terms cannot cross, so the bands give the whole frame's answer)."""
    ny = charge.shape[0]
    starts = range(0, ny, _BAND) if ny > 2 * _BAND else [0]
    step = model.geometry.reach
    guess, parts, stats = 8, [], []
    for r0 in starts:
        r1 = ny if len(starts) == 1 else min(r0 + _BAND, ny)
        while True:
            halo = 0 if len(starts) == 1 else step * (guess + 1)
            e0, e1 = max(0, r0 - halo), min(ny, r1 + halo)
            jac = jacobian(charge[e0:e1], model, valid[e0:e1])
            scaled, inverse, rho, terms, bound = _contraction(jac, tol)
            if halo == 0 or terms <= guess:
                break
            guess = terms
        offsets, g = _probe(scaled, inverse, terms, reach, e0)
        parts.append(g[:, r0 - e0:r1 - e0])
        stats.append((rho, terms, bound))
    rho, terms, bound = (max(v) for v in zip(*stats))
    return offsets, np.concatenate(parts, axis=1), rho, terms, bound


def _contraction(jac, tol):
    """``-D^{-1} N`` as a stencil, ``D^{-1}``, ``rho``, the Neumann terms for ``tol``
    and their truncation bound."""
    diag = jac[(0, 0)]
    if not np.all(diag > 0):
        raise LawError("the coupling's Jacobian has a non-positive diagonal at this frame: "
                       "the law is too strong to linearise here")
    scaled = {o: a / diag for o, a in jac.items() if o != (0, 0)}
    rho = float(np.max(sum(np.abs(a) for a in scaled.values())))
    if not rho < 1.0:
        raise LawError(f"the linearised decoupler does not contract at this frame "
                       f"(row sum {rho:.3g} >= 1)")
    dmin = float(diag.min())
    terms = 0
    while rho > 0 and rho ** (terms + 1) / (1.0 - rho) / dmin > tol:
        terms += 1
    return scaled, 1.0 / diag, rho, terms, rho ** (terms + 1) / (1.0 - rho) / dmin


def _probe(scaled, inverse, terms, reach, row0):
    """Rows of ``G`` on the colouring's offsets, by truncated Neumann solves
    (``row0``: the first row's index in the frame, for the colouring)."""
    n, a, offsets = colouring(list(scaled), reach)
    ny, nx = inverse.shape
    colour = ((np.arange(nx)[None, :] + a * np.arange(row0, row0 + ny)[:, None]) % n).ravel()
    inverse = inverse.ravel()
    matrix = _sparse(scaled, (ny, nx), -1.0)
    stencil = np.empty((len(offsets), ny * nx))
    for start in range(0, n, _BATCH):  # a few colours at a time bounds the memory
        stop = min(start + _BATCH, n)
        first = np.zeros((ny * nx, stop - start))
        here = np.flatnonzero((colour >= start) & (colour < stop))
        first[here, colour[here] - start] = inverse[here]
        z = _solve(first, matrix, terms)
        for k, (oy, ox) in enumerate(offsets):
            pick = (colour + ox + a * oy) % n - start
            sel = (pick >= 0) & (pick < stop - start)
            if sel.all():
                stencil[k] = np.take_along_axis(z, pick[:, None], axis=1)[:, 0]
            else:
                stencil[k][sel] = z[sel, pick[sel]]
    return offsets, stencil.reshape((len(offsets), ny, nx))


def _sparse(stencil, shape, factor=1.0):
    """``factor`` times the stencil ``{(dy, dx): array}`` as a CSR matrix on the
    flattened frame (entries that would leave the frame are zero in the stencil)."""
    from scipy import sparse

    ny, nx = shape
    size = ny * nx
    keys = list(stencil)
    itype = np.int32 if size < 2 ** 31 else np.int64
    rows = np.arange(size, dtype=itype)[:, None]
    cols = rows + np.array([oy * nx + ox for oy, ox in keys], dtype=itype)[None, :]
    data = np.stack([stencil[k].ravel() for k in keys], axis=1) * factor
    off = (cols < 0) | (cols >= size) | (data == 0)
    cols = np.where(off, rows, cols)  # an explicit zero on the row's own column
    data[off] = 0.0
    indptr = np.arange(0, size * len(keys) + 1, len(keys), dtype=itype)
    return sparse.csr_array((data.ravel(), cols.ravel(), indptr), shape=(size, size))


def _solve(first, negated, terms):
    """``z = sum_k (-D^{-1} N)^k D^{-1} b`` for ``k <= terms``, for several
    colours at once: Jacobi from ``z = D^{-1} b`` (``negated = -D^{-1} N``)."""
    z = first
    for _ in range(terms):
        z = negated @ z
        z += first
    return z

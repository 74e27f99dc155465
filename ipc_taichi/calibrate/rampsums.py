"""Flat ramps read into sufficient statistics: per spatial block, sums of
products of increments.

Per block, the sums over pixels and integrations of ``d_k(p) d_l(p + delta)``
for every pair of increments ``k, l`` and the 13 lags
:data:`~.rampmodel.LAGS` (one symmetric rank-k update per lag), their pixel-pair
counts, and each integration's sums of reads. The fixed pattern is cancelled by
subtracting, per pixel and increment, the mean over integrations (scaled by
``sqrt(n / (n - 1))``); the spatial mean of each increment is removed too. The
sums are additive: :class:`.ramps.FlatRamps` adds blocks for the jackknife.
"""

import numpy as np

from ..errors import IPCInputError
from .rampmodel import LAG_CLASSES, LAGS
from .stream import is_lazy, row_strips

__all__ = ["block_sums", "symmetrise"]

_MARGIN = 2
"""The reach of the largest lag: a block is read with this margin."""


def block_sums(data, mask, border, blocks, saturation):
    """The sums of products of increments of flat ramps, per spatial block.

    Parameters are those of :meth:`.ramps.FlatRamps.from_ramps`; ``data`` is
    (nints, ngroups, ny, nx).

    Returns
    -------
    sums : ndarray (blocks, 13, G', G')
        ``P + P^T`` per block and lag (:func:`_block_products`).
    counts : ndarray (blocks, 13)
        Pixel pairs (times integrations) per block and lag.
    increment_sums : ndarray (blocks, nints, G')
        Sums of each increment over each block's good pixels.
    n_pixels : ndarray (blocks,)
        Good pixels per block.
    notes : list of str
        What was dropped or assumed.
    """
    nints, ngroups, ny, nx = data.shape
    good, used, finite, notes = _usable(data, mask, border, saturation)
    if used < 4:
        raise IPCInputError(f"flat ramps: only {used} usable reads (at least 4 are needed "
                            "for the mean-ramp curvature and the time structure)")
    if good.sum() < 25 * blocks[0] * blocks[1]:
        raise IPCInputError(f"flat ramps: only {int(good.sum())} usable pixels for "
                            f"{blocks[0]}x{blocks[1]} blocks")
    rows = np.linspace(0, ny, blocks[0] + 1).round().astype(int)
    cols = np.linspace(0, nx, blocks[1] + 1).round().astype(int)
    edges = [(rows[i], rows[i + 1], cols[j], cols[j + 1])
             for i in range(blocks[0]) for j in range(blocks[1])]
    row = nints * used * (nx + 2 * _MARGIN) * 8  # float64 bytes of a row of a strip
    inc_sums = np.diff([sum(_block_read_sums(data, good, s, used, finite)
                            for s in _strips(e, row)) for e in edges], axis=2)
    n_pixels = np.array([good[y0:y1, x0:x1].sum() for y0, y1, x0, x1 in edges])
    mean_inc = inc_sums.sum(axis=0) / n_pixels.sum()  # (nints, increments)
    offset = mean_inc - mean_inc.mean(axis=0) if nints > 1 else mean_inc
    if nints > 1:
        offset = offset * np.sqrt(nints / (nints - 1.0))
    else:
        notes.append("one integration: the fixed pattern cannot be subtracted")
    sums, counts = zip(*(_added(_block_products(data, good, s, used, offset)
                                for s in _strips(e, row)) for e in edges), strict=True)
    return np.array(sums), np.array(counts), inc_sums, n_pixels, notes


def _strips(edge, row_bytes):
    """A block ``(y0, y1, x0, x1)`` as row strips of at most
    :data:`.stream.STRIP_BYTES` (the block itself when it fits): its sums are
    the strips' sums (each strip read with its own margin)."""
    y0, y1, x0, x1 = edge
    return [(y0 + r.start, y0 + r.stop, x0, x1) for r in row_strips(y1 - y0, row_bytes)]


def _added(parts):
    """The sums and counts of a block's strips, added."""
    sums, counts = zip(*parts, strict=True)
    return sum(sums[1:], sums[0]), sum(counts[1:], counts[0])


def _usable(data, mask, border, saturation):
    """Good pixels (ny, nx), the number of reads used, whether every used read is
    finite, notes."""
    nints, ngroups, ny, nx = data.shape
    notes = []
    used = ngroups
    strips = row_strips(ny, nints * ngroups * nx * 8)
    if saturation is not None:
        over = np.zeros(ngroups)
        for rows in strips:
            over += [np.count_nonzero(data[:, g, rows] >= float(saturation))
                     for g in range(ngroups)]
        over = np.nonzero(over / (nints * ny * nx) > 0.01)[0]
        if over.size:
            used = int(over[0])
            notes.append(f"reads {used}..{ngroups - 1} not used: more than 1 % of the pixels "
                         f"at or above the saturation level {float(saturation):.6g} e-")
    bad = np.zeros((ny, nx), bool)
    for rows in strips:
        bad[rows] |= ~np.isfinite(data[:, :used, rows]).all(axis=(0, 1))
    finite = not bad.any()
    if saturation is not None:
        for rows in strips:
            bad[rows] |= (data[:, :used, rows] >= float(saturation)).any(axis=(0, 1))
    if mask is not None:
        m = mask if is_lazy(mask) else np.asarray(mask, bool)
        if m.shape == (ny, nx):
            bad |= m
        elif m.shape == data.shape:
            for rows in strips:
                bad[rows] |= m[:, :used, rows].any(axis=(0, 1))
        else:
            raise IPCInputError(f"mask shape {m.shape} fits neither the ramps {data.shape} "
                                "nor a frame")
    b = int(border)
    if b > 0:
        bad[:b] = bad[-b:] = True
        bad[:, :b] = bad[:, -b:] = True
    return ~bad, used, finite, notes


def _region(data, good, edge, used):
    """A block with a margin of 2 (zero outside the frame): increments
    (nints, G', h, w), good pixels in the margin, good pixels of the block."""
    y0, y1, x0, x1 = edge
    nints, _, ny, nx = data.shape
    m = _MARGIN
    h, w = y1 - y0 + 2 * m, x1 - x0 + 2 * m
    reads = np.zeros((nints, used, h, w))
    ya, yb, xa, xb = max(y0 - m, 0), min(y1 + m, ny), max(x0 - m, 0), min(x1 + m, nx)
    sl = (slice(ya - y0 + m, yb - y0 + m), slice(xa - x0 + m, xb - x0 + m))
    reads[:, :, sl[0], sl[1]] = data[:, :used, ya:yb, xa:xb]
    ok = np.zeros((h, w), bool)
    ok[sl] = good[ya:yb, xa:xb]
    inner = np.zeros((h, w), bool)
    inner[m:h - m, m:w - m] = ok[m:h - m, m:w - m]
    reads = np.where(ok, reads, 0.0)
    return np.diff(reads, axis=1), ok, inner


def _block_read_sums(data, good, edge, used, finite):
    """Sum over the block's good pixels of each read (nints, used)."""
    y0, y1, x0, x1 = edge
    vals = data[:, :used, y0:y1, x0:x1]
    ok = good[y0:y1, x0:x1]
    if not finite:
        vals = np.where(ok, vals, 0.0)
    return np.einsum("igyx,yx->ig", vals, ok.astype(np.float64))


def _block_products(data, good, edge, used, offset):
    """``P + P^T`` with ``P = sum_p d_k(p) d_l(p + delta)`` over the block's pixels
    ``p`` (13, G', G'), and the number of pixel pairs per lag (13,).

    Only the symmetric part is needed, so each lag costs one symmetric rank-k
    update: with ``A`` the block's increments and ``B`` those shifted by the lag,
    ``A B^T + B A^T = (A + B)(A + B)^T - A A^T - B B^T``.
    """
    inc, ok, inner = _region(data, good, edge, used)
    nints, g = inc.shape[:2]
    if nints > 1:
        inc = (inc - inc.mean(axis=0)) * np.sqrt(nints / (nints - 1.0))
    inc -= offset[:, :, None, None]
    inc *= ok
    h, w = ok.shape
    size = h * w
    flat = inc.reshape(nints, g, size)
    okf, inf = ok.ravel(), inner.ravel()
    sums = np.zeros((len(LAGS), g, g))
    counts = np.array([nints * np.count_nonzero(inf[:size - s] & okf[s:])
                       for s in (dy * w + dx for dy, dx in LAGS)], dtype=np.float64)
    for i in range(nints):
        whole = flat[i]
        first = whole * inf.astype(np.float64)
        aa = first @ first.T
        bb_all = whole @ whole.T
        for n, (dy, dx) in enumerate(LAGS):
            s = dy * w + dx
            if s == 0:
                sums[n] += 2.0 * aa
                continue
            head = whole[:, :s]
            both = first[:, :size - s] + whole[:, s:]
            sums[n] += both @ both.T - aa - (bb_all - head @ head.T)
    return sums, counts


def symmetrise(sums, counts):
    """Symmetric covariances (9, G', G') (both orders of each pair, the four
    reflections of each lag) and the pixel-pair counts per lag (9,)."""
    g = sums.shape[-1]
    total = np.zeros((9, g, g))
    n = np.zeros(9)
    for raw, c in enumerate(LAG_CLASSES):
        total[c] += sums[raw]
        n[c] += counts[raw]
    return total / (2.0 * n[:, None, None]), n


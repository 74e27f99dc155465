"""The sub-pixel sampling of SCENE (``OVERSAMP = N``).

A SCENE HDU with ``OVERSAMP = N`` holds the expected charge generated in each
of ``N x N`` sub-pixels of every pixel (shape ``(N ny, N nx)``, electrons);
the ``N x N`` blocks sum to the pixels' totals. Pixel ``p`` covers
``[p - 1/2, p + 1/2]`` (integer coordinates at pixel centres) and holds
sub-pixels ``N p .. N p + N - 1``; sub-pixel ``i`` covers
``[i / N - 1/2, (i + 1) / N - 1/2]``, its centre at ``(i + 1/2) / N - 1/2``.
With ``N = 1`` the file holds pixel totals and nothing here changes them.

Within a sub-pixel the charge is taken as uniform: that is the picture
under which the fine-grid operators below are exact (a shift of a
piecewise-constant density is a linear interpolation of its cell integrals;
a Gaussian spread of charge uniform in a cell is the closed form of
:func:`~.effects.diffusion_weights` at the sub-pixel scale). One exception:
a sub-pixel whose neighbours hold almost nothing (:func:`isolated_points`)
holds a source narrower than itself (a pinhole spot), whose light is taken
at its centre: at ``N = 5`` the two pictures differ by ``1 / (12 N^2)``
px^2 in the spread's variance, 3 % of a 0.22 px diffusion sigma, which the
data of a few thousand hot pixels resolve.
"""

import numpy as np

__all__ = ["block_sum", "block_sum_axis", "shift_fine", "boundary_arrivals", "isolated_points",
           "POINT_CONTRAST"]

POINT_CONTRAST = 0.05  # a sub-pixel is a point when its 8 neighbours hold under 5 % of it


def block_sum(fine, n):
    """Sum ``n x n`` blocks of the last two axes: the pixels' totals.

    A NaN sub-pixel makes its pixel NaN (a bad scene pixel).
    """
    fine = np.asarray(fine, dtype=np.float64)
    n = int(n)
    if n == 1:
        return fine
    ny, nx = fine.shape[-2] // n, fine.shape[-1] // n
    return fine.reshape(fine.shape[:-2] + (ny, n, nx, n)).sum(axis=(-3, -1))


def block_sum_axis(fine, n, axis):
    """Sum groups of ``n`` along ``axis`` (-1 or -2) only."""
    fine = np.asarray(fine, dtype=np.float64)
    n = int(n)
    if n == 1:
        return fine
    if axis == -1:
        return fine.reshape(fine.shape[:-1] + (fine.shape[-1] // n, n)).sum(axis=-1)
    return fine.reshape(fine.shape[:-2] + (fine.shape[-2] // n, n, fine.shape[-1])).sum(axis=-2)


def shift_fine(fine, shift_y, shift_x):
    """Displace a fine grid by ``(shift_y, shift_x)`` sub-pixels.

    The charge in each sub-pixel is taken as uniform within it, so the
    charge a displaced sub-pixel grid holds is the linear interpolation of
    the neighbouring cells' values: exact for that picture, charge
    conserving away from the frame edge, never negative, and as right for a
    single-pixel spot or a sharp patch edge as for a star. The frame is
    extended by its edge values; a stack is shifted frame by frame.
    """
    from scipy.ndimage import shift

    dy, dx = float(shift_y), float(shift_x)
    fine = np.asarray(fine, dtype=np.float64)
    if dy == 0.0 and dx == 0.0:
        return fine
    frames = fine.reshape((-1,) + fine.shape[-2:])
    out = np.stack([shift(f, (dy, dx), order=1, mode="nearest", prefilter=False)
                    for f in frames])
    return out.reshape(fine.shape)


def boundary_arrivals(fine, n, axis):
    """The charge arriving next to each boundary between neighbours along ``axis``.

    Returns ``(low, high)``, shaped like the pixel grid with one fewer entry
    along ``axis``: for the boundary between pixels ``p`` and ``p + 1``,
    ``low`` is the charge in the row (``axis = -2``) or column (``-1``) of
    sub-pixels of ``p`` that touches the boundary, ``high`` that of ``p + 1``,
    each times ``n``: the density there, in charge per pixel width. For
    light uniform across its pixel both equal the pixels' totals.
    """
    fine = np.asarray(fine, dtype=np.float64)
    n = int(n)
    ny, nx = fine.shape[-2] // n, fine.shape[-1] // n
    blocks = fine.reshape(fine.shape[:-2] + (ny, n, nx, n))
    if axis == -1:
        first, last = blocks[..., 0].sum(axis=-2), blocks[..., n - 1].sum(axis=-2)
        return n * last[..., :, :-1], n * first[..., :, 1:]
    first, last = blocks[..., 0, :, :].sum(axis=-1), blocks[..., n - 1, :, :].sum(axis=-1)
    return n * last[..., :-1, :], n * first[..., 1:, :]


_POINTS_CACHE = {}  # id(fine) -> (fine, points): fits diffuse the same SCENE many times


def isolated_points(fine, contrast=POINT_CONTRAST):
    """The charge of sub-pixels whose 8 neighbours each hold less than
    ``contrast`` times their own (zero elsewhere): point sources narrower
    than a sub-pixel."""
    from scipy.ndimage import maximum_filter

    hit = _POINTS_CACHE.get((id(fine), contrast))
    if hit is not None and hit[0] is fine:
        return hit[1]
    key = (id(fine), contrast)
    source = fine
    fine = np.asarray(fine, dtype=np.float64)
    ring = np.ones((3, 3), dtype=bool)
    ring[1, 1] = False
    footprint = ring.reshape((1,) * (fine.ndim - 2) + (3, 3))
    around = maximum_filter(fine, footprint=footprint, mode="constant", cval=0.0)
    points = np.where((fine > 0) & (around < contrast * fine), fine, 0.0)
    if len(_POINTS_CACHE) > 8:
        _POINTS_CACHE.clear()
    _POINTS_CACHE[key] = (source, points)
    return points

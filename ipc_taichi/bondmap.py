"""IPC that varies across the detector: a map of each neighbour pair's coupling.

Physically IPC is a capacitance between two pixel nodes, so the natural map is
one number per neighbour pair (a *bond*), not one kernel per pixel: the charge a
bond moves is ``b(p, q) w(p->q) alpha(S_p, S_q) S_p`` from ``p`` to ``q`` and
``b(p, q) w(q->p) alpha(S_q, S_p) S_q`` back, with the same factor ``b`` both
ways. The model becomes (the paper's Eq. 3 times the map)

``M(p) = S(p) + sum_q b(p, q) [ w(q->p) alpha(S_q, S_p) S_q - w(p->q) alpha(S_p, S_q) S_p ]``

so charge is conserved bond by bond (with the ``isolated`` edge, exactly) and a
uniform detector is the map of ones.

Storage
-------
One array per offset ``u`` of :meth:`ipc_taichi.geometry.Geometry.half_stencil`
(one representative of each ``{u, -u}`` pair): ``values[k, y, x]`` is the factor
of the bond between ``(y, x)`` and ``(y + dy_k, x + dx_k)``. A bond that leaves
the frame (the ``zero`` edge moves charge to the zero-signal pixels outside)
takes the factor stored at the nearest in-frame position: the **edge rule of the
map** is replication, written once in :meth:`BondMap.padded`, which is what the
kernels and the reference both read (the map padded by the geometry's reach, as
the frames are).

A map may be given on super-pixels (``coarse[k, j, i]`` for the super-pixel
``j, i`` of ``superpixel = (sy, sx)`` pixels): it is interpolated bilinearly
from the super-pixels' centres to each bond's midpoint ``(y + dy/2, x + dx/2)``
and held constant beyond the outermost centres (:func:`interpolate`).

Per-pixel kernels
-----------------
Pipelines hold IPC as a kernel per pixel (JWST 4-D ``ipc`` references, Roman
IPC4D). :func:`bonds_from_kernels` converts them by one rule: with ``K_p(d)``
the fraction of pixel ``p``'s charge moved to ``p + d`` (a *scatter* kernel) and
the model's ``K_p(d) = b(p, p+d) w(d) a`` (``a`` the law's alpha at the signal
the kernel stands for), the bond factor is the mean of what its two ends say,

``b(p, p+u) = [ K_p(u) / (w(u) a) + K_{p+u}(-u) / (w(-u) a) ] / 2``,

and half their difference is returned as the rule's error: the part of the
kernels that no charge-conserving pair coupling can hold. A *gather* kernel
``G_q(e)`` (the fraction of ``q``'s measured value that came from ``q + e``) is
the scatter kernel re-indexed, ``K_p(d) = G_{p+d}(-d)``.
"""

from dataclasses import dataclass, field

import numpy as np

from .errors import IPCInputError

__all__ = ["BondMap", "interpolate", "bonds_from_kernels", "kernel_offsets"]


def interpolate(coarse, superpixel, shape, offset=(0.0, 0.0)):
    """Bilinear interpolation of super-pixel values to every pixel (or bond).

    Parameters
    ----------
    coarse : ndarray, shape (nj, ni)
        Values at the super-pixels' centres; super-pixel ``(j, i)`` covers
        pixels ``j*sy .. (j+1)*sy - 1`` in y (its centre at ``(j + 1/2) sy - 1/2``).
    superpixel : (sy, sx)
        Super-pixel size in pixels.
    shape : (ny, nx)
        The full-resolution frame.
    offset : (oy, ox)
        Where in the pixel the value is wanted (``(dy/2, dx/2)``: a bond's midpoint).

    Returns
    -------
    ndarray, shape (ny, nx), float64
        Constant beyond the outermost centres.
    """
    coarse = np.asarray(coarse, dtype=np.float64)
    sy, sx = (int(s) for s in superpixel)
    ny, nx = shape

    def axis(n, s, m, o):
        pos = (np.arange(n) + o + 0.5) / s - 0.5          # in units of super-pixel centres
        pos = np.clip(pos, 0.0, m - 1)
        lo = np.minimum(np.floor(pos).astype(np.intp), max(m - 2, 0))
        t = pos - lo
        hi = np.minimum(lo + 1, m - 1)
        return lo, hi, t

    ylo, yhi, ty = axis(ny, sy, coarse.shape[0], offset[0])
    xlo, xhi, tx = axis(nx, sx, coarse.shape[1], offset[1])
    ty, tx = ty[:, None], tx[None, :]
    return ((1 - ty) * ((1 - tx) * coarse[np.ix_(ylo, xlo)] + tx * coarse[np.ix_(ylo, xhi)])
            + ty * ((1 - tx) * coarse[np.ix_(yhi, xlo)] + tx * coarse[np.ix_(yhi, xhi)]))


@dataclass(frozen=True, eq=False)
class BondMap:
    """Relative coupling of every neighbour pair, per half-stencil offset.

    Build it with :meth:`full` (full resolution) or :meth:`superpixels`.

    Attributes
    ----------
    offsets : tuple of (dy, dx)
        The half-stencil offsets, in the order of
        :meth:`ipc_taichi.geometry.Geometry.half_stencil`.
    values : ndarray, shape (len(offsets), ny, nx), float64
        ``values[k, y, x]``: the factor of the bond ``(y, x) -- (y+dy_k, x+dx_k)``.
    coarse, superpixel :
        The super-pixel values it was interpolated from (``None`` when given at
        full resolution); kept so a model file stays small.
    """

    offsets: tuple
    values: np.ndarray = field(repr=False)
    coarse: np.ndarray = field(default=None, repr=False)
    superpixel: tuple = None

    def __post_init__(self):
        values = np.ascontiguousarray(self.values, dtype=np.float64)
        offsets = tuple((int(dy), int(dx)) for dy, dx in self.offsets)
        if values.ndim != 3 or values.shape[0] != len(offsets):
            raise IPCInputError(f"a bond map needs one 2-D array per half-stencil offset "
                                f"({len(offsets)}), got shape {values.shape}")
        if not np.isfinite(values).all() or (values < 0).any():
            raise IPCInputError("a bond map must be finite and non-negative")
        for dy, dx in offsets:
            if not (dy > 0 or (dy == 0 and dx > 0)):
                raise IPCInputError(f"bond-map offset {(dy, dx)} is not a half-stencil "
                                    "representative (dy > 0, or dy == 0 and dx > 0)")
        values.setflags(write=False)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "offsets", offsets)

    @classmethod
    def full(cls, geometry, values):
        """A full-resolution map for ``geometry``: ``values`` of shape
        ``(n_half, ny, nx)``, or ``(ny, nx)`` for the same factor in every direction."""
        offsets = tuple(u for u, _ in geometry.half_stencil())
        values = np.asarray(values, dtype=np.float64)
        if values.ndim == 2:
            values = np.broadcast_to(values, (len(offsets),) + values.shape)
        return cls(offsets, values)

    @classmethod
    def superpixels(cls, geometry, coarse, superpixel, shape):
        """A map given per super-pixel (``coarse`` of shape ``(n_half, nj, ni)``
        or ``(nj, ni)``), interpolated to each bond's midpoint (:func:`interpolate`)."""
        offsets = tuple(u for u, _ in geometry.half_stencil())
        coarse = np.asarray(coarse, dtype=np.float64)
        if coarse.ndim == 2:
            coarse = np.broadcast_to(coarse, (len(offsets),) + coarse.shape)
        if coarse.shape[0] != len(offsets):
            raise IPCInputError(f"super-pixel map has {coarse.shape[0]} directions, the "
                                f"geometry {len(offsets)}")
        sp = (int(superpixel[0]), int(superpixel[1]))
        values = np.stack([interpolate(c, sp, shape, (dy / 2, dx / 2))
                           for c, (dy, dx) in zip(coarse, offsets)])
        return cls(offsets, values, np.array(coarse), sp)

    @property
    def shape(self):
        """The frame shape ``(ny, nx)`` the map is for."""
        return self.values.shape[1:]

    def check(self, geometry, shape=None):
        """Raise :class:`IPCInputError` unless the map fits ``geometry`` (and ``shape``)."""
        offsets = tuple(u for u, _ in geometry.half_stencil())
        if offsets != self.offsets:
            raise IPCInputError(f"the bond map is for offsets {list(self.offsets)}, the "
                                f"geometry has {list(offsets)}")
        if shape is not None and tuple(shape) != tuple(self.shape):
            raise IPCInputError(f"the bond map is {self.shape[0]}x{self.shape[1]} (ny x nx), "
                                f"the frame {shape[0]}x{shape[1]}")

    def padded(self, reach, dtype=np.float64):
        """``values`` padded by ``reach`` on every side, edge values replicated
        (the map's edge rule): what the kernels and the reference read, at the
        same index as the padded frame."""
        r = int(reach)
        return np.pad(self.values, ((0, 0), (r, r), (r, r)), mode="edge").astype(dtype)

    def crop(self, y0, x0, ny, nx):
        """The map of the sub-frame ``[y0:y0+ny, x0:x0+nx]`` (tiles, Dask blocks).

        Bonds that leave the sub-frame but not the frame keep their own factor
        only inside the sub-frame: callers that couple tiles with a halo crop
        the tile with its halo."""
        return BondMap(self.offsets, self.values[:, y0:y0 + ny, x0:x0 + nx])

    def for_region(self, region, frame, label):
        """The map of the science region ``region`` (a ``(y, x)`` pair of slices)
        of a frame of shape ``frame``: this map if it is the region's size, cut
        from it if it is the whole frame's (a pipeline's reference file covers
        the detector, reference pixels included); else one line naming ``label``."""
        science = tuple(s.stop - s.start for s in region)
        if tuple(self.shape) == science:
            return self
        if tuple(self.shape) == tuple(frame):
            return self.crop(region[0].start, region[1].start, *science)
        raise IPCInputError(f"{label}: the model's bond map is {self.shape[0]}x{self.shape[1]} "
                            f"(ny x nx), the science region {science[0]}x{science[1]} (of a "
                            f"{frame[0]}x{frame[1]} frame)")

    def max_factor(self):
        """The largest bond factor (the convergence bound scales with it)."""
        return float(self.values.max()) if self.values.size else 1.0

    def is_uniform(self):
        """True when every bond's factor is exactly 1 (the uniform model)."""
        return bool((self.values == 1.0).all())

    def __eq__(self, other):
        return (isinstance(other, BondMap) and self.offsets == other.offsets
                and self.values.shape == other.values.shape
                and bool((self.values == other.values).all()))

    def __hash__(self):
        return hash((self.offsets, self.values.shape, self.values.ravel()[:512].tobytes()))


def kernel_offsets(kernels):
    """The offsets ``(dy, dx)`` of a per-pixel kernel array ``(ky, kx, ny, nx)``
    with odd ``ky``, ``kx`` (centre excluded)."""
    ky, kx = kernels.shape[:2]
    if ky % 2 == 0 or kx % 2 == 0:
        raise IPCInputError(f"per-pixel kernels need odd sizes, got {ky}x{kx}")
    cy, cx = ky // 2, kx // 2
    return [(j - cy, i - cx) for j in range(ky) for i in range(kx) if (j, i) != (cy, cx)]


def bonds_from_kernels(kernels, geometry, alpha, convention="scatter"):
    """The bond map that per-pixel kernels stand for (the module's rule).

    Parameters
    ----------
    kernels : ndarray, shape (ky, kx, ny, nx)
        Per-pixel kernels (fractions, forward: a measured frame is the kernels
        applied to the charge), the kernel centre at ``(ky//2, kx//2)``.
    geometry : Geometry
        The offsets and weights the map is for (weights ``w``).
    alpha : float
        The law's alpha at the signal the kernels stand for (``a`` in the rule).
    convention : {"scatter", "gather"}
        ``scatter``: ``kernels[.., y, x]`` spreads pixel ``(y, x)``'s charge;
        ``gather``: it says where pixel ``(y, x)``'s measured value came from.

    Returns
    -------
    bonds : BondMap
    error : ndarray, shape like ``bonds.values``
        Half the difference between what the bond's two ends say (in the
        map's units): the non-conserving part the map cannot hold.
    """
    k = np.asarray(kernels, dtype=np.float64)
    if k.ndim != 4:
        raise IPCInputError(f"per-pixel kernels must be 4-D (ky, kx, ny, nx), got {k.shape}")
    if convention not in ("scatter", "gather"):
        raise IPCInputError(f"convention must be scatter or gather, got {convention!r}")
    cy, cx = k.shape[0] // 2, k.shape[1] // 2
    ny, nx = k.shape[2:]

    def scatter(d):
        """K_p(d) for every p, NaN where p + d (gather: p - d...) leaves the frame."""
        dy, dx = d
        if abs(dy) > cy or abs(dx) > cx:
            return np.zeros((ny, nx))
        if convention == "scatter":
            return k[cy + dy, cx + dx]
        # K_p(d) = G_{p+d}(-d): shift the gather array by -d
        g = k[cy - dy, cx - dx]
        out = np.full((ny, nx), np.nan)
        ys, yd = _shift_slices(ny, dy)
        xs, xd = _shift_slices(nx, dx)
        out[yd, xd] = g[ys, xs]
        return out

    values, errors = [], []
    for u, (w_fwd, w_back) in geometry.half_stencil():
        dy, dx = u
        fwd = scatter(u) / (w_fwd * alpha) if w_fwd else np.full((ny, nx), np.nan)
        back_at_q = scatter((-dy, -dx)) / (w_back * alpha) if w_back else np.full((ny, nx), np.nan)
        back = np.full((ny, nx), np.nan)   # K_{p+u}(-u), moved to p
        ys, yd = _shift_slices(ny, dy)
        xs, xd = _shift_slices(nx, dx)
        back[yd, xd] = back_at_q[ys, xs]
        have_f, have_b = np.isfinite(fwd), np.isfinite(back)
        both = (np.where(have_f, fwd, 0.0) + np.where(have_b, back, 0.0)) / np.maximum(
            have_f.astype(int) + have_b, 1)
        err = np.where(have_f & have_b, np.abs(fwd - back) / 2, 0.0)
        values.append(np.where(have_f | have_b, both, 1.0))
        errors.append(err)
    values = np.clip(np.array(values), 0.0, None)
    return BondMap(tuple(u for u, _ in geometry.half_stencil()), values), np.array(errors)


def _shift_slices(n, d):
    """Source and destination slices so that ``dest[i] = src[i + d]`` where both exist."""
    if d >= 0:
        return slice(d, n), slice(0, n - d)
    return slice(0, n + d), slice(-d, n)

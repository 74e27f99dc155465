"""Per-pixel IPC kernels and the coupling model: the pipelines' form and ours.

Pipelines hold IPC as one small kernel per pixel; the model holds a law, a
geometry and a bond map (:mod:`ipc_taichi.bondmap`). This module converts
between them; :mod:`ipc_taichi.refformats` reads and writes the files.

Kernel conventions (checked against the pipelines' own code)
------------------------------------------------------------
``scatter`` (romanimpreprocess IPC4D, ``utils/ipc_linearity.ipc_fwd``):
    ``K[c+dy, c+dx, y, x]`` is the fraction of pixel ``(y, x)``'s charge that
    lands on ``(y+dy, x+dx)``: the kernel sits at the **source** pixel
    (``output[y,x] = sum_d input[y-dy,x-dx] K[1+dy,1+dx,y-dy,x-dx]``).
``rows`` (JWST 4-D ``ipc``, ``jwst/ipc/ipc_corr.ipc_convolve``):
    ``R[c+dy, c+dx, y, x]`` multiplies the value at ``(y-dy, x-dx)`` to make
    the value at ``(y, x)``: the kernel sits at the **destination** pixel and
    is applied as a convolution (jwst 3.0.0: ``part = k[j, i, y, x] *
    temp[y + (ky-1-j), x + (kx-1-i)]`` with ``temp`` the frame padded by
    ``ky//2``, i.e. source ``y - (j - ky//2)``). Axis order ``(ky, kx, ny, nx)``,
    kernel axes first, ``y`` before ``x`` in both pairs; the 2-D file is the
    same convolution with one kernel. A JWST kernel is the *inverse* (it
    removes IPC): its forward rows are its inverse (below).

The rows of the forward operator and the scatter kernels are the same numbers
re-indexed, ``R_q(d) = K_{q-d}(d)``.

Inverse (JWST) kernels: one rule
--------------------------------
Each pixel's inverse kernel is inverted **exactly as if it held across the
detector** (its convolution inverse on a periodic grid of :data:`GRID` pixels,
cut back to the kernel's size): :func:`invert_kernels`, the same rule for the
2-D file (one kernel) and the 4-D file (every pixel), for reading and for
writing. Its error: (1) the cut drops the inverse's terms beyond the kernel
(second order in alpha: ``alpha^2`` at two pixels for a nearest-neighbour
kernel), which makes a written-then-read coupling differ from the model's by
``~alpha^2`` relative (1e-4 at alpha = 1 %); (2) the JWST pipeline applies the
per-pixel inverse row by row, which is exact to first order in alpha and
differs from the true inverse of a varying detector by ``alpha^2`` times the
change of the map over one pixel, plus the dropped terms of (1): the pipeline
and the iterative decoupler agree to first order, not better. The first-order
rule ``K = 2 delta - Kinv`` was not chosen: it is wrong by ``8 alpha^2``
(nearest neighbours) everywhere, ~5 % of the coupling at alpha = 0.6 %.

Kernels -> model
----------------
:func:`model_from_kernels`: the geometry is the mean kernel's
(:func:`law_from_forward_kernel`: alpha the mean of the four nearest entries,
weights the kernel over alpha); the map is
:func:`ipc_taichi.bondmap.bonds_from_kernels` of the scatter kernels, divided
by its median (over the bonds that couple at all: reference pixels whose
kernel is a delta do not), so the law is the constant ``alpha x median`` (the
typical coupling) and the map's median is 1. Kernels identical at every pixel give
no map (the uniform model).

Model -> kernels
----------------
:func:`scatter_kernels`: ``K_p(d) = w(d) alpha(S, S) b(p, p+d)`` at the
stated signal ``S`` (a signal-dependent law is written as the kernel of a
level scene at ``S``, :data:`DEFAULT_SIGNAL` unless given), the centre
``1 - sum_d K_p(d)``. The map's edge rule (replicated) gives the bonds that
leave the frame; with the ``isolated`` edge they carry nothing.
"""

import numpy as np

from .bondmap import BondMap, bonds_from_kernels
from .errors import IPCInputError
from .geometry import Geometry
from .laws import constant
from .model import CouplingModel

__all__ = ["DEFAULT_SIGNAL", "GRID", "NOISE", "invert_kernels", "law_from_forward_kernel",
           "scatter_kernels", "rows_from_scatter", "scatter_from_rows", "model_from_kernels",
           "is_uniform"]

DEFAULT_SIGNAL = 10000.0
"""Electrons: the signal at which a signal-dependent law is written as a kernel
(``alpha(S, S)``, a level scene), unless ``--signal`` says otherwise."""

GRID = 8
"""Side of the periodic grid on which a 3x3 kernel is inverted, per pixel of
its half-size (5x5: 16): the inverse's terms that wrap around are of order
``alpha^7``, negligible."""

NOISE = 1e-4
"""Kernel entries below this fraction of alpha are noise (a float32 file's
rounding is ~1e-6 of alpha; real diagonal coupling ~0.1 alpha)."""

_CHUNK = 4_000_000  # grid points inverted at once (64 MB of complex numbers)


def invert_kernels(kernels, size=None):
    """The convolution inverse of each kernel, cut to its shape (the module's rule).

    Parameters
    ----------
    kernels : ndarray, shape (ky, kx) or (ky, kx, ny, nx)
        Odd-sized kernels, centre at ``(ky//2, kx//2)``.

    size : int, optional
        The periodic grid's side, even (default :data:`GRID` per pixel of half-size).

    Returns
    -------
    ndarray, same shape, float64
        NaN for a kernel with no inverse (e.g. all zero: a reference pixel).
    """
    k = np.asarray(kernels, dtype=np.float64)
    if k.ndim == 2:
        return invert_kernels(k[:, :, None, None], size)[:, :, 0, 0]
    ky, kx = k.shape[:2]
    size = GRID * max(ky // 2, kx // 2, 1) if size is None else int(size) + int(size) % 2  # even
    if ky % 2 == 0 or kx % 2 == 0 or max(ky, kx) > size // 2:
        raise IPCInputError(f"an IPC kernel must have odd sides up to {size // 2 - 1}, "
                            f"got {ky}x{kx}")
    # the periodic grid's discrete Fourier transform, evaluated only where the
    # kernel is (forward) and where its cut inverse is wanted (back), in real
    # arithmetic: four small matrix products per block of pixels
    oy, ox = np.divmod(np.arange(ky * kx), kx)
    half = size // 2 + 1  # a real kernel's spectrum: the other half is its conjugate
    fy, fx = np.divmod(np.arange(size * half), half)
    theta = 2 * np.pi * (np.outer(fy, oy - ky // 2) + np.outer(fx, ox - kx // 2)) / size
    cos, sin = np.cos(theta), np.sin(theta)
    twice = np.where((fx == 0) | (fx == size // 2), 1.0, 2.0)[:, None]  # counted once, twice
    flat = k.reshape(ky * kx, -1)
    out = np.empty_like(flat)
    step = max(1, _CHUNK // (size * size))
    for p0 in range(0, flat.shape[1], step):
        block = np.ascontiguousarray(flat[:, p0:p0 + step])
        re, im = cos @ block, -(sin @ block)        # the spectrum
        with np.errstate(divide="ignore", invalid="ignore"):  # a zero kernel: NaN, said
            power = re * re + im * im
            re, im = re / power, -im / power        # its reciprocal
        out[:, p0:p0 + step] = (cos.T @ (twice * re) - sin.T @ (twice * im)) / (size * size)
    return out.reshape(k.shape)


def law_from_forward_kernel(kernel, name):
    """``(law, geometry)`` of one forward kernel: the constant alpha = the mean
    of the four nearest entries, the geometry the kernel over alpha (entries
    below :data:`NOISE` alpha, negative ones included, carry no coupling)."""
    k = np.asarray(kernel, dtype=np.float64)
    if k.ndim != 2 or k.shape[0] != k.shape[1] or k.shape[0] not in (3, 5):
        raise IPCInputError(f"{name}: an IPC kernel must be 3x3 or 5x5, got shape {k.shape}")
    c = k.shape[0] // 2
    alpha = float(np.mean([k[c, c - 1], k[c, c + 1], k[c - 1, c], k[c + 1, c]]))
    if not alpha > 0:
        raise IPCInputError(f"{name}: the kernel's nearest entries are not positive "
                            f"(alpha {alpha:.3g}); not a forward IPC kernel")
    noise = k < NOISE * alpha  # negative or negligible far entries carry no coupling
    return constant(alpha), Geometry.from_kernel(np.where(noise, 0.0, k), alpha)


def is_uniform(kernels):
    """Whether a 4-D kernel array holds the same kernel at every pixel."""
    k = np.asarray(kernels)
    return bool((k == k[:, :, :1, :1]).all())


def _shifted(a, dy, dx, fill=np.nan):
    """``out[y, x] = a[y + dy, x + dx]`` where that exists, else ``fill``."""
    ny, nx = a.shape
    out = np.full((ny, nx), fill)
    ys, yd = (slice(dy, ny), slice(0, ny - dy)) if dy >= 0 else (slice(0, ny + dy),
                                                                   slice(-dy, ny))
    xs, xd = (slice(dx, nx), slice(0, nx - dx)) if dx >= 0 else (slice(0, nx + dx),
                                                                   slice(-dx, nx))
    out[yd, xd] = a[ys, xs]
    return out


def scatter_from_rows(rows):
    """Scatter kernels ``K_p(d) = R_{p+d}(d)`` of destination rows (NaN where
    ``p + d`` leaves the frame: the rows do not say)."""
    r = np.asarray(rows, dtype=np.float64)
    cy, cx = r.shape[0] // 2, r.shape[1] // 2
    out = np.empty_like(r)
    for j in range(r.shape[0]):
        for i in range(r.shape[1]):
            out[j, i] = _shifted(r[j, i], j - cy, i - cx)
    return out


def rows_from_scatter(scatter):
    """Destination rows ``R_q(d) = K_{q-d}(d)`` of scatter kernels given on a
    frame padded by the kernel's half-size on every side (the sources beyond
    the edge); returns the rows of the frame inside."""
    k = np.asarray(scatter, dtype=np.float64)
    cy, cx = k.shape[0] // 2, k.shape[1] // 2
    ny, nx = k.shape[2] - 2 * cy, k.shape[3] - 2 * cx
    out = np.empty(k.shape[:2] + (ny, nx))
    for j in range(k.shape[0]):
        for i in range(k.shape[1]):
            dy, dx = j - cy, i - cx
            out[j, i] = k[j, i, cy - dy:cy - dy + ny, cx - dx:cx - dx + nx]
    return out


def scatter_kernels(model, signal=DEFAULT_SIGNAL, shape=None, pad=0):
    """The scatter kernels ``(2r+1, 2r+1, ny+2 pad, nx+2 pad)`` of ``model`` at
    ``signal`` electrons (module docstring); ``shape`` is the map's, or given
    for a uniform model; ``pad`` extends the frame by the map's edge rule."""
    geometry = model.geometry
    r = max(geometry.reach, 1)
    if model.bonds is not None:
        shape = model.bonds.shape
    if shape is None:
        raise IPCInputError("a uniform model has no frame size: give the shape of the kernels")
    ny, nx = (int(n) for n in shape)
    a = float(model.law.alpha(float(signal), float(signal)))
    reach, py, px = geometry.reach + pad, ny + 2 * pad, nx + 2 * pad
    bonds = (model.bonds.padded(reach) if model.bonds is not None
             else np.ones((len(geometry.half_stencil()), ny + 2 * reach, nx + 2 * reach)))
    k = np.zeros((2 * r + 1, 2 * r + 1, py, px))
    o = geometry.reach  # the padded frame's origin inside the map padded by reach + pad
    for n, ((uy, ux), (w_fwd, w_back)) in enumerate(geometry.half_stencil()):
        k[r + uy, r + ux] = w_fwd * a * bonds[n, o:o + py, o:o + px]
        k[r - uy, r - ux] = w_back * a * bonds[n, o - uy:o - uy + py, o - ux:o - ux + px]
    if model.edge == "isolated":  # nothing crosses the frame's edge
        for j in range(2 * r + 1):
            for i in range(2 * r + 1):
                inside = np.zeros((py, px), dtype=bool)
                inside[pad:pad + ny, pad:pad + nx] = True
                k[j, i] *= _shifted(inside.astype(float), j - r, i - r, fill=0.0) * inside
    k[r, r] = 0.0
    k[r, r] = 1.0 - k.sum(axis=(0, 1))
    return k


def _mean_kernel(k):
    """The mean kernel, each ``{u, -u}`` pair averaged over the same bonds: those
    inside the frame between two coupled pixels (:func:`_coupled`), so that a
    map does not make a symmetric coupling look lopsided (the bonds at the
    frame's two edges differ; reference pixels couple to nothing)."""
    cy, cx = k.shape[0] // 2, k.shape[1] // 2
    coupled = _coupled(k)
    mean = np.zeros(k.shape[:2])
    for j in range(k.shape[0]):
        for i in range(k.shape[1]):
            uy, ux = j - cy, i - cx
            if not (uy > 0 or (uy == 0 and ux > 0)):
                continue
            fwd = k[j, i]                                   # K_p(u), the bond p -- p+u
            back = _shifted(k[cy - uy, cx - ux], uy, ux)    # K_{p+u}(-u), the same bond
            both = (np.isfinite(fwd) & np.isfinite(back) & coupled
                    & _shifted(coupled.astype(float), uy, ux, fill=0.0).astype(bool))
            if both.any():
                mean[j, i], mean[cy - uy, cx - ux] = fwd[both].mean(), back[both].mean()
    return mean


def _coupled(k, floor=1e-6):
    """Pixels that both give and receive charge (sums of ``|K|`` above ``floor``,
    unknown entries left out): not a reference pixel whose kernel is a delta."""
    cy, cx = k.shape[0] // 2, k.shape[1] // 2
    give = np.zeros(k.shape[2:])
    take = np.zeros(k.shape[2:])
    for j in range(k.shape[0]):
        for i in range(k.shape[1]):
            if (j, i) != (cy, cx):
                give += np.nan_to_num(np.abs(k[j, i]))
                take += np.nan_to_num(np.abs(_shifted(k[j, i], cy - j, cx - i)))  # K_{p-d}(d)
    return (give > floor) & (take > floor)


def _fill_leaving(raw, k):
    """The map's values with the bonds that leave the frame and that no kernel
    gives (rows of destination pixels say nothing of the outside) copied from
    the bond one step inside, ``p - u`` (clipped into the frame at corners)."""
    values = np.array(raw.values)
    cy, cx = k.shape[0] // 2, k.shape[1] // 2
    ny, nx = values.shape[1:]
    yy, xx = np.mgrid[:ny, :nx]
    for n, (uy, ux) in enumerate(raw.offsets):
        known = np.isfinite(k[cy + uy, cx + ux]) if abs(uy) <= cy and abs(ux) <= cx else \
            np.zeros((ny, nx), dtype=bool)
        out = (yy + uy < 0) | (yy + uy >= ny) | (xx + ux < 0) | (xx + ux >= nx)
        unknown = out & ~known
        iy = np.clip(yy[unknown] - uy, 0, ny - 1)
        ix = np.clip(xx[unknown] - ux, 0, nx - 1)
        values[n][unknown] = values[n][iy, ix]
    return values


def model_from_kernels(scatter, name, edge="zero", law=None):
    """The model that forward scatter kernels ``(ky, kx, ny, nx)`` stand for
    (module docstring); NaN entries are unknown (left out of the mean and of
    the bond's two ends). ``law`` replaces the constant (the map is kept).

    Returns
    -------
    model : CouplingModel
    info : dict
        ``alpha`` (the constant), ``map`` (None or the range, and the rule's
        error: the largest and median half-difference of a bond's two ends,
        relative to the map).
    """
    k = np.asarray(scatter, dtype=np.float64)
    finite = np.isfinite(k).all(axis=(0, 1))
    if not finite.any():
        raise IPCInputError(f"{name}: no pixel has a complete kernel")
    first = k[:, :, finite][:, :, 0]
    if np.where(np.isfinite(k), k == first[:, :, None, None], True).all():  # no map
        base, geometry = law_from_forward_kernel(first, name)
        return (CouplingModel.resolve(law or base, geometry, edge),
                {"alpha": float(base.alpha(0.0, 0.0)), "map": None})
    base, geometry = law_from_forward_kernel(_mean_kernel(k), name)
    alpha0 = float(base.alpha(0.0, 0.0))
    raw, error = bonds_from_kernels(k, geometry, alpha0)
    raw = BondMap(raw.offsets, _fill_leaving(raw, k))
    coupled = raw.values[raw.values > 0]  # not the bonds of uncoupled (reference) pixels
    median = float(np.median(coupled)) if coupled.size else 0.0
    if not median > 0:
        raise IPCInputError(f"{name}: the kernels' median coupling is not positive")
    values = raw.values / median
    model = CouplingModel.resolve(law or constant(alpha0 * median), geometry, edge,
                                  bonds=BondMap(raw.offsets, values))
    rel = error / median
    return model, {"alpha": alpha0 * median,
                   "map": {"min": float(values.min()), "max": float(values.max()),
                           "rule_error_max": float(rel.max()),
                           "rule_error_median": float(np.median(rel))}}

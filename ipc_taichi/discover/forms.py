"""The physical forms of the frame effects that are not IPC: plain NumPy
functions (IPC itself is the core engine, :func:`ipc_taichi.couple`). Each
effect's record (:mod:`.effects`) applies its form in the detector chain; the
forms take the parameters under the names the report uses.
"""

import math

import numpy as np
from scipy.special import ndtr

from ..brighterfatter import (
    BF_REFERENCE,
    isolated_loss,
    kernel_error_from_deflection,
    kernel_from_deflection,
)
from ..errors import IPCInputError
from ..laws import donlon2018
from .sampling import block_sum_axis

__all__ = ["diffuse", "diffusion_weights", "brighter_fatter", "nonlinearity", "reciprocity",
           "shift_scene", "NL_REFERENCE", "BF_REFERENCE", "RECIPROCITY_REFERENCE", "BF_STEPS",
           "LAW_SCALE_DIFF", "LAW_SCALE_LEVEL", "bf_kernel",
           "brighter_fatter_section", "section_kernel"]

NL_REFERENCE = 50000.0  # e-: the signal at which the non-linearity deficit is quoted
# BF_REFERENCE (ipc_taichi.brighterfatter): likewise for the brighter-fatter deflection
RECIPROCITY_REFERENCE = 1.0  # e-: response 1 at this signal (GalSim's base-flux convention)
BF_STEPS = 8  # collection is integrated in this many equal slices of the exposure
# the signal-dependent family's scales: the paper's, from the one place they are written
LAW_SCALE_DIFF = donlon2018().scale_diff
LAW_SCALE_LEVEL = donlon2018().scale_level


def _big_g(t):
    """``G(t) = t Phi(t) + phi(t)``, the integral of the normal CDF ``Phi``."""
    return t * ndtr(t) + np.exp(-0.5 * t * t) / math.sqrt(2.0 * math.pi)


def diffusion_weights(sigma, half):
    """1-D weights on offsets ``-half..half`` of a Gaussian spread of RMS ``sigma`` of
    charge generated uniformly across a pixel and integrated over each collecting pixel.

    ``w_k = int_{-1/2}^{1/2} du int_{k-1/2}^{k+1/2} N(x - u; sigma) dx
    = sigma [G((k+1)/sigma) - 2 G(k/sigma) + G((k-1)/sigma)]``: the pixel box
    convolved with itself (a triangle) and the Gaussian. The neighbour weight
    grows as ``sigma / sqrt(2 pi)`` from zero, so a fit can move from 0.
    """
    k = np.arange(-half, half + 1, dtype=np.float64)
    if sigma <= 1e-9:
        return (k == 0).astype(np.float64)
    s = float(sigma)
    w = s * (_big_g((k + 1) / s) - 2.0 * _big_g(k / s) + _big_g((k - 1) / s))
    w = np.clip(w, 0.0, None)
    return w / w.sum()


def diffuse(charge, sigma_px, at_centre=False, collect=1):
    """Spread charge generated across each pixel's area by a Gaussian of RMS ``sigma_px``.

    Separable and normalised (charge conserved inside the frame); the frame
    is extended by its edge values, as the scene beyond it is unknown. With
    ``at_centre`` the charge is generated at each pixel's centre instead
    (weights ``Phi((k + 1/2)/sigma) - Phi((k - 1/2)/sigma)``): the picture for a
    point source narrower than the cell that holds it. With ``collect = N``
    the cells are sub-pixels and the result is summed over each ``N x N``
    block (the collecting pixels); the sum along x comes before the
    spread along y, which then works on a grid ``N`` times smaller.
    """
    from scipy.ndimage import convolve1d

    sigma = float(sigma_px)
    if sigma <= 0:
        if collect > 1:
            return block_sum_axis(block_sum_axis(charge, collect, -1), collect, -2)
        return charge
    half = max(2, int(math.ceil(4 * sigma)) + 1)
    if at_centre:
        k = np.arange(-half, half + 1, dtype=np.float64)
        w = ndtr((k + 0.5) / sigma) - ndtr((k - 0.5) / sigma)
        w = w / w.sum()
    else:
        w = diffusion_weights(sigma, half)
    out = convolve1d(charge, w, axis=-1, mode="nearest")
    if collect > 1:
        out = block_sum_axis(out, collect, -1)
        return block_sum_axis(convolve1d(out, w, axis=-2, mode="nearest"), collect, -2)
    return convolve1d(out, w, axis=-2, mode="nearest")


def brighter_fatter(charge, deflection_x_at_50ke, deflection_y_at_50ke=None, upwind=0.5,
                    reach=0.0, steps=BF_STEPS, boundary=None):
    """Collect ``charge`` with pixel boundaries shifted by the charge already collected.

    The exposure is integrated in ``steps`` equal slices (midpoint rule).
    The boundary between neighbours ``p`` and ``q`` moves into the fuller
    pixel in proportion to the difference of their collected charge (the
    Antilogus et al. 2014 picture, nearest-neighbour terms, with separate
    strengths along x and y), and the arrivals in the strip it sweeps go to
    the other pixel. Per slice the flow from ``p`` to ``q`` is
    ``d (Q_p - Q_q) / 50 ke- x a / (1 + w)``, with ``a`` the arrivals per
    slice in the swept strip: ``(1 - w) (a_p + a_q) / 2 + w a_up`` where
    ``a_up`` is the shrinking pixel's (``w`` = ``upwind``); dividing by
    ``1 + w`` makes a pixel holding 50 ke- among empty neighbours sends ``d`` of its
    arrivals across its two boundaries in that direction for every ``w``
    (and loses ``(d_x + d_y) / 2`` of its charge over the exposure). With ``w = 0``
    and a constant arrival rate the total flow is
    ``(d / 4)(C_p^2 - C_q^2) / 50 ke-`` (a flow driven by the difference of
    squared charges); ``w = 1`` is the strict boundary-shift picture, which
    moves relatively more charge where the neighbour receives little light
    (hot pixels, the edges of flat patches). The field that moves a
    boundary comes from more than the two pixels: ``Q`` above is the charge
    plus ``reach`` times the charge of the 4 nearest neighbours, so a long
    edge (many charged neighbours) pushes harder than an isolated pixel.
    Flat fields stay flat; charge is conserved except at the frame edge.

    The arrivals in a swept strip are those of the pixel's area when the
    light is uniform across it. Where SCENE says how it lies within each
    pixel, ``boundary`` gives ``{axis: (low, high)}`` for ``axis`` -1 (x)
    and -2 (y): the charge arriving next to each boundary on its two sides,
    per pixel width, over the exposure (:func:`~.sampling.boundary_arrivals`),
    which replace ``a_p`` and ``a_q`` there: light at a pixel's centre is not
    moved by a boundary that shifts by a fraction of a pixel.
    """
    dx = float(deflection_x_at_50ke)
    dy = dx if deflection_y_at_50ke is None else float(deflection_y_at_50ke)
    w, r = float(upwind), float(reach)
    if dx == 0.0 and dy == 0.0:
        return charge
    arrive = np.asarray(charge, dtype=np.float64) / steps
    q = np.zeros_like(arrive)
    norm = 1.0 / (1.0 + w)
    for _ in range(steps):
        qm = q + 0.5 * arrive
        if r != 0.0:
            qm = qm + r * _neighbour_sum(qm)
        q = q + arrive
        for axis, d in ((-1, dx), (-2, dy)):
            if d == 0.0:
                continue
            lo = [slice(None)] * arrive.ndim
            hi = [slice(None)] * arrive.ndim
            lo[axis], hi[axis] = slice(None, -1), slice(1, None)
            lo, hi = tuple(lo), tuple(hi)
            dq = qm[lo] - qm[hi]
            if boundary is None:
                a_lo, a_hi = arrive[lo], arrive[hi]
            else:
                a_lo, a_hi = (b / steps for b in boundary[axis])
            a_up = np.where(dq > 0, a_lo, a_hi)
            swept = (1.0 - w) * 0.5 * (a_lo + a_hi) + w * a_up
            flow = d * norm * dq / BF_REFERENCE * swept
            q[lo] -= flow
            q[hi] += flow
    return q


def _neighbour_sum(q):
    """Sum of the 4 nearest neighbours (nothing beyond the frame)."""
    out = np.zeros_like(q)
    out[..., 1:, :] += q[..., :-1, :]
    out[..., :-1, :] += q[..., 1:, :]
    out[..., :, 1:] += q[..., :, :-1]
    out[..., :, :-1] += q[..., :, 1:]
    return out


def nonlinearity(signal, deficit_at_50ke, cubic_term=0.0):
    """``f(x) = x (1 - (d - b) u - b u^2)``, ``u = x / 50000``: ``d`` below linear at 50 ke-."""
    d, b = float(deficit_at_50ke), float(cubic_term)
    if d == 0.0 and b == 0.0:
        return signal
    u = signal / NL_REFERENCE
    return signal * (1.0 - (d - b) * u - b * u * u)


def reciprocity(charge, alpha_per_decade):
    """``C (C / 1 e-)^(alpha / ln 10)`` for ``C > 0``: a response rising by
    ``alpha`` per decade of signal (the power law of reciprocity failure)."""
    a = float(alpha_per_decade)
    if a == 0.0:
        return charge
    c = np.asarray(charge, dtype=np.float64)
    safe = np.maximum(c, RECIPROCITY_REFERENCE)
    return np.where(c > 0, c * np.exp(a / math.log(10.0) * np.log(safe / RECIPROCITY_REFERENCE)),
                    c)


_SPLINE_CACHE = {}  # (id(scene), frame) -> (scene, coefficients): fits shift the same scenes


def _spline_coefficients(scene, k, frame):
    from scipy.ndimage import spline_filter

    hit = _SPLINE_CACHE.get((id(scene), k))
    if hit is not None and hit[0] is scene:
        return hit[1]
    coeffs = spline_filter(frame, order=5, mode="nearest")
    if len(_SPLINE_CACHE) > 32:
        _SPLINE_CACHE.clear()
    _SPLINE_CACHE[(id(scene), k)] = (scene, coeffs)
    return coeffs


def shift_scene(scene, shift_y_px, shift_x_px):
    """SCENE displaced by ``(shift_y_px, shift_x_px)`` pixels.

    A quintic spline of the pixel values: the picture is a scene smooth on
    the pixel scale (sources imaged through optics), for which it is
    accurate to a fraction of the shot noise of a 50 ke- star at 0.3 px.
    Single-pixel events and sharp edges are not band-limited and are not
    shifted faithfully (see ``docs/discover.md``). The frame is extended by
    its edge values; a stack of frames is shifted frame by frame.
    """
    from scipy.ndimage import shift

    dy, dx = float(shift_y_px), float(shift_x_px)
    scene = np.asarray(scene, dtype=np.float64)
    if dy == 0.0 and dx == 0.0:
        return scene
    frames = scene.reshape((-1,) + scene.shape[-2:])
    out = np.stack([shift(_spline_coefficients(scene, k, f), (dy, dx), order=5, mode="nearest",
                          prefilter=False) for k, f in enumerate(frames)])
    return out.reshape(scene.shape)


def bf_kernel(params, cov=None):
    """The kernel (5x5, per electron) of ``brighter_fatter`` parameters and, with
    ``cov`` (their covariance, in the effect's parameter order), its errors
    (:mod:`ipc_taichi.brighterfatter`); ``upwind`` 1 and ``reach`` 0 where absent."""
    p = {"upwind": 1.0, "reach": 0.0, **params}
    kernel = kernel_from_deflection(p["deflection_x_at_50ke"], p["deflection_y_at_50ke"],
                                    p["reach"], p["upwind"])
    if cov is None:
        return kernel, None
    keys = ("deflection_x_at_50ke", "deflection_y_at_50ke", "upwind", "reach")
    return kernel, kernel_error_from_deflection(p, cov, keys)


def brighter_fatter_section(params, cov=None, source="fitted"):
    """The report's ``brighter_fatter``: the model's boundary-shift parameters as
    the kernel ``ipc-taichi calibrate`` measures (the model file's section),
    so a lab can compare the two (:mod:`ipc_taichi.brighterfatter`).

    ``cov`` is the parameters' covariance (the effect's order) for
    ``kernel_error``; ``source`` says where the parameters came from.
    """
    kernel, error = bf_kernel(params, cov)
    return {"kernel": kernel.tolist(), "kernel_error": None if error is None else error.tolist(),
            "units": "1/electron",
            "convention": "pixel area 1 + sum_d a(d) Q(p+d); a[2+dy][2+dx]",
            "params": dict(params), "source": source,
            "isolated_loss_at_50ke": isolated_loss(kernel),
            "picture": "the kernel of the boundary shifts for light smooth across neighbouring "
                       "pixels, where the two pictures agree for any upwind "
                       "(ipc_taichi.brighterfatter.kernel_from_deflection); terms beyond the "
                       "nearest neighbours come from reach alone"}


def section_kernel(section, key, source):
    """A 5x5 array of finite numbers from a model file's ``brighter_fatter`` section
    (``None`` when the key is absent)."""
    if section.get(key) is None:
        return None
    try:
        value = np.asarray(section[key], dtype=np.float64)
    except (TypeError, ValueError):
        value = np.zeros(0)
    if value.shape != (5, 5) or not np.all(np.isfinite(value)):
        raise IPCInputError(f"{source}: brighter_fatter.{key} must be a 5x5 array of finite "
                            f"numbers (per electron, [2+dy][2+dx])")
    return value

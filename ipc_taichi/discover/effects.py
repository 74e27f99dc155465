"""The vocabulary of detector effects the discrepancy workflow can add.

Each effect has a name (the names of ``docs/discovery_format.md``), a stage
of the detector chain (see :mod:`ipc_taichi.discover.model` for the order and
why), and a few parameters, each with the value that means "off", bounds and
a typical scale. Every parameter enters the model smoothly through its "off"
value with a non-zero first derivative there (no form is flat at zero), and
the bounds allow the sign that contradicts the effect's meaning wherever a
fit might need it: a fit that wants the wrong sign must be able to say so
(:func:`contradiction`), instead of sticking at the bound and looking like
"no effect". The physics of the effects that are not IPC lives here as
plain NumPy functions; IPC itself is the core engine (:func:`ipc_taichi.couple`).

Parameters (all reported under these names)
-------------------------------------------
``misregistration``
    ``shift_y_px``, ``shift_x_px``: MEASURED is SCENE displaced by this many
    pixels (a source at ``x0`` in SCENE is seen at ``x0 + shift_x_px``).
``reciprocity_failure``
    ``alpha_per_decade``: the collected photo-charge is
    ``C (C / 1 e-)^(alpha / ln 10)``: the response rises by ``alpha`` (a
    fraction) per decade of signal (count rate at a fixed exposure time).
``charge_diffusion``
    ``sigma_px``: RMS (pixels) of the lateral spread of carriers generated
    uniformly across the pixel area, integrated over the collecting pixels.
``dark_current``
    ``dark_e``: electrons of collected charge added to every pixel.
``brighter_fatter``
    ``deflection_x_at_50ke``, ``deflection_y_at_50ke``: the fraction of newly
    arriving charge that a pixel already holding 50 ke- more than its empty
    neighbours sends across its boundaries along x (to its two row
    neighbours together) and along y (to its two column neighbours);
    ``upwind`` (0-1): which arrivals a moved boundary hands over, from the
    mean of the two pixels' (0: a flow driven by the difference of squared
    charges) to the shrinking pixel's own (1: the boundary-shift picture);
    ``reach``: how much the charge of the 4 nearest neighbours of the two
    pixels adds to the field that moves their boundary (0: only the two
    pixels' own charge; a long edge then pushes as hard as a single pixel).
``flat_field``
    ``response_variance``: variance of the per-pixel response (gain or QE)
    about 1; reported also as ``response_rms``.
``diagonal_ipc``, ``second_neighbor_ipc``
    ``alpha_diag``, ``alpha_second``: coupling fraction per neighbour at zero
    signal (a geometry weight ``alpha / alpha(0, 0)`` on the law).
``anisotropic_ipc``
    ``weight_horizontal``, ``weight_vertical``: multipliers of alpha along a
    row and along a column; reported with ``anisotropy = (h - v)/((h + v)/2)``.
``signal_dependent_ipc``
    ``amp_diff``, ``amp_level``, ``alpha_floor``: the constant starting law
    becomes the donlon2018 family with its scales (``ipc_taichi.laws``) and
    these amplitudes. Offered only when the starting law is constant.
``classical_nonlinearity``
    ``deficit_at_50ke``, ``cubic_term``: ``f(x) = x (1 - (d - b) u - b u^2)``
    with ``u = x / 50000 e-``, after IPC.
``excess_read_noise``
    ``excess_variance_e2``: read-noise variance above ``READNOIS^2``
    (electrons squared); reported also as ``readnoise_e``.
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from ..brighterfatter import (
    BF_REFERENCE,
    kernel_error_from_deflection,
    kernel_from_deflection,
    kernel_plausibility,
)
from ..laws import donlon2018
from .sampling import block_sum_axis

__all__ = ["Param", "Effect", "EFFECTS", "EFFECT_NAMES", "SEPARATION", "DEGENERATE",
           "diffuse", "diffusion_weights", "brighter_fatter", "nonlinearity", "reciprocity",
           "shift_scene", "derived_params", "contradiction", "implausible", "bf_kernel",
           "PHYSICAL_LIMITS",
           "NL_REFERENCE", "BF_REFERENCE",
           "RECIPROCITY_REFERENCE", "LAW_SCALE_DIFF", "LAW_SCALE_LEVEL"]

NL_REFERENCE = 50000.0  # e-: the signal at which the non-linearity deficit is quoted
# BF_REFERENCE (ipc_taichi.brighterfatter): likewise for the brighter-fatter deflection
RECIPROCITY_REFERENCE = 1.0  # e-: response 1 at this signal (GalSim's base-flux convention)
BF_STEPS = 8  # collection is integrated in this many equal slices of the exposure
# the signal-dependent family's scales: the paper's, from the one place they are written
LAW_SCALE_DIFF = donlon2018().scale_diff
LAW_SCALE_LEVEL = donlon2018().scale_level


@dataclass(frozen=True)
class Param:
    """One fitted parameter: its "off" value, bounds and scale."""

    name: str
    off: float
    lower: float
    upper: float
    scale: float
    scan: bool = True  # try a coarse scan for the start (shape parameters need none)


@dataclass(frozen=True)
class Effect:
    """A named detector effect and where it acts.

    ``stage`` is ``"scene"`` (a data problem, before the detector),
    ``"collection"`` (changes the expected collected charge, before shot
    noise), ``"coupling"`` (the IPC law or geometry), ``"readout"`` (acts on
    the node signal after coupling) or ``"variance"`` (changes only the
    noise: its fit maximises the Gaussian likelihood with the mean fixed).
    """

    name: str
    stage: str
    params: tuple
    meaning: str

    def off(self):
        return {p.name: p.off for p in self.params}


EFFECTS = {e.name: e for e in (
    Effect("misregistration", "scene",
           (Param("shift_y_px", 0.0, -1.5, 1.5, 0.01), Param("shift_x_px", 0.0, -1.5, 1.5, 0.01)),
           "SCENE and MEASURED are offset by a sub-pixel shift"),
    Effect("diagonal_ipc", "coupling",
           (Param("alpha_diag", 0.0, 0.0, 0.02, 1e-3),),
           "coupling to the 4 diagonal neighbours"),
    Effect("anisotropic_ipc", "coupling",
           (Param("weight_horizontal", 1.0, 0.2, 3.0, 0.05),
            Param("weight_vertical", 1.0, 0.2, 3.0, 0.05)),
           "coupling along rows differs from coupling along columns"),
    Effect("second_neighbor_ipc", "coupling",
           (Param("alpha_second", 0.0, 0.0, 0.02, 1e-3),),
           "coupling to pixels two steps away along a row or column"),
    Effect("signal_dependent_ipc", "coupling",
           (Param("amp_diff", 0.0, -0.01, 0.05, 1e-3),
            Param("amp_level", 0.0, -0.01, 0.05, 1e-3),
            Param("alpha_floor", float("nan"), 0.0, 0.05, 1e-3)),  # off = the constant alpha
           "the coupling varies with signal"),
    Effect("classical_nonlinearity", "readout",
           (Param("deficit_at_50ke", 0.0, -0.3, 0.5, 0.01),
            Param("cubic_term", 0.0, -0.5, 0.5, 0.01, scan=False)),
           "the pixel's response falls below linear as its signal grows"),
    Effect("reciprocity_failure", "collection",
           (Param("alpha_per_decade", 0.0, -0.1, 0.2, 0.002),),
           "the response rises above linear as the signal (count rate) grows"),
    Effect("brighter_fatter", "collection",
           (Param("deflection_x_at_50ke", 0.0, -0.2, 0.3, 0.003),
            Param("deflection_y_at_50ke", 0.0, -0.2, 0.3, 0.003),
            # upwind and reach do nothing at zero deflection: their "off" values
            # are the starting guesses of the field's standard picture
            Param("upwind", 1.0, 0.0, 1.0, 0.05, scan=False),
            Param("reach", 0.5, -0.5, 1.0, 0.05, scan=False)),
           "charge already collected pushes new charge into neighbours"),
    Effect("charge_diffusion", "collection",
           (Param("sigma_px", 0.0, 0.0, 1.5, 0.02),),
           "carriers spread to neighbours before collection (blur before shot noise)"),
    Effect("dark_current", "collection",
           (Param("dark_e", 0.0, -1e4, 1e6, 1.0),),
           "a spatially uniform additive collected charge"),
    Effect("flat_field", "variance",
           (Param("response_variance", 0.0, 0.0, 0.01, 1e-5),),
           "pixel-to-pixel response variation, fixed per pixel across the pairs"),
    Effect("excess_read_noise", "variance",
           (Param("excess_variance_e2", 0.0, -1e4, 1e5, 1.0),),
           "the read noise is larger than READNOIS says"),
)}

EFFECT_NAMES = tuple(EFFECTS)

# Pairs whose signatures overlap: when one of them is a candidate and the
# other is already in the model, the candidate is fitted together with the
# partner's parameters (a joint refit), so neither is dropped for having been
# fitted with the other's value frozen.
DEGENERATE = (
    frozenset({"charge_diffusion", "brighter_fatter"}),
    frozenset({"anisotropic_ipc", "diagonal_ipc"}),
    frozenset({"charge_diffusion", "diagonal_ipc"}),
    frozenset({"classical_nonlinearity", "reciprocity_failure"}),
    frozenset({"brighter_fatter", "classical_nonlinearity"}),
    frozenset({"flat_field", "excess_read_noise"}),
)

# What tells near-degenerate effects apart (reported with the alternatives).
SEPARATION = {
    frozenset({"charge_diffusion", "diagonal_ipc"}):
        "diffusion also feeds the 4 nearest neighbours (more than the diagonals) and acts "
        "before shot noise; diagonal IPC feeds only the diagonals and scales with the law",
    frozenset({"charge_diffusion", "brighter_fatter"}):
        "diffusion moves a fixed fraction at every signal; brighter-fatter moves a fraction "
        "that grows with the charge already collected (compare stacks binned by signal)",
    frozenset({"brighter_fatter", "diagonal_ipc"}):
        "brighter-fatter feeds the nearest neighbours and grows with signal; diagonal IPC "
        "feeds the diagonals",
    frozenset({"charge_diffusion", "anisotropic_ipc"}):
        "diffusion is isotropic with a fixed fraction and a small diagonal part; a rescaled "
        "IPC geometry follows the law's signal dependence and has no diagonal part",
    frozenset({"brighter_fatter", "anisotropic_ipc"}):
        "brighter-fatter grows with signal; a rescaled IPC geometry follows the law",
    frozenset({"brighter_fatter", "classical_nonlinearity"}):
        "brighter-fatter conserves charge (neighbours gain what the peak loses) and leaves "
        "flat fields flat; non-linearity loses signal, flat patches included",
    frozenset({"brighter_fatter", "signal_dependent_ipc"}):
        "both change the neighbour fraction with signal; brighter-fatter acting on the "
        "arriving charge, before shot noise, makes the neighbours' variance grow with what "
        "they receive, a coupling does not (compare evidence_with_variance: positive for "
        "brighter-fatter when it acts before shot noise; a flow computed from the collected "
        "charge is, in its noise, a coupling)",
    frozenset({"signal_dependent_ipc", "anisotropic_ipc"}):
        "a signal-dependent law changes the coupling with signal in both directions; "
        "anisotropy changes it by direction at every signal",
    frozenset({"second_neighbor_ipc", "charge_diffusion"}):
        "diffusion feeds the nearest neighbours first; second-neighbour IPC skips them",
    frozenset({"classical_nonlinearity", "reciprocity_failure"}):
        "non-linearity lowers the response at high signal, after IPC; reciprocity failure "
        "raises it, logarithmically, before shot noise",
    frozenset({"dark_current", "reciprocity_failure"}):
        "dark current adds the same charge everywhere; reciprocity failure scales with signal",
    frozenset({"flat_field", "excess_read_noise"}):
        "a response map adds variance growing as signal squared and repeating pixel by pixel "
        "across pairs; excess read noise is the same at every signal",
}


def contradiction(effect, params):
    """Why fitted ``params`` contradict the meaning of ``effect`` (``None`` if they do not).

    Such a fit is not reported under the effect's name: a non-linearity that
    rises above linear is not a non-linearity.
    """
    p = params
    if effect == "classical_nonlinearity" and p["deficit_at_50ke"] <= 0:
        return (f"the response rises above linear (deficit at 50 ke- "
                f"{p['deficit_at_50ke']:.4g} <= 0)")
    if effect == "reciprocity_failure" and p["alpha_per_decade"] <= 0:
        return f"the response falls with signal (alpha per decade {p['alpha_per_decade']:.4g})"
    if effect == "brighter_fatter":
        dx, dy = p["deflection_x_at_50ke"], p["deflection_y_at_50ke"]
        if dx + dy <= 0 or min(dx, dy) < -0.25 * abs(dx + dy):
            return (f"collected charge would attract new charge (deflections x {dx:.4g}, "
                    f"y {dy:.4g})")
    if effect == "dark_current" and p["dark_e"] <= 0:
        return f"a negative collected charge ({p['dark_e']:.4g} e-)"
    if effect == "excess_read_noise" and p["excess_variance_e2"] <= 0:
        return f"less read noise than READNOIS ({p['excess_variance_e2']:.4g} e-^2)"
    return None


# The largest strength a real detector shows, per effect (beyond it a fit is
# absorbing something else): HgCdTe and CCD response maps (quantum efficiency
# and gain together) vary by a few per cent RMS; a read noise is not several
# times what the detector's own characterisation (READNOIS) says. The
# brighter-fatter effect is judged by its kernel (ipc_taichi.brighterfatter:
# KERNEL_LIMITS and kernel_plausibility), whose size and shape real detectors bound.
PHYSICAL_LIMITS = {"flat_field": 0.05, "excess_read_noise": 3.0}


def bf_kernel(params, cov=None):
    """The kernel (5x5, per electron) of ``brighter_fatter`` parameters and, with
    ``cov`` (their covariance, in the effect's parameter order), its errors
    (:mod:`ipc_taichi.brighterfatter`); ``upwind`` 1 and ``reach`` 0 where absent."""
    p = {"upwind": 1.0, "reach": 0.0, **params}
    kernel = kernel_from_deflection(p["deflection_x_at_50ke"], p["deflection_y_at_50ke"],
                                    p["reach"], p["upwind"])
    if cov is None:
        return kernel, None
    keys = tuple(q.name for q in EFFECTS["brighter_fatter"].params)
    return kernel, kernel_error_from_deflection(p, cov, keys)


def implausible(effect, params, readnoise=None, cov=None):
    """Why fitted ``params`` lie outside the physical range of ``effect``
    (:data:`PHYSICAL_LIMITS`; for ``excess_read_noise`` a multiple of the
    header's ``readnoise``; for ``brighter_fatter`` the kernel the parameters
    amount to, :func:`ipc_taichi.brighterfatter.kernel_plausibility`, with
    ``cov`` the parameters' covariance for its errors), or ``None``. Such a fit
    is not named: its strength or shape says it absorbs a misfit of another kind."""
    limit = PHYSICAL_LIMITS.get(effect)
    if effect == "excess_read_noise" and readnoise:
        total = math.sqrt(max(readnoise ** 2 + params["excess_variance_e2"], 0.0))
        if total > limit * readnoise:
            return (f"a read noise of {total:.1f} e- ({total / readnoise:.1f} times READNOIS; "
                    f"at most {limit:g} times is plausible)")
    if effect == "flat_field":
        rms = math.sqrt(max(params["response_variance"], 0.0))
        if rms > limit:
            return (f"a response map of RMS {100 * rms:.1f} % (a real one is at most "
                    f"{100 * limit:g} %)")
    if effect == "brighter_fatter":
        why = kernel_plausibility(*bf_kernel(params, cov))
        if why:
            return f"its kernel is not a real detector's: {why}"
    return None


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


def derived_params(effect, params, uncertainties=None, cov=None, readnoise=None):
    """Extra reported quantities (and their uncertainties) derived from the fit."""
    if effect == "flat_field":
        u = params["response_variance"]
        su = (uncertainties or {}).get("response_variance", float("nan")) if cov is None \
            else float(np.sqrt(max(cov[0, 0], 0.0)))
        rms = math.sqrt(max(u, 0.0))
        return {"response_rms": rms}, {"response_rms": su / (2 * rms) if rms > 0 else su ** 0.5}
    if effect == "excess_read_noise" and readnoise is not None:
        e = params["excess_variance_e2"]
        se = (uncertainties or {}).get("excess_variance_e2", float("nan")) if cov is None \
            else float(np.sqrt(max(cov[0, 0], 0.0)))
        rn = math.sqrt(max(readnoise ** 2 + e, 0.0))
        return {"readnoise_e": rn}, {"readnoise_e": se / (2 * rn) if rn > 0 else float("nan")}
    if effect != "anisotropic_ipc":
        return {}, {}
    h, v = params["weight_horizontal"], params["weight_vertical"]
    m = 0.5 * (h + v)
    a = (h - v) / m
    # gradient of a = (h - v) / ((h + v)/2) with respect to (h, v)
    g = np.array([1.0 / m - a / (2 * m), -1.0 / m - a / (2 * m)])
    if cov is not None:
        sa = float(np.sqrt(max(g @ cov @ g, 0.0)))
    elif uncertainties is not None:
        sa = float(np.hypot(g[0] * uncertainties["weight_horizontal"],
                            g[1] * uncertainties["weight_vertical"]))
    else:
        sa = float("nan")
    return {"anisotropy": float(a)}, {"anisotropy": sa}

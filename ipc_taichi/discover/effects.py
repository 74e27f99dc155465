"""The vocabulary of detector effects the discrepancy workflow can add.

Each effect has a name (the names of ``DISCOVERY_FORMAT.md``), a stage of
the detector chain (see :mod:`ipc_taichi.discover.model` for the order and
why), and a few parameters, each with the value that means "off", bounds and
a typical scale. The physics of the effects that are not IPC lives here as
plain NumPy functions; IPC itself is the core engine (:func:`ipc_taichi.couple`)
with a law and a :class:`~ipc_taichi.Geometry`.

Parameters (all reported under these names)
-------------------------------------------
``diagonal_ipc``
    ``alpha_diag``: coupling fraction to each diagonal neighbour at zero
    signal (absolute, e.g. 0.0015). It is a geometry weight
    ``alpha_diag / alpha(0, 0)`` multiplying the law, so it follows the
    law's signal dependence.
``anisotropic_ipc``
    ``weight_horizontal``, ``weight_vertical``: multipliers of alpha along a
    row and along a column (1, 1 = the starting model); reported with
    ``anisotropy = (h - v) / ((h + v) / 2)``, a fraction.
``second_neighbor_ipc``
    ``alpha_second``: coupling fraction to each pixel two steps away along a
    row or column, at zero signal (a geometry weight like ``alpha_diag``).
``signal_dependent_ipc``
    ``amp_diff``, ``amp_level``, ``alpha_floor``: the constant starting law
    becomes ``amp_diff exp(-|S-N|/20000)
    + amp_level exp(-sqrt(S^2+N^2)/(20000 sqrt2)) + alpha_floor``
    (the family of Donlon et al. 2018; fractions). Offered only when the
    starting law is constant.
``classical_nonlinearity``
    ``deficit_at_50ke``, ``cubic_term``: ``f(x) = x (1 - (d - b) u - b u^2)``
    with ``u = x / 50000 e-``: the response is ``d`` (a fraction) below
    linear at 50 ke-; ``b`` lets the curve bend like a cubic polynomial.
``brighter_fatter``
    ``deflection_at_50ke``: fraction of newly arriving charge that a pixel
    already holding 50 ke- pushes into its 4 nearest neighbours (in total);
    proportional to the charge already collected.
``charge_diffusion``
    ``sigma_px``: RMS of a Gaussian blur of the arriving charge (pixels),
    integrated over pixels, applied before shot noise.
``dark_current``
    ``dark_e``: uniform charge added to every pixel (electrons per frame).
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

__all__ = ["Param", "Effect", "EFFECTS", "EFFECT_NAMES", "SEPARATION", "diffuse",
           "brighter_fatter", "nonlinearity", "derived_params", "NL_REFERENCE",
           "LAW_SCALE_DIFF", "LAW_SCALE_LEVEL"]

NL_REFERENCE = 50000.0  # e-: the signal at which the non-linearity deficit is quoted
BF_REFERENCE = 50000.0  # e-: likewise for the brighter-fatter deflection
BF_STEPS = 8            # collection is integrated in this many equal slices of the exposure
LAW_SCALE_DIFF = 20000.0                   # the scales of the donlon2018 family
LAW_SCALE_LEVEL = 20000.0 * math.sqrt(2.0)


@dataclass(frozen=True)
class Param:
    """One fitted parameter: its "off" value, bounds, scale and starting seeds."""

    name: str
    off: float
    lower: float
    upper: float
    scale: float
    seeds: tuple = ()  # extra starting points for parameters with a flat start (sigma_px)


@dataclass(frozen=True)
class Effect:
    """A named detector effect and where it acts.

    ``stage`` is ``"collection"`` (changes the expected collected charge,
    before shot noise), ``"coupling"`` (changes the IPC law or geometry) or
    ``"readout"`` (acts on the node signal after coupling).
    """

    name: str
    stage: str
    params: tuple
    meaning: str

    def off(self):
        return {p.name: p.off for p in self.params}


EFFECTS = {e.name: e for e in (
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
            Param("cubic_term", 0.0, -0.5, 0.5, 0.01)),
           "the pixel's response falls below linear as its signal grows"),
    Effect("brighter_fatter", "collection",
           (Param("deflection_at_50ke", 0.0, 0.0, 0.2, 0.005),),
           "charge already collected pushes new charge into neighbours"),
    Effect("charge_diffusion", "collection",
           (Param("sigma_px", 0.0, 0.0, 1.5, 0.05, seeds=(0.15, 0.3, 0.5)),),
           "carriers spread to neighbours before collection (blur before shot noise)"),
    Effect("dark_current", "collection",
           (Param("dark_e", 0.0, -1e4, 1e6, 1.0),),
           "a spatially uniform additive signal"),
)}

EFFECT_NAMES = tuple(EFFECTS)

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
        "both change the neighbour fraction with signal; brighter-fatter acts before shot "
        "noise (the neighbours' variance grows) and on the pixel's own charge",
    frozenset({"signal_dependent_ipc", "anisotropic_ipc"}):
        "a signal-dependent law changes the coupling with signal in both directions; "
        "anisotropy changes it by direction at every signal",
    frozenset({"second_neighbor_ipc", "charge_diffusion"}):
        "diffusion feeds the nearest neighbours first; second-neighbour IPC skips them",
}


def _gaussian_weights(sigma, half):
    """Pixel-integrated 1-D Gaussian on offsets -half..half, normalised."""
    k = np.arange(-half, half + 1, dtype=np.float64)
    if sigma <= 0:
        return (k == 0).astype(np.float64)
    w = ndtr((k + 0.5) / sigma) - ndtr((k - 0.5) / sigma)
    return w / w.sum()


def diffuse(charge, sigma_px):
    """Blur arriving charge by a pixel-integrated Gaussian of RMS ``sigma_px``.

    Separable, normalised (charge conserved inside the frame); the frame is
    extended by its edge values, as the scene beyond it is unknown.
    """
    from scipy.ndimage import convolve1d

    sigma = float(sigma_px)
    if sigma <= 0:
        return charge
    half = max(2, int(math.ceil(4 * sigma)))
    w = _gaussian_weights(sigma, half)
    out = convolve1d(charge, w, axis=-1, mode="nearest")
    return convolve1d(out, w, axis=-2, mode="nearest")


def _spread_to_neighbours(out_each):
    """Charge arriving at each pixel from its 4 nearest neighbours, each of
    which sends ``out_each`` to every neighbour (none arrives from outside)."""
    gain = np.zeros_like(out_each)
    gain[..., 1:, :] += out_each[..., :-1, :]
    gain[..., :-1, :] += out_each[..., 1:, :]
    gain[..., :, 1:] += out_each[..., :, :-1]
    gain[..., :, :-1] += out_each[..., :, 1:]
    return gain


def brighter_fatter(charge, deflection_at_50ke, steps=BF_STEPS):
    """Collect ``charge`` in ``steps`` equal slices; charge arriving at a pixel
    that already holds ``Q`` goes, for a fraction ``deflection * Q / 50 ke-``,
    to its 4 nearest neighbours instead (a quarter each).

    This is the brighter-fatter picture of charge already collected repelling
    new charge. The midpoint of each slice is used for ``Q`` (second-order in
    the slice). Flat fields stay flat; total charge is conserved except at the
    frame edge.
    """
    d = float(deflection_at_50ke)
    if d == 0.0:
        return charge
    arrive = charge / steps
    q = np.zeros_like(charge)
    for _ in range(steps):
        frac = np.clip(d * (q + 0.5 * arrive) / BF_REFERENCE, -0.5, 0.5) * 0.25
        out_each = arrive * frac
        q = q + arrive - 4.0 * out_each + _spread_to_neighbours(out_each)
    return q


def nonlinearity(signal, deficit_at_50ke, cubic_term=0.0):
    """``f(x) = x (1 - (d - b) u - b u^2)``, ``u = x / 50000``: ``d`` below linear at 50 ke-."""
    d, b = float(deficit_at_50ke), float(cubic_term)
    if d == 0.0 and b == 0.0:
        return signal
    u = signal / NL_REFERENCE
    return signal * (1.0 - (d - b) * u - b * u * u)


def derived_params(effect, params, uncertainties=None, cov=None):
    """Extra reported quantities (and their uncertainties) derived from the fit."""
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

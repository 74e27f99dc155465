"""The vocabulary of detector effects the discrepancy workflow can add: one
record per effect (:class:`~.record.Effect`), all in :data:`EFFECTS`.

Each record's docstring says what its parameters mean (all reported under
these names) and what its one ``--effect NAME=VALUE`` value is; its methods
are its place in the chain (:mod:`.model`), its tests and its conversions
(:mod:`.record`). The physical forms are :mod:`.forms`. Adding an effect is
one more record here, or :func:`register` (``docs/discover.md``, "Adding an
effect"); :data:`DEGENERATE` and :data:`SEPARATION` say which effects look
alike and what tells them apart.
"""

import math

import numpy as np

from ..brighterfatter import BF_REFERENCE, deflection_from_kernel, kernel_plausibility
from ..errors import IPCInputError
from ..laws import ParametricLaw, get_law
from .diagnostics import UNEXPLAINED_Z
from .forms import (
    BF_STEPS,
    LAW_SCALE_DIFF,
    LAW_SCALE_LEVEL,
    NL_REFERENCE,
    RECIPROCITY_REFERENCE,
    bf_kernel,
    brighter_fatter,
    brighter_fatter_section,
    diffuse,
    diffusion_weights,
    nonlinearity,
    reciprocity,
    section_kernel,
    shift_scene,
)
from .pairs import DEGENERATE, SEPARATION
from .record import (
    CHAIN_STAGES,
    SHIFT_ANTISYMMETRY,
    Effect,
    Param,
    is_constant_law,
)
from .sampling import block_sum, boundary_arrivals, isolated_points, shift_fine

__all__ = ["Param", "Effect", "EFFECTS", "EFFECT_NAMES", "SEPARATION", "DEGENERATE",
           "register", "chain_order", "physical_limits", "is_constant_law",
           "diffuse", "diffusion_weights", "brighter_fatter", "nonlinearity", "reciprocity",
           "shift_scene", "derived_params", "contradiction", "implausible", "bf_kernel",
           "brighter_fatter_section", "PHYSICAL_LIMITS", "SHIFT_ANTISYMMETRY",
           "NL_REFERENCE", "BF_REFERENCE", "BF_STEPS",
           "RECIPROCITY_REFERENCE", "LAW_SCALE_DIFF", "LAW_SCALE_LEVEL"]


def _variance_error(uncertainties, cov, key):
    return (uncertainties or {}).get(key, float("nan")) if cov is None \
        else float(np.sqrt(max(cov[0, 0], 0.0)))


class Misregistration(Effect):
    """``shift_y_px``, ``shift_x_px``: MEASURED is SCENE displaced by this many
    pixels (a source at ``x0`` in SCENE is seen at ``x0 + shift_x_px``). A
    data problem, not a detector effect: it comes first in the chain and is
    named first when it qualifies (every effect downstream sees its dipoles)."""

    position = 0.0
    first = True
    picture_dependent = True
    subpixel = (
        "the fitted shift moves SCENE by interpolating its pixel values, exact only for "
        "light smooth on the pixel scale; how the light lies within a pixel is not in "
        "SCENE (a star and a uniform 1x1 source of the same pixel values shift "
        "differently), so without the sources' profiles no interpolation shifts stars "
        "sharper than about 2.2 px FWHM, single-pixel events and sharp edges exactly (a "
        "0.3 px shift of a 1.8 px FWHM star leaves 1.8 % of its peak with a spline and "
        "with a band-limited shift alike): what remains here may be that limit of the "
        "data, not a missing effect; a SCENE with OVERSAMP (the light on a sub-pixel grid) "
        "lifts it")

    def collect(self, charge, p):
        n = charge.oversample
        if n > 1 or charge.within_pixel == "uniform":  # exact for light uniform in a cell
            charge.value = shift_fine(charge.value, n * p["shift_y_px"], n * p["shift_x_px"])
        else:  # the spline undershoots next to sharp features: no negative charge
            charge.value = np.clip(shift_scene(charge.value, p["shift_y_px"], p["shift_x_px"]),
                                   0.0, None)

    def refuted(self, check, trial):
        ratio = check.antisymmetry(trial, self.name)
        if not ratio >= SHIFT_ANTISYMMETRY:  # a blur can pass for a spline shift
            return (f"a shift, but not an antisymmetric one: displaced the other way the model "
                    f"fits only {ratio:.2f} times the shift's gain worse than unshifted (a shift "
                    f"gives 2, a symmetric misfit such as a blur 0; needs "
                    f"{SHIFT_ANTISYMMETRY:g})")
        return None

    def from_value(self, value, readnoise=None):
        """The shift along x (pixels)."""
        return {"shift_y_px": 0.0, "shift_x_px": float(value)}


class GeometryTerm(Effect):
    """A coupling geometry term: weights on the law's nearest coupling
    ``alpha(0, 0)``, so offered only where the law has one (``alpha(0, 0) >
    0``; a zero law has no coupling to weight)."""

    def offered(self, law):
        return float(law.alpha(0.0, 0.0)) > 0.0


class CouplingTerm(GeometryTerm):
    """``alpha_diag`` (``diagonal_ipc``), ``alpha_second`` (``second_neighbor_ipc``):
    the coupling fraction per neighbour at zero signal (a geometry weight
    ``alpha / alpha(0, 0)`` on the law); the one value is that coupling."""

    def couple_geometry(self, p, terms, alpha0):
        terms[self.terms[0]] = p[self.params[0].name] / alpha0

    def from_terms(self, terms, alpha0):
        w = terms[self.terms[0]]
        return {self.params[0].name: w * alpha0} if w else None

    def from_value(self, value, readnoise=None):
        return {self.params[0].name: float(value)}


class AnisotropicIPC(GeometryTerm):
    """``weight_horizontal``, ``weight_vertical``: multipliers of alpha along a
    row and along a column; reported with ``anisotropy = (h - v)/((h + v)/2)``
    (the one value: ``h = 1 + a/2``, ``v = 1 - a/2``)."""

    terms = ("horizontal", "vertical")

    def couple_geometry(self, p, terms, alpha0):
        terms["horizontal"] = p["weight_horizontal"]
        terms["vertical"] = p["weight_vertical"]

    def from_terms(self, terms, alpha0):
        h, v = terms["horizontal"], terms["vertical"]
        return None if (h, v) == (1.0, 1.0) else {"weight_horizontal": h, "weight_vertical": v}

    def from_value(self, value, readnoise=None):
        v = float(value)
        return {"weight_horizontal": 1.0 + v / 2, "weight_vertical": 1.0 - v / 2}

    def derived(self, p, uncertainties=None, cov=None, readnoise=None):
        h, v = p["weight_horizontal"], p["weight_vertical"]
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

    def signature(self, fit):
        """The anisotropy: a rescaled coupling (``h = v != 1``) is not anisotropic."""
        params, _, cov = self.own(fit)
        value, error = self.derived(params, cov=cov)
        sigma = error["anisotropy"]
        return (value["anisotropy"] / sigma) ** 2 if sigma > 0 else math.inf


class SignalDependentIPC(Effect):
    """``amp_diff``, ``amp_level``, ``alpha_floor``: the constant starting law
    becomes the donlon2018 family with its scales (``ipc_taichi.laws``) and
    these amplitudes. Offered only when the starting law is constant; the one
    value of a simulated file is a law spec (the data's law)."""

    def starting(self, law):
        return {**self.off(), "alpha_floor": float(law.floor)}

    def offered(self, law):
        return is_constant_law(law)

    def couple_law(self, p, law):
        return ParametricLaw(p["amp_diff"], LAW_SCALE_DIFF, p["amp_level"], LAW_SCALE_LEVEL,
                             p["alpha_floor"], name="fitted signal-dependent")

    def signature(self, fit):
        """The two amplitudes jointly: a constant law with a new floor is not signal-dependent."""
        idx = [fit.keys.index((self.name, "amp_diff")), fit.keys.index((self.name, "amp_level"))]
        a = np.array([fit.values[fit.keys[i]] for i in idx])
        try:
            return float(a @ np.linalg.solve(fit.cov[np.ix_(idx, idx)], a))
        except np.linalg.LinAlgError:
            return 0.0

    def parse(self, text):
        return text.strip()

    def hidden(self, value, readnoise, law):
        return None, get_law(value)


class ClassicalNonlinearity(Effect):
    """``deficit_at_50ke``, ``cubic_term``: ``f(x) = x (1 - (d - b) u - b u^2)``
    with ``u = x / 50000 e-``, after IPC (the one value: the deficit; a model
    file's ``beta``: ``M = Q - beta Q^2``, ``d = beta x 50 ke-``)."""

    position = 8.0
    section = "classical_nonlinearity"

    def response(self, p):
        p = dict(p)
        return lambda m: nonlinearity(m, p["deficit_at_50ke"], p["cubic_term"])

    def contradiction(self, p):
        if p["deficit_at_50ke"] <= 0:
            return (f"the response rises above linear (deficit at 50 ke- "
                    f"{p['deficit_at_50ke']:.4g} <= 0)")
        return None

    def from_value(self, value, readnoise=None):
        return {"deficit_at_50ke": float(value), "cubic_term": 0.0}

    def from_section(self, section, source):
        try:
            beta = float(section["beta"])
        except (TypeError, KeyError, ValueError):
            raise IPCInputError(f"{source}: classical_nonlinearity must give \"beta\" (per "
                                "electron, M = Q - beta Q^2)") from None
        params = {"deficit_at_50ke": beta * NL_REFERENCE, "cubic_term": 0.0}
        return params, {"beta": beta, "params": params}


class ReciprocityFailure(Effect):
    """``alpha_per_decade``: the collected photo-charge is ``C (C / 1 e-)^(alpha
    / ln 10)``: the response rises by ``alpha`` (a fraction) per decade of
    signal (count rate at a fixed exposure time). It acts on the arriving
    light, before anything is collected; on a sub-pixel grid, on the pixels'
    totals (the sub-pixels of a pixel scaled alike)."""

    position = 1.0

    def collect(self, charge, p):
        alpha, n, c = p["alpha_per_decade"], charge.oversample, charge.value
        if n > 1:
            total = block_sum(c, n)
            gain = np.divide(reciprocity(total, alpha), total, out=np.ones_like(total),
                             where=total > 0)
            charge.value = c * np.repeat(np.repeat(gain, n, axis=-2), n, axis=-1)
        else:
            charge.value = reciprocity(c, alpha)

    def contradiction(self, p):
        if p["alpha_per_decade"] <= 0:
            return f"the response falls with signal (alpha per decade {p['alpha_per_decade']:.4g})"
        return None

    def from_value(self, value, readnoise=None):
        return {"alpha_per_decade": float(value)}


class DiagonalIPC(CouplingTerm):
    __doc__ = CouplingTerm.__doc__
    terms = ("diagonal",)


class SecondNeighbourIPC(CouplingTerm):
    __doc__ = CouplingTerm.__doc__
    terms = ("second",)


class BrighterFatter(Effect):
    """``deflection_x_at_50ke``, ``deflection_y_at_50ke``: the fraction of newly
    arriving charge that a pixel already holding 50 ke- more than its empty
    neighbours sends across its boundaries along x (to its two row
    neighbours together) and along y (to its two column neighbours);
    ``upwind`` (0-1): which arrivals a moved boundary hands over, from the
    mean of the two pixels' (0: a flow driven by the difference of squared
    charges) to the shrinking pixel's own (1: the boundary-shift picture);
    ``reach``: how much the charge of the 4 nearest neighbours of the two
    pixels adds to the field that moves their boundary (0: only the two
    pixels' own charge; a long edge then pushes as hard as a single pixel).
    The one value: both deflections (an isolated 50 ke- pixel loses half of
    it, :func:`~.forms.brighter_fatter`); a model file's kernel through
    :func:`ipc_taichi.brighterfatter.deflection_from_kernel`. Judged by its
    kernel (:func:`ipc_taichi.brighterfatter.kernel_plausibility`), whose
    size and shape real detectors bound."""

    position = 4.0
    on_pixels = True
    needs_fine_grid = True
    section = "brighter_fatter"
    reports_section = True
    spots_aside = True
    subpixel = (
        "the boundary-shift picture moves the charge that arrives next to each pixel "
        "boundary, taken as uniform across the pixel; light concentrated inside its pixel "
        "(a pinhole spot, a star's core) arrives mostly away from the boundaries and is "
        "moved less, and SCENE does not say where it lies: what remains at hot pixels and "
        "star centres may be that limit of the data; a SCENE with OVERSAMP (the light on a "
        "sub-pixel grid) lifts it")

    def at_binning(self, charge, p):
        charge.arrivals = {axis: boundary_arrivals(charge.value, charge.oversample, axis)
                           for axis in (-1, -2)}

    def collect(self, charge, p):
        charge.value = brighter_fatter(charge.value, p["deflection_x_at_50ke"],
                                       p["deflection_y_at_50ke"], p["upwind"], p["reach"],
                                       boundary=charge.arrivals)

    def contradiction(self, p):
        dx, dy = p["deflection_x_at_50ke"], p["deflection_y_at_50ke"]
        if dx + dy <= 0 or min(dx, dy) < -0.25 * abs(dx + dy):
            return (f"collected charge would attract new charge (deflections x {dx:.4g}, "
                    f"y {dy:.4g})")
        return None

    def implausible(self, p, readnoise=None, cov=None):
        why = kernel_plausibility(*bf_kernel(p, cov))
        return f"its kernel is not a real detector's: {why}" if why else None

    def report_section(self, params, cov, source):
        return brighter_fatter_section(params, cov, source)

    def from_value(self, value, readnoise=None):
        v = float(value)
        return {"deflection_x_at_50ke": v, "deflection_y_at_50ke": v, "upwind": 0.5,
                "reach": 0.0}

    def from_section(self, section, source):
        if not isinstance(section, dict) or section.get("units", "1/electron") != "1/electron":
            raise IPCInputError(f"{source}: brighter_fatter must be an object with a 5x5 "
                                "\"kernel\" in units of 1/electron")
        kernel = section_kernel(section, "kernel", source)
        if kernel is None:
            raise IPCInputError(f"{source}: brighter_fatter has no \"kernel\"")
        converted = deflection_from_kernel(kernel, section_kernel(section, "kernel_error",
                                                                   source))
        params = {k: converted[k] for k in (
            "deflection_x_at_50ke", "deflection_y_at_50ke", "upwind", "reach")}
        return params, {"kernel": kernel.tolist(), "params": params,
                        "not_held": converted["residual"],
                        "outside_5x5": converted["outside_5x5"],
                        "unrepresented": converted["unrepresented"], "note": converted["note"]}


class ChargeDiffusion(Effect):
    """``sigma_px``: RMS (pixels) of the lateral spread of carriers generated
    uniformly across the pixel area, integrated over the collecting pixels: a
    blur of the expected charge, before shot noise. On a sub-pixel grid each
    sub-pixel's charge moves from where it is generated (a pinhole spot's
    light from its sub-pixel's centre), collected on the pixels at once
    unless a later stage needs the fine grid."""

    position = 2.0
    subpixel = (
        "the diffusion model spreads charge generated uniformly across each pixel (right "
        "for single-pixel events and flat areas); light that peaks inside its pixel (a "
        "star) keeps more of it, so where the data's diffusion starts from the photons' "
        "true positions, star centres are left above the model (sigma 0.22 px, a 1.8 px "
        "FWHM star: the model's peak 11 % low) and SCENE cannot say which picture holds "
        "for which pixel: what remains at star centres may be that limit of the data; a "
        "SCENE with OVERSAMP (the light on a sub-pixel grid) lifts it")

    def collect(self, charge, p):
        sigma, n, c = p["sigma_px"], charge.oversample, charge.value
        if n == 1:
            charge.value = diffuse(c, sigma)
            return
        points = isolated_points(c)  # a pinhole spot's light starts at its sub-pixel's centre
        m = 1 if charge.fine else n
        charge.value = diffuse(c - points, n * sigma, collect=m) + (
            diffuse(points, n * sigma, at_centre=True, collect=m) if points.any() else 0.0)
        charge.oversample = n if charge.fine else 1  # else: already on the pixels

    def from_value(self, value, readnoise=None):
        return {"sigma_px": float(value)}


class DarkCurrent(Effect):
    """``dark_e``: electrons of collected charge added to every pixel (collected
    like photo-charge, so it has shot noise and is coupled by IPC; it arrives
    uniformly, next to every boundary alike)."""

    position = 3.0
    on_pixels = True

    def collect(self, charge, p):
        d = p["dark_e"]
        charge.value = charge.value + d
        if charge.arrivals is not None:  # dark charge arrives uniformly
            charge.arrivals = {a: (lo + d, hi + d) for a, (lo, hi) in charge.arrivals.items()}

    def contradiction(self, p):
        if p["dark_e"] <= 0:
            return f"a negative collected charge ({p['dark_e']:.4g} e-)"
        return None

    def from_value(self, value, readnoise=None):
        return {"dark_e": float(value)}


class FlatField(Effect):
    """``response_variance``: variance of the per-pixel response (gain or QE)
    about 1, the same map in every pair of a file, carried as noise; reported
    also as ``response_rms`` (the one value). HgCdTe and CCD response maps
    (quantum efficiency and gain together) vary by a few per cent RMS."""

    position = 5.0
    limit = 0.05

    def response_variance(self, p):
        return p["response_variance"]

    def implausible(self, p, readnoise=None, cov=None):
        rms = math.sqrt(max(p["response_variance"], 0.0))
        if rms > self.limit:
            return (f"a response map of RMS {100 * rms:.1f} % (a real one is at most "
                    f"{100 * self.limit:g} %)")
        return None

    def derived(self, p, uncertainties=None, cov=None, readnoise=None):
        su = _variance_error(uncertainties, cov, "response_variance")
        rms = math.sqrt(max(p["response_variance"], 0.0))
        return {"response_rms": rms}, {"response_rms": su / (2 * rms) if rms > 0 else su ** 0.5}

    def refuted(self, check, trial):
        z = check.flat_interior_z()
        if z < UNEXPLAINED_Z:
            return (f"a response map, but flat areas show no variance excess ({z:+.1f} sigma): "
                    "the excess sits at sources and edges")
        return None

    def from_value(self, value, readnoise=None):
        v = float(value)
        return {"response_variance": v * v}


class ExcessReadNoise(Effect):
    """``excess_variance_e2``: read-noise variance above ``READNOIS^2``
    (electrons squared); reported also as ``readnoise_e`` (the one value: the
    true read noise). A read noise is not several times what the detector's
    own characterisation (READNOIS) says."""

    position = 10.0
    limit = 3.0

    def read_variance(self, p):
        return p["excess_variance_e2"]

    def contradiction(self, p):
        if p["excess_variance_e2"] <= 0:
            return f"less read noise than READNOIS ({p['excess_variance_e2']:.4g} e-^2)"
        return None

    def implausible(self, p, readnoise=None, cov=None):
        if readnoise:
            total = math.sqrt(max(readnoise ** 2 + p["excess_variance_e2"], 0.0))
            if total > self.limit * readnoise:
                return (f"a read noise of {total:.1f} e- ({total / readnoise:.1f} times "
                        f"READNOIS; at most {self.limit:g} times is plausible)")
        return None

    def derived(self, p, uncertainties=None, cov=None, readnoise=None):
        if readnoise is None:
            return {}, {}
        se = _variance_error(uncertainties, cov, "excess_variance_e2")
        rn = math.sqrt(max(readnoise ** 2 + p["excess_variance_e2"], 0.0))
        return {"readnoise_e": rn}, {"readnoise_e": se / (2 * rn) if rn > 0 else float("nan")}

    def noise_weight(self, var, a):
        return (1.0 / var) / var.mean()

    def from_value(self, value, readnoise=None):
        v = float(value)
        return {"excess_variance_e2": v * v - float(readnoise) ** 2}


EFFECTS = {e.name: e for e in (
    Misregistration("misregistration", "scene",
                    (Param("shift_y_px", 0.0, -1.5, 1.5, 0.01),
                     Param("shift_x_px", 0.0, -1.5, 1.5, 0.01)),
                    "SCENE and MEASURED are offset by a sub-pixel shift"),
    DiagonalIPC("diagonal_ipc", "coupling",
                (Param("alpha_diag", 0.0, 0.0, 0.02, 1e-3),),
                "coupling to the 4 diagonal neighbours"),
    AnisotropicIPC("anisotropic_ipc", "coupling",
                   (Param("weight_horizontal", 1.0, 0.2, 3.0, 0.05),
                    Param("weight_vertical", 1.0, 0.2, 3.0, 0.05)),
                   "coupling along rows differs from coupling along columns"),
    SecondNeighbourIPC("second_neighbor_ipc", "coupling",
                       (Param("alpha_second", 0.0, 0.0, 0.02, 1e-3),),
                       "coupling to pixels two steps away along a row or column"),
    SignalDependentIPC("signal_dependent_ipc", "coupling",
                       (Param("amp_diff", 0.0, -0.01, 0.05, 1e-3),
                        Param("amp_level", 0.0, -0.01, 0.05, 1e-3),
                        Param("alpha_floor", float("nan"), 0.0, 0.05, 1e-3)),  # off: starting()
                       "the coupling varies with signal"),
    ClassicalNonlinearity("classical_nonlinearity", "readout",
                          (Param("deficit_at_50ke", 0.0, -0.3, 0.5, 0.01),
                           Param("cubic_term", 0.0, -0.5, 0.5, 0.01, scan=False)),
                          "the pixel's response falls below linear as its signal grows"),
    ReciprocityFailure("reciprocity_failure", "collection",
                       (Param("alpha_per_decade", 0.0, -0.1, 0.2, 0.002),),
                       "the response rises above linear as the signal (count rate) grows"),
    BrighterFatter("brighter_fatter", "collection",
                   (Param("deflection_x_at_50ke", 0.0, -0.2, 0.3, 0.003),
                    Param("deflection_y_at_50ke", 0.0, -0.2, 0.3, 0.003),
                    # upwind and reach do nothing at zero deflection: their "off" values
                    # are the starting guesses of the field's standard picture
                    Param("upwind", 1.0, 0.0, 1.0, 0.05, scan=False),
                    Param("reach", 0.5, -0.5, 1.0, 0.05, scan=False)),
                   "charge already collected pushes new charge into neighbours"),
    ChargeDiffusion("charge_diffusion", "collection",
                    (Param("sigma_px", 0.0, 0.0, 1.5, 0.02),),
                    "carriers spread to neighbours before collection (blur before shot noise)"),
    DarkCurrent("dark_current", "collection",
                (Param("dark_e", 0.0, -1e4, 1e6, 1.0),),
                "a spatially uniform additive collected charge"),
    FlatField("flat_field", "variance",
              (Param("response_variance", 0.0, 0.0, 0.01, 1e-5),),
              "pixel-to-pixel response variation, fixed per pixel across the pairs"),
    ExcessReadNoise("excess_read_noise", "variance",
                    (Param("excess_variance_e2", 0.0, -1e4, 1e5, 1.0),),
                    "the read noise is larger than READNOIS says"),
)}

EFFECT_NAMES = tuple(EFFECTS)  # the vocabulary as shipped (EFFECTS also holds registered ones)


def register(effect):
    """Add ``effect`` (an :class:`Effect`) to :data:`EFFECTS`; returns a callable
    that takes it out again (a test's toy effect, a lab's own)."""
    if effect.name in EFFECTS:
        raise ValueError(f"effect {effect.name!r} is already in the vocabulary")
    EFFECTS[effect.name] = effect
    return lambda: EFFECTS.pop(effect.name, None)


def chain_order():
    """The detector chain: the effects with a :attr:`Effect.position` and the
    stages that are not effects (:data:`CHAIN_STAGES`), in order."""
    places = [(e.position, e.name) for e in EFFECTS.values() if e.position is not None]
    return tuple(name for _, name in sorted(places + [(p, s) for s, p in CHAIN_STAGES]))


def physical_limits():
    """``{effect: largest strength a real detector shows}`` (beyond it a fit
    absorbs something else; :attr:`Effect.limit`)."""
    return {e.name: e.limit for e in EFFECTS.values() if e.limit is not None}


PHYSICAL_LIMITS = physical_limits()  # as shipped; brighter-fatter is judged by its kernel


def contradiction(effect, params):
    """Why fitted ``params`` contradict the meaning of ``effect`` (``None`` if they do not).

    Such a fit is not reported under the effect's name: a non-linearity that
    rises above linear is not a non-linearity.
    """
    return EFFECTS[effect].contradiction(params)


def implausible(effect, params, readnoise=None, cov=None):
    """Why fitted ``params`` lie outside the physical range of ``effect`` (for
    ``excess_read_noise`` a multiple of the header's ``readnoise``; for
    ``brighter_fatter`` its kernel, with ``cov`` the parameters' covariance for
    its errors), or ``None``. Such a fit is not named: its strength or shape
    says it absorbs a misfit of another kind."""
    return EFFECTS[effect].implausible(params, readnoise, cov)


def derived_params(effect, params, uncertainties=None, cov=None, readnoise=None):
    """Extra reported quantities (and their uncertainties) derived from the fit."""
    return EFFECTS[effect].derived(params, uncertainties, cov, readnoise)

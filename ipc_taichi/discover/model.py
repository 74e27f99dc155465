"""A composable detector model: an ordered chain of named effects.

The chain, applied to a SCENE (the expected charge, electrons)
----------------------------------------------------------------
0. **misregistration** -- SCENE displaced by a sub-pixel shift: a data
   problem, not a detector effect, so it comes before everything else (and
   the search fits it first: every effect downstream sees its dipoles).
1. **reciprocity_failure** -- the photo-charge collected depends on the
   count rate: it acts on the arriving light, before anything is collected.
2. **charge_diffusion** -- carriers generated across the pixel area spread
   before they are collected: a blur of the expected charge, before shot noise.
3. **dark_current** -- charge generated in the pixel itself: added to the
   expected collected charge (collected like photo-charge, so it has shot
   noise and is coupled by IPC).
4. **brighter_fatter** -- charge already collected moves the pixel
   boundaries: it redistributes the *arriving* charge, so it belongs to
   collection, after 1-3 and before shot noise.
5. **flat_field** -- a fixed per-pixel response (QE or gain) about 1: the
   same map in every pair of a file. Its map is unknown, so the model
   carries it as noise: a variance ``u sum_q J_pq^2 C_q^2`` per pixel
   (the map's noise coupled by IPC), correlated across the pairs
   (:mod:`ipc_taichi.discover.search` uses the exact correlated
   likelihood); a simulation draws one map per file.
6. **shot noise** -- Poisson noise of the collected charge (``SHOTNOIS``).
7. **IPC** -- capacitive coupling between the pixel nodes acts on the
   charge that sits on them (collected charge, noise included): the shared
   chain ``ipc_taichi.detector`` (``collect``, ``read_out``, ``read_noise``)
   with the law (``IPCLAW``, or a fitted
   signal-dependent law) and the geometry terms (anisotropic, diagonal,
   second neighbour).
8. **classical_nonlinearity** -- after IPC. The non-linearity is the node's
   voltage response to what is on it; what the read-out sees on a node
   already includes the coupled contribution of its neighbours. (Peers
   apply it before IPC; the two orders differ by terms of order alpha x
   deficit, about 0.03 % of a neighbour's signal for alpha = 1 % and a 3 %
   deficit, below the noise of any frame here.)
9. **read noise** -- Gaussian, ``READNOIS`` electrons RMS, plus
   ``excess_read_noise`` (a variance) when it is in the model.

Prediction
----------
:meth:`DetectorModel.predict` returns the expected value and variance per
pixel. The expected collected charge ``C`` comes from steps 0-5; the mean is
``g(C)`` with ``g`` the read-out chain (steps 7-8). The variance propagates
the Poisson variance of ``C`` through ``g`` to first order,
``Var M_p = sum_q J_pq^2 C_q + read variance (+ u sum_q J_pq^2 C_q^2)`` with
``J = dg/dC`` the exact Jacobian of the (non-linear, signal-dependent)
read-out chain; ``J`` is obtained colour by colour from one evaluation of
``g`` each, perturbing pixels far enough apart that their footprints do not
overlap.
"""

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..brighterfatter import deflection_from_kernel
from ..detector import collect, read_noise, read_out
from ..errors import GeometryError, IPCInputError
from ..geometry import Geometry
from ..laws import ParametricLaw, get_law
from ..model import CouplingModel
from .effects import (
    EFFECTS,
    LAW_SCALE_DIFF,
    LAW_SCALE_LEVEL,
    NL_REFERENCE,
    brighter_fatter,
    diffuse,
    nonlinearity,
    reciprocity,
    shift_scene,
)
from .sampling import block_sum, boundary_arrivals, isolated_points, shift_fine

__all__ = ["DetectorModel", "CHAIN_ORDER", "SUBPIXEL_EFFECTS", "WITHIN_PIXEL", "is_constant_law",
           "effects_from_document"]

CHAIN_ORDER = ("misregistration", "reciprocity_failure", "charge_diffusion", "dark_current",
               "brighter_fatter", "flat_field", "shot_noise", "ipc", "classical_nonlinearity",
               "read_noise", "excess_read_noise")

# the effects that move charge by a fraction of a pixel: they use a sub-pixel
# SCENE when there is one (every other stage works on the pixels' totals)
SUBPIXEL_EFFECTS = frozenset({"misregistration", "charge_diffusion", "brighter_fatter"})

# How a pixel-total SCENE's light is taken to lie within each pixel, where
# the operators need it (``within_pixel``): "smooth" across pixels (sources
# imaged through optics; the spline shift), or "uniform" within each pixel
# (single-pixel spots, sharp edges; the linear shift, exact for them). The
# diffusion and brighter-fatter of pixel totals take the light as uniform in
# both; an OVERSAMP SCENE says where the light lies and ignores this.
WITHIN_PIXEL = ("smooth", "uniform")


def is_constant_law(law):
    """True for a signal-independent law (``constant:A``)."""
    return (getattr(law, "kind", "") == "parametric" and law.amp_diff == 0.0
            and law.amp_level == 0.0)


def _section_kernel(section, key, source):
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


def effects_from_document(document, source="model file"):
    """The detector effects a coupling-model file's measured sections amount to.

    ``brighter_fatter`` (a kernel ``a``, per electron, ``pixel area 1 + sum_d
    a(d) Q(p+d)``) becomes discover's boundary-shift parameters through
    :func:`ipc_taichi.brighterfatter.deflection_from_kernel`, the kernel's
    errors weighting its terms; ``classical_nonlinearity`` (``M = Q - beta
    Q^2``) becomes ``deficit_at_50ke = beta x 50 ke-`` with no cubic term.

    Returns
    -------
    (dict, dict)
        ``{effect: params}`` and ``{effect: what was converted}`` for the
        report (the section's values, the parameters, and for the kernel what
        the boundary picture could not hold). Both empty without sections.

    Raises
    ------
    IPCInputError
        A section that is not what calibrate writes (one line naming ``source``).
    """
    effects, notes = {}, {}
    section = (document or {}).get("brighter_fatter")
    if section is not None:
        if not isinstance(section, dict) or section.get("units", "1/electron") != "1/electron":
            raise IPCInputError(f"{source}: brighter_fatter must be an object with a 5x5 "
                                "\"kernel\" in units of 1/electron")
        kernel = _section_kernel(section, "kernel", source)
        if kernel is None:
            raise IPCInputError(f"{source}: brighter_fatter has no \"kernel\"")
        converted = deflection_from_kernel(kernel, _section_kernel(section, "kernel_error",
                                                                   source))
        effects["brighter_fatter"] = {k: converted[k] for k in (
            "deflection_x_at_50ke", "deflection_y_at_50ke", "upwind", "reach")}
        notes["brighter_fatter"] = {"kernel": kernel.tolist(), "params": effects[
            "brighter_fatter"], "not_held": converted["residual"],
            "outside_5x5": converted["outside_5x5"],
            "unrepresented": converted["unrepresented"], "note": converted["note"]}
    section = (document or {}).get("classical_nonlinearity")
    if section is not None:
        try:
            beta = float(section["beta"])
        except (TypeError, KeyError, ValueError):
            raise IPCInputError(f"{source}: classical_nonlinearity must give \"beta\" (per "
                                "electron, M = Q - beta Q^2)") from None
        effects["classical_nonlinearity"] = {"deficit_at_50ke": beta * NL_REFERENCE,
                                             "cubic_term": 0.0}
        notes["classical_nonlinearity"] = {"beta": beta,
                                           "params": effects["classical_nonlinearity"]}
    return effects, notes


def _colouring(offsets):
    """``(period, slope)`` such that pixels with equal ``(x + slope*y) mod period``
    have disjoint footprints ``p + D`` (``D`` = offsets, their negatives, 0)."""
    d = {(0, 0)} | set(offsets) | {(-a, -b) for a, b in offsets}
    diff = {(a1 - a2, b1 - b2) for a1, b1 in d for a2, b2 in d} - {(0, 0)}
    for period in range(len(d), 64):
        for slope in range(period):
            if all((dx + slope * dy) % period for dy, dx in diff):
                return period, slope
    raise AssertionError("no colouring found")  # cannot happen for reach <= 2


@dataclass(frozen=True)
class DetectorModel:
    """The detector chain with its parameters (see the module docstring).

    Parameters
    ----------
    law : str or law object
        The starting IPC law (``IPCLAW``), e.g. ``"donlon2018"`` or ``"constant:0.0125"``.
    readnoise : float
        Read noise, electrons RMS.
    shot_noise : bool
        Whether the measured frame has Poisson noise of the collected charge.
    effects : dict
        ``{effect name: {parameter: value}}`` of the effects switched on.
    edge : str
        The coupling's frame-edge rule.
    within_pixel : str
        How a pixel-total SCENE's light lies within each pixel for the shift
        (:data:`WITHIN_PIXEL`): ``"smooth"`` (the default) or ``"uniform"``.
    """

    law: object
    readnoise: float
    shot_noise: bool = True
    effects: dict = field(default_factory=dict)
    edge: str = "zero"
    within_pixel: str = "smooth"

    def __post_init__(self):
        object.__setattr__(self, "law", get_law(self.law))
        if self.within_pixel not in WITHIN_PIXEL:
            raise ValueError(f"within_pixel {self.within_pixel!r}; known: "
                             f"{', '.join(WITHIN_PIXEL)}")
        unknown = set(self.effects) - set(EFFECTS)
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}; known: {', '.join(EFFECTS)}")

    # -- building ---------------------------------------------------------
    @classmethod
    def from_coupling(cls, coupling, readnoise, shot_noise=True, document=None):
        """The starting model of a :class:`~ipc_taichi.model.CouplingModel`
        (a coupling-model file): its law and edge, and its geometry as the
        coupling effects it amounts to (``anisotropic_ipc``, ``diagonal_ipc``,
        ``second_neighbor_ipc``, with absolute couplings at zero signal).
        With the file's ``document`` (:meth:`~ipc_taichi.model.CouplingModel.load`
        with ``with_document``), its measured ``brighter_fatter`` and
        ``classical_nonlinearity`` sections join as those effects
        (:func:`effects_from_document`).

        Raises :class:`~ipc_taichi.errors.GeometryError` for a geometry that is
        not of that symmetric form, :class:`~ipc_taichi.errors.IPCInputError`
        for a section that is not what calibrate writes.
        """
        g = coupling.geometry
        h, v = g.weight(0, 1), g.weight(1, 0)
        diag, second = g.weight(1, 1), g.weight(0, 2)
        if Geometry.terms(h, v, diag, second).weights != g.weights:
            raise GeometryError("the coupling model's geometry is not symmetric nearest, "
                                "diagonal and second-neighbour terms (second neighbours "
                                "equal along x and y): discover cannot start from it")
        alpha0 = float(coupling.law.alpha(0.0, 0.0))
        effects = {}
        if (h, v) != (1.0, 1.0):
            effects["anisotropic_ipc"] = {"weight_horizontal": h, "weight_vertical": v}
        if diag:
            effects["diagonal_ipc"] = {"alpha_diag": diag * alpha0}
        if second:
            effects["second_neighbor_ipc"] = {"alpha_second": second * alpha0}
        effects.update(effects_from_document(document)[0])
        return cls(coupling.law, readnoise, shot_noise, effects, coupling.edge)

    def with_effects(self, effects):
        """A copy with these ``{name: params}`` replacing or adding to the current ones."""
        merged = {k: dict(v) for k, v in self.effects.items()}
        for k, v in effects.items():
            merged[k] = dict(v)
        return replace(self, effects=merged)

    def starting_params(self, name):
        """The parameter values that switch effect ``name`` on at zero strength."""
        params = EFFECTS[name].off()
        if name == "signal_dependent_ipc":
            params["alpha_floor"] = float(self.law.floor)
        return params

    def _p(self, name, key):
        return self.effects[name][key]

    # -- the coupling stage -----------------------------------------------
    def ipc_law(self):
        """The law in use: the starting law, or the fitted signal-dependent one."""
        if "signal_dependent_ipc" in self.effects:
            p = self.effects["signal_dependent_ipc"]
            return ParametricLaw(p["amp_diff"], LAW_SCALE_DIFF, p["amp_level"], LAW_SCALE_LEVEL,
                                 p["alpha_floor"], name="fitted signal-dependent")
        return self.law

    def geometry(self, law=None):
        """Geometry terms; absolute couplings are converted with the law's alpha(0, 0)."""
        law = law or self.ipc_law()
        alpha0 = float(law.alpha(0.0, 0.0))
        h = v = 1.0
        if "anisotropic_ipc" in self.effects:
            h = self._p("anisotropic_ipc", "weight_horizontal")
            v = self._p("anisotropic_ipc", "weight_vertical")
        diag = second = 0.0
        if "diagonal_ipc" in self.effects:
            diag = self._p("diagonal_ipc", "alpha_diag") / alpha0
        if "second_neighbor_ipc" in self.effects:
            second = self._p("second_neighbor_ipc", "alpha_second") / alpha0
        return Geometry.terms(horizontal=h, vertical=v, diagonal=diag, second=second)

    # -- the chain ----------------------------------------------------------
    def collected(self, scene, oversample=1):
        """Expected collected charge (steps 0-4) from the expected scene charge.

        With ``oversample = N > 1`` the scene is on the sub-pixel grid of
        :mod:`.sampling` (shape ``N`` times the pixels'): the shift and the
        diffusion act there (each sub-pixel's charge moved from where it is
        generated, then integrated over the collecting pixels), and
        brighter-fatter takes the charge arriving next to each boundary from
        it; reciprocity failure acts on the pixels' totals (the sub-pixels
        of a pixel scaled alike). The result is on the pixel grid.
        """
        n = int(oversample)
        c = np.asarray(scene, dtype=np.float64)
        if "misregistration" in self.effects:
            p = self.effects["misregistration"]
            if n > 1 or self.within_pixel == "uniform":  # exact for light uniform in a cell
                c = shift_fine(c, n * p["shift_y_px"], n * p["shift_x_px"])
            else:  # the spline undershoots next to sharp features: no negative charge
                c = np.clip(shift_scene(c, p["shift_y_px"], p["shift_x_px"]), 0.0, None)
        if "reciprocity_failure" in self.effects:
            alpha = self._p("reciprocity_failure", "alpha_per_decade")
            if n > 1:
                total = block_sum(c, n)
                gain = np.divide(reciprocity(total, alpha), total, out=np.ones_like(total),
                                 where=total > 0)
                c = c * np.repeat(np.repeat(gain, n, axis=-2), n, axis=-1)
            else:
                c = reciprocity(c, alpha)
        bf = "brighter_fatter" in self.effects
        if "charge_diffusion" in self.effects:
            sigma = self._p("charge_diffusion", "sigma_px")
            if n > 1:  # a pinhole spot's light starts at its sub-pixel's centre
                points = isolated_points(c)
                # collected on the pixels at once, unless brighter-fatter needs the fine grid
                m = 1 if bf else n
                c = diffuse(c - points, n * sigma, collect=m) + (
                    diffuse(points, n * sigma, at_centre=True, collect=m) if points.any()
                    else 0.0)
                n = n if bf else 1  # without brighter-fatter: already on the pixels
            else:
                c = diffuse(c, sigma)
        arrivals = None
        if n > 1:
            if bf:
                arrivals = {axis: boundary_arrivals(c, n, axis) for axis in (-1, -2)}
            c = block_sum(c, n)
        if "dark_current" in self.effects:
            c = c + self._p("dark_current", "dark_e")
        if "brighter_fatter" in self.effects:
            p = self.effects["brighter_fatter"]
            if arrivals is not None and "dark_current" in self.effects:
                d = self._p("dark_current", "dark_e")  # dark charge arrives uniformly
                arrivals = {a: (lo + d, hi + d) for a, (lo, hi) in arrivals.items()}
            c = brighter_fatter(c, p["deflection_x_at_50ke"], p["deflection_y_at_50ke"],
                                p["upwind"], p["reach"], boundary=arrivals)
        return c

    def readout(self, signal):
        """The node chain after collection (steps 7-8), without read noise."""
        return read_out(signal, self.coupling_model(), self._response())

    def coupling_model(self):
        """The :class:`~ipc_taichi.model.CouplingModel` of the coupling stage."""
        law = self.ipc_law()
        return CouplingModel.resolve(law, self.geometry(law), self.edge)

    def _response(self):
        """The read-out response after IPC (``classical_nonlinearity``), or ``None``."""
        if "classical_nonlinearity" not in self.effects:
            return None
        p = dict(self.effects["classical_nonlinearity"])
        return lambda m: nonlinearity(m, p["deficit_at_50ke"], p["cubic_term"])

    def expected(self, scene, oversample=1):
        """Expected measured frame (``oversample``: see :meth:`collected`)."""
        return self.readout(self.collected(scene, oversample))

    def response_variance(self):
        """Variance of the per-pixel response (``flat_field``), 0 when absent."""
        return float(self.effects.get("flat_field", {}).get("response_variance", 0.0))

    def read_variance(self):
        """Read-noise variance: ``READNOIS^2`` plus ``excess_read_noise`` (kept positive)."""
        extra = float(self.effects.get("excess_read_noise", {}).get("excess_variance_e2", 0.0))
        return max(float(self.readnoise) ** 2 + extra, 1e-6)

    def predict_parts(self, scene, oversample=1):
        """``(mean, independent variance, response scale)`` on the pixel grid
        (``oversample``: see :meth:`collected`).

        The independent variance is shot and read noise. The response map
        (``flat_field``) multiplies the collected charge, so a map of
        variance ``u`` adds ``u a^2`` with ``a^2 = sum_q J_pq^2 C_q^2``: the
        map's noise is coupled (and smoothed) by IPC like any charge. It is
        shared by every pair of a file, so it is kept apart (see the module
        docstring).
        """
        c = self.collected(scene, oversample)
        mean = self.readout(c)
        var = np.full(mean.shape, self.read_variance())
        shot, scale2 = self._propagated_variances(c, mean)
        if self.shot_noise:
            var = var + shot
        return mean, var, np.sqrt(scale2)

    def predict(self, scene, oversample=1):
        """Expected value and variance per pixel, ``(mean, variance)``."""
        mean, var, a = self.predict_parts(scene, oversample)
        u = self.response_variance()
        return mean, (var + u * a * a if u > 0 else var)

    def _propagated_variances(self, c, mean, step=1e-3):
        """``(sum_q J_pq^2 C_q, sum_q J_pq^2 C_q^2)`` with ``J`` the Jacobian of
        :meth:`readout` at ``C``.

        Pixels of one colour are perturbed together by ``step * C_q``; their
        footprints do not overlap, so each output pixel ``p`` sees exactly one
        perturbed source ``q`` and ``dM_p / step = J_pq C_q``. Squared, that
        is the second sum; divided by ``C_q`` (the source's charge spread
        over its footprint), the first.
        """
        offsets = [o for o, _ in self.geometry().weights]
        footprint = {(0, 0)} | set(offsets) | {(-a, -b) for a, b in offsets}
        period, slope = _colouring(offsets)
        ny, nx = c.shape[-2:]
        colour = (np.arange(nx)[None, :] + slope * np.arange(ny)[:, None]) % period
        cc = np.clip(c, 0.0, None)
        shot = np.zeros_like(mean)
        scale2 = np.zeros_like(mean)
        for k in range(period):
            src = np.where(colour == k, cc, 0.0)
            dm = (self.readout(c + step * src) - mean) / step  # J_pq C_q
            spread = np.zeros_like(src)
            for dy, dx in footprint:  # C_q at every pixel of q's footprint
                spread[..., max(dy, 0):ny + min(dy, 0), max(dx, 0):nx + min(dx, 0)] += \
                    src[..., max(-dy, 0):ny + min(-dy, 0), max(-dx, 0):nx + min(-dx, 0)]
            scale2 += dm * dm
            shot += np.where(spread > 0, dm * dm / np.where(spread > 0, spread, 1.0), 0.0)
        return shot, scale2

    def simulate(self, scene, rng, oversample=1):
        """A noisy measured frame (seeded ``numpy.random.Generator``).

        A 3-D ``scene`` is a stack of pairs of one file: they share one
        response map (``flat_field``), as the pairs of a file share pixels.
        ``oversample``: see :meth:`collected`.
        """
        c = self.collected(scene, oversample)
        u = self.response_variance()
        if u > 0:
            c = c * (1.0 + math.sqrt(u) * rng.standard_normal(c.shape[-2:]))
        c = collect(c, rng if self.shot_noise else None)
        return self.readout(c) + read_noise(c.shape, math.sqrt(self.read_variance()), rng)

    def describe(self):
        """One line: law, read noise and the effects with their parameters."""
        parts = [f"law {self.law.name}", f"read noise {self.readnoise:g} e-",
                 f"shot noise {'on' if self.shot_noise else 'off'}"]
        for name, p in self.effects.items():
            parts.append(name + "(" + ", ".join(f"{k}={v:.4g}" for k, v in p.items()) + ")")
        return "; ".join(parts)

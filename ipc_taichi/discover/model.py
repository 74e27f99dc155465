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

from ..detector import collect, read_noise, read_out
from ..errors import GeometryError
from ..geometry import Geometry
from ..laws import get_law
from ..model import SECTIONS, CouplingModel
from .effects import EFFECTS, chain_order, is_constant_law
from .record import GEOMETRY_TERMS, Charge
from .sampling import block_sum

__all__ = ["DetectorModel", "CHAIN_ORDER", "SUBPIXEL_EFFECTS", "WITHIN_PIXEL", "is_constant_law",
           "effects_from_document", "noise_terms"]

CHAIN_ORDER = chain_order()  # the shipped vocabulary's; the report asks chain_order()

# the effects that move charge by a fraction of a pixel: they use a sub-pixel
# SCENE when there is one (every other stage works on the pixels' totals)
SUBPIXEL_EFFECTS = frozenset(e.name for e in EFFECTS.values() if e.subpixel)

# How a pixel-total SCENE's light is taken to lie within each pixel, where
# the operators need it (``within_pixel``): "smooth" across pixels (sources
# imaged through optics; the spline shift), or "uniform" within each pixel
# (single-pixel spots, sharp edges; the linear shift, exact for them). The
# diffusion and brighter-fatter of pixel totals take the light as uniform in
# both; an OVERSAMP SCENE says where the light lies and ignores this.
WITHIN_PIXEL = ("smooth", "uniform")


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
    records = {e.section: e for e in EFFECTS.values() if e.section}
    for key in SECTIONS:  # the file's sections in the format's order
        section = (document or {}).get(key)
        if key in records and section is not None:
            name = records[key].name
            effects[name], notes[name] = records[key].from_section(section, source)
    return effects, notes


def noise_terms(effects):
    """``(response variance, extra read variance)`` of ``{effect: params}``: the
    variance effects' :meth:`~.record.Effect.response_variance` and
    :meth:`~.record.Effect.read_variance`, summed."""
    u = extra = 0.0
    for name, p in effects.items():
        u += EFFECTS[name].response_variance(p)
        extra += EFFECTS[name].read_variance(p)
    return float(u), float(extra)


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
        terms = dict(zip(GEOMETRY_TERMS, (h, v, diag, second)))
        effects = {}
        for e in sorted((e for e in EFFECTS.values() if e.terms),  # the geometry's order
                        key=lambda e: GEOMETRY_TERMS.index(e.terms[0])):
            params = e.from_terms(terms, alpha0)
            if params is not None:
                effects[e.name] = params
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
        return EFFECTS[name].starting(self.law)

    def _at(self, *stages):
        """``[(record, params)]`` of the model's effects in these stages, in chain order."""
        found = [(EFFECTS[n], p) for n, p in self.effects.items() if EFFECTS[n].stage in stages]
        return sorted(found, key=lambda rp: -1.0 if rp[0].position is None else rp[0].position)

    # -- the coupling stage -----------------------------------------------
    def ipc_law(self):
        """The law in use: the starting law, or the one the coupling effects make of it."""
        law = self.law
        for record, p in self._at("coupling"):
            law = record.couple_law(p, law)
        return law

    def geometry(self, law=None):
        """Geometry terms; absolute couplings are converted with the law's alpha(0, 0)."""
        law = law or self.ipc_law()
        alpha0 = float(law.alpha(0.0, 0.0))
        terms = {"horizontal": 1.0, "vertical": 1.0, "diagonal": 0.0, "second": 0.0}
        for record, p in self._at("coupling"):
            record.couple_geometry(p, terms, alpha0)
        return Geometry.terms(**terms)

    # -- the chain ----------------------------------------------------------
    def collected(self, scene, oversample=1):
        """Expected collected charge (steps 0-4) from the expected scene charge.

        With ``oversample = N > 1`` the scene is on the sub-pixel grid of
        :mod:`.sampling` (shape ``N`` times the pixels'): the effects act
        there (:meth:`~.record.Effect.collect`) until the first that collects
        on the pixels' totals (:attr:`~.record.Effect.on_pixels`), before which
        the grid is summed to the pixels, each effect first taking what it
        needs from it (:meth:`~.record.Effect.at_binning`). The result is on
        the pixel grid.
        """
        chain = self._at("scene", "collection")
        charge = Charge(np.asarray(scene, dtype=np.float64), int(oversample), self.within_pixel,
                        fine=any(record.needs_fine_grid for record, _ in chain))
        binned = False
        for record, p in chain:
            if record.on_pixels and not binned:
                self._bin(charge, chain)
                binned = True
            record.collect(charge, p)
        if not binned:
            self._bin(charge, chain)
        return charge.value

    @staticmethod
    def _bin(charge, chain):
        """Sum the sub-pixel grid to the pixels (after each effect's :meth:`at_binning`)."""
        if charge.oversample > 1:
            for record, p in chain:
                record.at_binning(charge, p)
            charge.value = block_sum(charge.value, charge.oversample)
            charge.oversample = 1

    def readout(self, signal):
        """The node chain after collection (steps 7-8), without read noise."""
        return read_out(signal, self.coupling_model(), self._response())

    def coupling_model(self):
        """The :class:`~ipc_taichi.model.CouplingModel` of the coupling stage."""
        law = self.ipc_law()
        return CouplingModel.resolve(law, self.geometry(law), self.edge)

    def _response(self):
        """The read-out response after IPC (the readout effects'), or ``None``."""
        responses = [record.response(p) for record, p in self._at("readout")]
        responses = [f for f in responses if f is not None]
        if len(responses) <= 1:
            return responses[0] if responses else None
        def chained(m):
            for f in responses:
                m = f(m)
            return m
        return chained

    def expected(self, scene, oversample=1):
        """Expected measured frame (``oversample``: see :meth:`collected`)."""
        return self.readout(self.collected(scene, oversample))

    def response_variance(self):
        """Variance of the per-pixel response (``flat_field``), 0 when absent."""
        return noise_terms(self.effects)[0]

    def read_variance(self):
        """Read-noise variance: ``READNOIS^2`` plus ``excess_read_noise`` (kept positive)."""
        return max(float(self.readnoise) ** 2 + noise_terms(self.effects)[1], 1e-6)

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

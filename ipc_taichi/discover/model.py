"""A composable detector model: an ordered chain of named effects.

The chain, applied to a SCENE (the expected charge, electrons)
----------------------------------------------------------------
1. **charge_diffusion** -- arriving carriers spread before they are
   collected: a blur of the expected charge. It acts on photo-charge on its
   way to the junction, so it comes first and before shot noise.
2. **dark_current** -- charge generated in the pixel itself: added to the
   expected collected charge (it is collected like photo-charge, so it has
   shot noise and is coupled by IPC).
3. **brighter_fatter** -- charge already collected repels new charge into
   the neighbours: it redistributes the *arriving* charge, so it belongs to
   collection, after diffusion and dark current and before shot noise.
4. **shot noise** -- Poisson noise of the collected charge (``SHOTNOIS``).
5. **IPC** -- capacitive coupling between the pixel nodes acts on the
   charge that sits on them (collected charge, noise included): the core
   engine, ``ipc_taichi.couple`` with the law (``IPCLAW``, or a fitted
   signal-dependent law) and the geometry terms (anisotropic, diagonal,
   second neighbour).
6. **classical_nonlinearity** -- after IPC. The non-linearity is the node's
   voltage response to what is on it (the node capacitance changes with
   its bias); what the read-out sees on a node already includes the coupled
   contribution of its neighbours, so the response curve applies to the
   coupled signal. (Peers apply it before IPC; the two orders differ by
   terms of order alpha x deficit, about 0.03 % of a neighbour's signal for
   alpha = 1 % and a 3 % deficit, below the noise of any frame here.)
7. **read noise** -- Gaussian, ``READNOIS`` electrons RMS, added last.

Prediction
----------
:meth:`DetectorModel.predict` returns the expected value and variance per
pixel. The expected collected charge ``C`` comes from steps 1-3; the mean is
``g(C)`` with ``g`` the read-out chain (steps 5-6). The variance propagates
the Poisson variance of ``C`` through ``g`` to first order,
``Var M_p = sum_q J_pq^2 C_q + READNOIS^2`` with ``J = dg/dC`` the exact
Jacobian of the (non-linear, signal-dependent) read-out chain; ``J`` is
obtained column-colour by column-colour from a few evaluations of ``g``,
perturbing pixels far enough apart that their footprints do not overlap.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from ..coupling import couple
from ..geometry import Geometry
from ..laws import ParametricLaw, get_law
from .effects import (EFFECTS, LAW_SCALE_DIFF, LAW_SCALE_LEVEL, brighter_fatter, diffuse,
                      nonlinearity)

__all__ = ["DetectorModel", "CHAIN_ORDER", "is_constant_law"]

CHAIN_ORDER = ("charge_diffusion", "dark_current", "brighter_fatter", "shot_noise", "ipc",
               "classical_nonlinearity", "read_noise")


def is_constant_law(law):
    """True for a signal-independent law (``constant:A``)."""
    return (getattr(law, "kind", "") == "parametric" and law.amp_diff == 0.0
            and law.amp_level == 0.0)


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
    """

    law: object
    readnoise: float
    shot_noise: bool = True
    effects: dict = field(default_factory=dict)
    edge: str = "zero"

    def __post_init__(self):
        object.__setattr__(self, "law", get_law(self.law))
        unknown = set(self.effects) - set(EFFECTS)
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}; known: {', '.join(EFFECTS)}")

    # -- building ---------------------------------------------------------
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
    def collected(self, scene):
        """Expected collected charge (steps 1-3) from the expected scene charge."""
        c = np.asarray(scene, dtype=np.float64)
        if "charge_diffusion" in self.effects:
            c = diffuse(c, self._p("charge_diffusion", "sigma_px"))
        if "dark_current" in self.effects:
            c = c + self._p("dark_current", "dark_e")
        if "brighter_fatter" in self.effects:
            c = brighter_fatter(c, self._p("brighter_fatter", "deflection_at_50ke"))
        return c

    def readout(self, signal):
        """The node chain after collection (steps 5-6), without read noise."""
        law = self.ipc_law()
        m = np.asarray(couple(signal, law=law, geometry=self.geometry(law), edge=self.edge),
                       dtype=np.float64)
        if "classical_nonlinearity" in self.effects:
            p = self.effects["classical_nonlinearity"]
            m = nonlinearity(m, p["deficit_at_50ke"], p["cubic_term"])
        return m

    def expected(self, scene):
        """Expected measured frame."""
        return self.readout(self.collected(scene))

    def predict(self, scene):
        """Expected value and variance per pixel, ``(mean, variance)``."""
        c = self.collected(scene)
        mean = self.readout(c)
        var = np.full(mean.shape, float(self.readnoise) ** 2)
        if self.shot_noise:
            var = var + self._propagated_shot_variance(c, mean)
        return mean, var

    def _propagated_shot_variance(self, c, mean, step=0.1):
        """``sum_q J_pq^2 C_q`` with ``J`` the Jacobian of :meth:`readout` at ``C``.

        Pixels of one colour are perturbed together by ``step * sqrt(C_q)``;
        their footprints do not overlap, so each output pixel sees exactly one
        perturbed source and ``(dM_p / step)^2 = J_pq^2 C_q``.
        """
        offsets = [o for o, _ in self.geometry().weights]
        period, slope = _colouring(offsets)
        ny, nx = c.shape[-2:]
        colour = (np.arange(nx)[None, :] + slope * np.arange(ny)[:, None]) % period
        amp = step * np.sqrt(np.clip(c, 0.0, None))
        var = np.zeros_like(mean)
        for k in range(period):
            dm = self.readout(c + np.where(colour == k, amp, 0.0)) - mean
            var += (dm / step) ** 2
        return var

    def simulate(self, scene, rng):
        """A noisy measured frame (seeded ``numpy.random.Generator``)."""
        c = self.collected(scene)
        if self.shot_noise:
            c = rng.poisson(np.clip(c, 0.0, None)).astype(np.float64)
        m = self.readout(c)
        return m + rng.normal(0.0, float(self.readnoise), m.shape)

    def describe(self):
        """One line: law, read noise and the effects with their parameters."""
        parts = [f"law {self.law.name}", f"read noise {self.readnoise:g} e-",
                 f"shot noise {'on' if self.shot_noise else 'off'}"]
        for name, p in self.effects.items():
            parts.append(name + "(" + ", ".join(f"{k}={v:.4g}" for k, v in p.items()) + ")")
        return "; ".join(parts)

"""What a detector effect of the discrepancy workflow is: a record
(:class:`Effect`) that owns everything the model and the search do with it.

An effect has a name (the names of ``docs/discovery_format.md``), a stage of
the detector chain (see :mod:`ipc_taichi.discover.model` for the order and
why), a few parameters (:class:`Param`: the value that means "off", bounds
and a typical scale) and what the effect does, as methods the model and the
search call without knowing which effect they hold: its forward application
(:meth:`Effect.collect`, :meth:`Effect.couple_law`,
:meth:`Effect.couple_geometry`, :meth:`Effect.response`, the variances), its
contradiction tests (:meth:`Effect.contradiction`, :meth:`Effect.refuted`),
its physical range (:meth:`Effect.implausible`) and its parameter
conversions (from a ``--effect NAME=VALUE`` value, a coupling-model file's
section, the starting geometry). The base class does nothing: a record
overrides what its effect does. The records of the frame vocabulary are
:mod:`.effects` (``docs/discover.md``, "Adding an effect", adds one); the
ramp vocabulary's, :mod:`.ramp_effects`, are records of this kind with their
own fit (:class:`~.ramp_effects.RampEffect`).

Every parameter enters the model smoothly through its "off" value with a
non-zero first derivative there (no form is flat at zero), and the bounds
allow the sign that contradicts the effect's meaning wherever a fit might
need it: a fit that wants the wrong sign must be able to say so
(:meth:`Effect.contradiction`), instead of sticking at the bound and looking
like "no effect".
"""

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import IPCInputError

__all__ = ["Param", "Effect", "Charge", "is_constant_law", "SHIFT_ANTISYMMETRY",
           "CHAIN_STAGES", "GEOMETRY_TERMS"]

SHIFT_ANTISYMMETRY = 1.0  # halfway between a blur (0) and a shift (2): Misregistration.refuted
# the stages of the chain that are not effects, at their places among the effects' positions
CHAIN_STAGES = (("shot_noise", 6.0), ("ipc", 7.0), ("read_noise", 9.0))
GEOMETRY_TERMS = ("horizontal", "vertical", "diagonal", "second")  # Geometry.terms' order


def is_constant_law(law):
    """True for a signal-independent law (``constant:A``)."""
    return (getattr(law, "kind", "") == "parametric" and law.amp_diff == 0.0
            and law.amp_level == 0.0)


@dataclass(frozen=True)
class Param:
    """One fitted parameter: its "off" value, bounds and scale."""

    name: str
    off: float
    lower: float
    upper: float
    scale: float
    scan: bool = True  # try a coarse scan for the start (shape parameters need none)


@dataclass
class Charge:
    """The expected charge on its way through collection (:meth:`Effect.collect`).

    ``value`` (electrons) is on the sub-pixel grid of ``oversample`` (1: the
    pixels); ``within_pixel`` is the model's picture of light in a pixel-total
    SCENE (:data:`~.model.WITHIN_PIXEL`); ``fine`` says a later stage needs the
    sub-pixel grid (:attr:`Effect.needs_fine_grid`); ``arrivals`` is what such a
    stage took from it when the grid was summed to pixels (``None`` before).
    """

    value: np.ndarray
    oversample: int
    within_pixel: str
    fine: bool = False
    arrivals: dict = field(default=None)


@dataclass(frozen=True)
class Effect:
    """A named detector effect and where it acts.

    ``stage`` is ``"scene"`` (a data problem, before the detector),
    ``"collection"`` (changes the expected collected charge, before shot
    noise), ``"coupling"`` (the IPC law or geometry), ``"readout"`` (acts on
    the node signal after coupling) or ``"variance"`` (changes only the
    noise: its fit maximises the Gaussian likelihood with the mean fixed).

    The class attributes and methods below are what a record may override;
    as written here they make an effect that does nothing anywhere.
    """

    name: str
    stage: str
    params: tuple
    meaning: str

    position = None      # place in the chain (model.CHAIN_ORDER); None: part of "ipc"
    on_pixels = False    # collects on the pixels' totals (after the sub-pixel grid is summed)
    needs_fine_grid = False  # takes something from the sub-pixel grid (at_binning)
    subpixel = ""        # moves charge by a fraction of a pixel: what SCENE cannot tell it
    terms = ()           # the Geometry.terms it sets (coupling effects)
    section = ""         # the coupling-model file section it is read from
    reports_section = False  # the report carries report_section() under the effect's name
    first = False        # named before stronger candidates when nameable (gates.choose)
    picture_dependent = False  # depends on how a pixel-total SCENE's light lies in a pixel
    spots_aside = False  # judged again without single-pixel sources when refused
    limit = None         # the largest strength a real detector shows (PHYSICAL_LIMITS)

    def off(self):
        return {p.name: p.off for p in self.params}

    # -- the forward model ------------------------------------------------
    def starting(self, law):
        """The parameters that switch the effect on at zero strength (``law``: the starting law)."""
        return self.off()

    def offered(self, law):
        """Whether the search tries the effect on a model with starting ``law``."""
        return True

    def collect(self, charge, p):
        """Act on the expected :class:`Charge` (scene and collection stages), in place."""

    def at_binning(self, charge, p):
        """Take what the effect needs from the sub-pixel grid before it is summed to pixels."""

    def couple_law(self, p, law):
        """The coupling law with the effect (coupling stage)."""
        return law

    def couple_geometry(self, p, terms, alpha0):
        """Set the effect's :data:`GEOMETRY_TERMS` in ``terms`` (``alpha0``:
        the law's alpha(0, 0))."""

    def response(self, p):
        """The read-out response after IPC, ``M -> f(M)``, or ``None``."""
        return None

    def response_variance(self, p):
        """Variance of a per-pixel response about 1 (carried as noise)."""
        return 0.0

    def read_variance(self, p):
        """Read-noise variance added to ``READNOIS^2`` (e-^2)."""
        return 0.0

    # -- judging a fit -----------------------------------------------------
    def contradiction(self, p):
        """Why fitted ``p`` contradict the effect's meaning, or ``None``."""
        return None

    def implausible(self, p, readnoise=None, cov=None):
        """Why fitted ``p`` lie outside the effect's physical range, or ``None``."""
        return None

    def derived(self, p, uncertainties=None, cov=None, readnoise=None):
        """Extra reported quantities and their uncertainties (``cov``: the
        fit's, in ``p``'s order)."""
        return {}, {}

    def signature(self, fit):
        """Squared significance of what makes the fit this effect (:func:`~.gates.signature`)."""
        return math.inf

    def noise_weight(self, var, a):
        """Where a noise effect adds its variance (:func:`~.gates.noise_mean_z`)."""
        return a * a / var

    def refuted(self, check, trial):
        """Why the data refuse a fitted candidate (``check``:
        :class:`~.gates.Evidence`), or ``None``."""
        return None

    def report_section(self, params, cov, source):
        """The report's section under the effect's name (with :attr:`reports_section`)."""
        return None

    # -- conversions -------------------------------------------------------
    def from_value(self, value, readnoise=None):
        """Model parameters from a ``--effect NAME=VALUE`` value
        (:func:`~.labdata.effect_params`)."""
        raise IPCInputError(f"--effect {self.name}: no conversion from one value")

    def parse(self, text):
        """The value of ``--effect NAME=TEXT`` (a number; ``ValueError`` otherwise)."""
        return float(text)

    def hidden(self, value, readnoise, law):
        """``(params, law)`` of a simulated file hiding the effect at ``value``."""
        return self.from_value(value, readnoise), law

    def from_terms(self, terms, alpha0):
        """The parameters a starting geometry's ``terms`` amount to, or ``None``."""
        return None

    def from_section(self, section, source):
        """``(params, note)`` from a coupling-model file's :attr:`section`."""
        raise IPCInputError(f"{source}: {self.section} cannot be read")

    def own(self, fit):
        """``(params, errors, cov)`` of the effect in ``fit``, in the fit's key order."""
        keys = [k for k in fit.keys if k[0] == self.name]
        idx = [fit.keys.index(k) for k in keys]
        return ({n: fit.values[(e, n)] for e, n in keys}, {n: fit.errors[(e, n)] for e, n in keys},
                fit.cov[np.ix_(idx, idx)])

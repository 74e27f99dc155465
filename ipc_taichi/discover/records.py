"""The records of a search (:func:`~.search.discover`): small frozen values.

:class:`Setting` is what every round shares (the data, the probes, the
rules' numbers, where the search started); :class:`State` where the search
stands between rounds. A round's candidates, their fits and the choice make
a :class:`Round`; a named effect a :class:`Step`, an effect taken out again a
:class:`Pruning`, and the end of the search a :class:`Stop`. Each record of
the report gives its entry (``as_dict``) and its progress line (``line``);
:func:`~.report.assemble` puts the entries together.
"""

import math
from dataclasses import dataclass, replace

from .fitting import FRAGILE

__all__ = ["Setting", "State", "Round", "Step", "Pruning", "Stop"]


@dataclass(frozen=True)
class Setting:
    """What every round of a search shares.

    ``lab`` the lab file (:class:`~.labdata.LabData`), ``frames`` its data
    (:class:`~.blocks.PairBlocks`), ``probes`` and ``masks`` those of each
    frame (:meth:`~.blocks.PairBlocks.probes`), ``threshold`` the delta BIC
    an effect must pass, ``seed`` the noise floor's, ``floor_simulations``
    the final floor's simulations; ``starting_model`` (one line) and
    ``seeded`` (what a coupling-model file's measured sections put in it)
    say where the search started.
    """

    lab: object
    frames: object
    probes: list
    masks: list
    threshold: float
    seed: int
    floor_simulations: int
    starting_model: str
    seeded: dict

    @property
    def ln_n(self):
        """The log of the number of valid pixels (the BIC's penalty per parameter)."""
        return math.log(self.frames.n)


@dataclass(frozen=True)
class State:
    """Where a search stands: its ``model``, that model's prediction
    (``parts``) and ``gap``, the last joint refit ``fit`` (``None`` before the
    first step), the :class:`Step` records taken, the :class:`Pruning` records
    and the candidates ``rejected``, ``((effect, why), ...)``, the most
    recently refused last."""

    model: object
    parts: list
    gap: float
    fit: object = None
    steps: tuple = ()
    pruned: tuple = ()
    rejected: tuple = ()

    def rejecting(self, name, why):
        """This state with ``name`` refused for ``why`` (moved last)."""
        return replace(self, rejected=tuple((n, w) for n, w in self.rejected if n != name)
                       + ((name, why),))

    def naming(self, name):
        """This state with ``name`` no longer among the rejected (named now)."""
        return replace(self, rejected=tuple((n, w) for n, w in self.rejected if n != name))


@dataclass(frozen=True)
class Round:
    """One round's candidates.

    ``gap`` is the gap the round faced, ``floor`` and ``floor_sigma`` the
    current model's noise floor, ``dev_now`` its deviance; ``trials`` maps
    every candidate to its :class:`~.fitting.Trial`, ``contradicting`` those
    the gates refuse to their reason (:func:`~.gates.gate`), ``named`` the
    nameable ones (:func:`~.gates.nameable`) and ``best`` is the one chosen
    (:func:`~.gates.choose`).
    """

    gap: float
    floor: float
    floor_sigma: float
    dev_now: float
    trials: dict
    contradicting: dict
    named: dict
    best: str

    @property
    def trial(self):
        """The chosen candidate's :class:`~.fitting.Trial`."""
        return self.trials[self.best]

    @property
    def above_floor(self):
        """How many floor scatters the gap lies above the floor (``inf`` without scatter)."""
        return (self.gap - self.floor) / self.floor_sigma if self.floor_sigma > 0 else math.inf

    def explained(self, gap_after):
        """The share of the gap's excess over the floor that ``gap_after`` removes
        (``None`` without an excess)."""
        excess = self.gap - self.floor
        return (self.gap - gap_after) / excess if excess > 0 else None

    def line(self):
        """The progress line: every candidate's evidence, strongest first."""
        return "candidates: " + ", ".join(
            f"{n} {self.trials[n].evidence:.1f}"
            + (" (contradicts)" if n in self.contradicting else "")
            for n in sorted(self.trials, key=lambda n: -self.trials[n].evidence))


@dataclass(frozen=True)
class Step:
    """A named effect: the :class:`Round` that chose it (``choice``), the gap
    after its joint refit, its ``params`` and ``uncertainties`` there, its
    ``evidence_with_variance`` (:func:`~.fitting.full_evidence`), the partners
    refitted with it, the earlier effects ``pruned`` for it and the
    near-degenerate ``alternatives``."""

    choice: Round
    gap_after: float
    params: dict
    uncertainties: dict
    evidence_with_variance: float
    refitted_with: list
    pruned: tuple
    alternatives: list
    picture: str = ""  # how the joint refit was made when not on every pixel

    @property
    def effect(self):
        return self.choice.best

    @property
    def explained_fraction(self):
        return self.choice.explained(self.gap_after)

    def as_dict(self):
        """The report's entry for this step."""
        r, t = self.choice, self.choice.trial
        return {"effect": r.best, "params": self.params, "uncertainties": self.uncertainties,
                "gap_before": r.gap, "gap_after": self.gap_after,
                "explained_fraction": self.explained_fraction,
                "evidence": t.evidence, "evidence_kind": "delta_BIC",
                "evidence_with_variance": self.evidence_with_variance,
                "delta_chi2": t.delta, "n_params": t.n_params,
                "refitted_with": self.refitted_with, "pruned": list(self.pruned),
                "floor_before": r.floor, "floor_sigma_before": r.floor_sigma,
                "alternatives": self.alternatives,
                **({"fitted": self.picture} if self.picture else {}),
                "candidates": {n: round(c.evidence, 2) for n, c in r.trials.items()},
                "contradicting": r.contradicting,
                "without_signature": sorted(set(r.trials) - set(r.named)
                                            - set(r.contradicting))}

    def line(self):
        """The progress line."""
        f = self.explained_fraction
        return (f"added {self.effect}: delta BIC {self.choice.trial.evidence:.1f}, gap "
                f"{self.choice.gap:.4f} -> {self.gap_after:.4f}"
                + (f" ({100 * f:.0f} % of the excess)" if f is not None else ""))


@dataclass(frozen=True)
class Pruning:
    """An earlier effect taken out after step ``after_step``, when
    ``replaced_by`` joined: its parameters before, the delta BIC of keeping
    it (``evidence``), and whether it was ``fragile`` (needed only by the
    smooth picture of pixel-total light, :data:`~.fitting.FRAGILE`) rather
    than doing work the newcomer now does."""

    effect: str
    after_step: int
    replaced_by: str
    params_before: dict
    evidence: float
    threshold: float
    fragile: bool = False

    @property
    def reason(self):
        if self.fragile:
            return (f"{FRAGILE}: with the light uniform within each pixel, keeping it was "
                    f"worth delta BIC {self.evidence:.1f} (threshold {self.threshold:g})")
        return (f"after {self.replaced_by} joined and every parameter was refitted, keeping "
                f"{self.effect} was worth delta BIC {self.evidence:.1f} (threshold "
                f"{self.threshold:g}): {self.replaced_by} does its work")

    def as_dict(self):
        """The report's entry under ``pruned``."""
        return {"effect": self.effect, "after_step": self.after_step,
                "replaced_by": self.replaced_by, "params_before": self.params_before,
                "evidence": round(self.evidence, 2), "reason": self.reason}

    def line(self):
        """The progress line."""
        why = FRAGILE if self.fragile else f"keeping it was worth delta BIC {self.evidence:.1f}"
        return f"dropped {self.effect}: {why}"


@dataclass(frozen=True)
class Stop:
    """Why the search stopped.

    ``kind`` is ``"exhausted"`` (every effect of the vocabulary is in the
    model), ``"unqualified"`` (no candidate may be named, or the best one's
    evidence is under the threshold) or ``"refused"`` (the best one was
    refused once joined, :func:`~.gates.refusal`, removing
    ``explained_fraction`` of the excess); ``choice`` is the last
    :class:`Round` (``None`` when exhausted).
    """

    kind: str
    reason: str
    choice: Round = None
    explained_fraction: float = None

    @classmethod
    def exhausted(cls):
        return cls("exhausted", "every effect of the vocabulary is in the model")

    @classmethod
    def unqualified(cls, rnd, threshold):
        """The stop of a round whose best candidate may not be named or is too weak."""
        why = ("" if rnd.named else "no candidate qualifies (signature or sign); ") + (
            f"best candidate {rnd.best} has delta BIC {rnd.trial.evidence:.1f} "
            f"(threshold {threshold:g}); gap {rnd.gap:.4f} is {rnd.above_floor:.1f} "
            f"scatters above the floor {rnd.floor:.4f}")
        return cls("unqualified", why, rnd)

    @classmethod
    def refused(cls, rnd, refusal, fraction):
        """The stop of a round whose best candidate the :class:`~.gates.Refusal` refuses."""
        why = f"best candidate {rnd.best} (delta BIC {rnd.trial.evidence:.1f}) {refusal.reason}"
        return cls("refused", why, rnd, fraction)

    def as_dict(self):
        """The report's ``stop``."""
        if self.choice is None:
            return {"reason": self.reason}
        out = {"reason": self.reason, "best_candidate": self.choice.best,
               "evidence": round(self.choice.trial.evidence, 2)}
        if self.kind == "refused":
            out["explained_fraction"] = self.explained_fraction
        out["gap_scatters_above_floor"] = round(self.choice.above_floor, 2)
        out["contradicting"] = self.choice.contradicting
        return out

    def line(self):
        """The progress line."""
        return "stop: " + self.reason

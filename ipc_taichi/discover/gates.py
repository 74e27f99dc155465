"""The naming gates: what a fitted candidate must show to be named, and the
refusals of the search.

A fit can lower the gap without being the effect it is named after. The
gates here ask each candidate for its own signature: an anisotropy or a
signal dependence significant by itself (:func:`signature`), zero-mean
residuals where a noise effect adds its variance (:func:`noise_mean_z`), a
variance excess inside flat areas for a response map (:func:`flat_interior_z`),
an antisymmetric misfit for a shift (:func:`shift_antisymmetry`); :func:`gate`
collects why each candidate may not be named, :func:`nameable` keeps the
others and :func:`choose` picks the one a round names.

A named candidate can still be refused once it joins the model
(:func:`refusal`): after the joint refit it may be needed only by the smooth
picture of pixel-total light, leave a named effect outside its physical
range (:func:`refit_gate`), explain too little of the gap's excess over the
floor (:data:`MIN_EXPLAINED_FRACTION`) or leave the gap below the floor.
:func:`refuse_noiseless` refuses a file with nothing to weigh residuals by;
:func:`is_complete` is the final verdict.
"""

import math
from dataclasses import dataclass

import numpy as np

from ..errors import IPCInputError
from .blocks import PairBlocks
from .diagnostics import UNEXPLAINED_Z, dipoles, residuals_by_probe
from .effects import EFFECTS, SHIFT_ANTISYMMETRY, contradiction, implausible
from .fitting import FRAGILE, chi2_of, fit_candidate, is_noise_effect, sds_of

__all__ = ["gate", "nameable", "choose", "evidence_beside", "refit_gate", "refusal",
           "refuse_noiseless", "is_complete", "Refusal", "signature", "noise_mean_z",
           "flat_interior_z", "mean_misfit", "shift_antisymmetry", "scatters_below_floor",
           "SIGNATURE_Z2", "SHIFT_ANTISYMMETRY", "ALTERNATIVE_RATIO", "MIN_EXPLAINED_FRACTION",
           "COMPLETE_SIGMAS", "Evidence"]

SIGNATURE_Z2 = 25.0  # an effect's own signature must be 5 sigma (see signature)
ALTERNATIVE_RATIO = 0.5  # misregistration first from half the best evidence (see choose)
MIN_EXPLAINED_FRACTION = 0.25  # a step must remove this share of the gap's excess
COMPLETE_SIGMAS = 3.0  # complete: final gap within this many floor scatters of the floor


def signature(name, fit):
    """Squared significance of what makes ``name`` that effect, not a rescaled IPC.

    A rescaled coupling (``weight_horizontal = weight_vertical != 1``, or a
    constant law with a new floor) would otherwise pass for anisotropy or
    signal dependence whenever anything adds nearest-neighbour charge (e.g.
    diffusion). The signature is each record's
    (:meth:`~.record.Effect.signature`): the anisotropy for
    ``anisotropic_ipc``, the two amplitudes jointly for
    ``signal_dependent_ipc``; for the other effects the evidence itself.
    """
    return EFFECTS[name].signature(fit)


def noise_mean_z(frames, model, parts, name):
    """The mean of the residuals where a noise effect adds its variance, in units
    of its standard error: a variance excess has zero mean there, a missing
    signal (an after-image, a cosmic ray, a ghost) does not."""
    num = den = 0.0
    for (mean, var, a), block in zip(parts, frames.blocks):
        m, v = block.measured, block.valid
        var = np.maximum(var, 1e-12)
        r = (m - mean) / np.sqrt(var)
        # where the effect's variance is a large share of the total
        w = np.where(v, EFFECTS[name].noise_weight(var, a), 0.0)
        num += float(np.sum(w * r))
        # the residuals' own scatter: a variance excess inflates it, and a
        # z in units of the model's variance would then flag noise as a signal
        den += float(np.sum(w * w * r * r))
    return num / math.sqrt(den) if den > 0 else 0.0


def flat_interior_z(frames, model, parts, masks):
    """Significance of the chi-square excess inside flat areas (``inf`` when
    the frames have none): a response map shows there like anywhere bright,
    the leftovers of a mis-modelled blur or coupling do not."""
    values, i = [], 0
    for (mean, _, _), var, block in zip(parts, PairBlocks.total_variance(model, parts),
                                        frames.blocks):
        for k in range(len(mean)):
            inside = masks[i]["flat_patches"][0] & block.valid[k]
            values.append(((block.measured[k] - mean[k]) ** 2 / var[k])[inside])
            i += 1
    values = np.concatenate(values)
    if values.size < 20:  # nothing flat to confirm a response map with
        return -math.inf
    return (float(values.mean()) - 1.0) / math.sqrt(2.0 / values.size)



def mean_misfit(residuals, masks):
    """The probe part (centres or surroundings of hot pixels, stars, flat
    patches and their edges) whose mean residual is most significant, as
    ``("stars centres", z)``, when it passes :data:`~.diagnostics.UNEXPLAINED_Z`;
    else ``None``. ``z`` is the mean over its standard error measured from
    the residuals' own scatter (an inflated variance does not hide it, an
    underestimated one does not create it)."""
    worst = None
    for kind, parts in residuals_by_probe(residuals, masks).items():
        for where, part in parts.items():
            if part["n"] <= 5 or not np.isfinite(part["z"]) or not part["chi2"] > 0:
                continue
            spread = max(part["chi2"] - part["mean"] ** 2, 1e-12)
            z = part["z"] / math.sqrt(spread)
            if abs(z) > UNEXPLAINED_Z and (worst is None or abs(z) > abs(worst[1])):
                worst = (f"{kind.replace('_', ' ')} "
                         f"{'centres' if where == 'centre' else 'surroundings'}", z)
    return worst


def _own_cov(fit, name):
    """The covariance of effect ``name``'s parameters (in the effect's order) in ``fit``."""
    idx = [fit.keys.index((name, p.name)) for p in EFFECTS[name].params]
    return fit.cov[np.ix_(idx, idx)]


@dataclass(frozen=True)
class Evidence:
    """What a record's :meth:`~.record.Effect.refuted` may ask of the data in
    :func:`gate`: the frames, the current model, its prediction and the masks."""

    frames: object
    model: object
    parts: list
    masks: list

    def flat_interior_z(self):
        """:func:`flat_interior_z` of the current model."""
        return flat_interior_z(self.frames, self.model, self.parts, self.masks)

    def antisymmetry(self, trial, name):
        """:func:`shift_antisymmetry` of effect ``name``'s fitted ``trial``."""
        return shift_antisymmetry(self.frames, self.model, self.parts, trial, name)


def gate(frames, model, parts, trials, probes, masks):
    """Why each fitted candidate may not be named: ``{effect: reason}``.

    ``trials`` maps each candidate to its :class:`~.fitting.Trial`. A fit
    that contradicts the effect's meaning (:func:`~.effects.contradiction`),
    a noise effect where the residuals have a non-zero mean, a response map
    whose flat areas show no variance excess, and a shift whose misfit is not
    antisymmetric are refused; so are a fit whose strength is outside the
    effect's physical range (:func:`~.effects.implausible`) and a noise
    effect while the mean is mis-modelled at the probes (:func:`mean_misfit`):
    variance effects earn their name from variance alone.
    """
    contradicting = {}
    for n, t in trials.items():
        params = {p.name: t.fit.values[(n, p.name)] for p in EFFECTS[n].params}
        why = contradiction(n, params)
        if why:
            contradicting[n] = "the fit contradicts the effect: " + why
        elif implausible(n, params, model.readnoise, _own_cov(t.fit, n)):
            contradicting[n] = ("the fitted strength is outside the physical range: "
                                + implausible(n, params, model.readnoise, _own_cov(t.fit, n)))
    residuals = frames.residuals(model, parts)[0]
    current = dipoles(residuals, probes)
    misfit = mean_misfit(residuals, masks)
    for axis in ("x", "y"):  # a dipole's two sides cancel in the means above
        z = current[axis][1]
        if misfit is None and np.isfinite(z) and abs(z) > UNEXPLAINED_Z:
            misfit = (f"dipoles along {axis} around the sources", z)
    for n in trials:
        if is_noise_effect(n) and n not in contradicting:
            z = noise_mean_z(frames, model, parts, n)
            if abs(z) > UNEXPLAINED_Z:
                contradicting[n] = (f"a variance excess, but the residuals there have a "
                                    f"non-zero mean ({z:+.1f} standard errors)")
            elif misfit:
                where, zm = misfit
                contradicting[n] = (f"a variance excess, but the mean is mis-modelled where "
                                    f"it acts ({where}: {zm:+.1f} standard errors): a variance "
                                    "effect would absorb a wrong mean")
    check = Evidence(frames, model, parts, masks)
    for n in sorted(trials, key=lambda n: not is_noise_effect(n)):  # variance effects first
        why = None if n in contradicting else EFFECTS[n].refuted(check, trials[n])
        if why:
            contradicting[n] = why
    return contradicting


def refit_gate(fit, names, readnoise=None):
    """The first of the effects ``names`` (those the search named) in a jointly
    refitted model (``fit``, a :func:`~.fitting.refit_all` result) whose
    parameters now contradict it or lie outside its physical range, as
    ``(effect, why)``; ``None`` when all hold.

    A candidate passes :func:`gate` with the rest of the model fixed; the joint
    refit can then move it where it could not have been named (on a GalSim
    file whose hot pixels never saw their own charge, a brighter-fatter named
    beside a diagonal coupling went, once refitted alone, to a kernel whose
    centre is zero and whose nearest terms are negative).
    """
    for name, params in fit.model.effects.items():
        if name not in names:
            continue
        why = contradiction(name, params)
        if why:
            return name, "contradicts the effect: " + why
        keys = [(name, p.name) for p in EFFECTS[name].params]
        cov = _own_cov(fit, name) if all(k in fit.keys for k in keys) else None
        why = implausible(name, params, readnoise, cov)
        if why:
            return name, "is outside the physical range: " + why
    return None


def shift_antisymmetry(frames, model, parts, trial, name):
    """How antisymmetric the misfit a fitted shift removes is.

    With ``chi2(s)`` the chi-square of the model displaced by the fitted
    shift ``s`` (``trial``, a :class:`~.fitting.Trial`, of effect ``name``) and
    ``chi2(0)`` the current one, returns ``(chi2(-s) - chi2(s)) / (chi2(0) -
    chi2(s))``: a real shift between SCENE and MEASURED makes its mirror
    image worse than no shift by what the shift gains (2 where the misfit is
    linear in the shift), a symmetric misfit that a spline shift partly
    absorbs (a blur: 0.24-0.32 on GalSim's silicon diffusion) leaves the
    mirror image almost as good (0). Every pixel counts, weighted by its
    noise, so it does not hang on how many sources a frame holds, as a mean
    dipole around them did (3.4 sigma for an 0.4 px shift of 46 sources).
    """
    if not trial.delta > 0:
        return 0.0
    fit = trial.fit
    shift = fit.model.effects[name]
    mirror = fit.model.with_effects({name: {k: -v for k, v in shift.items()}})
    sds = sds_of(model, parts)
    return (chi2_of(frames, mirror, sds) - fit.chi2) / trial.delta


def nameable(trials, contradicting):
    """The candidates (``{effect: Trial}``) that may be named: not refused by
    :func:`gate` (``contradicting``) and with their own signature at 5 sigma
    (:func:`signature`)."""
    return {n: t for n, t in trials.items()
            if n not in contradicting and signature(n, t.fit) > SIGNATURE_Z2}


def choose(trials, named, threshold, beside=None):
    """The candidate a round names: the strongest nameable one (the strongest
    of all when none is), unless ``misregistration`` is nameable with evidence
    above ``threshold`` and :data:`ALTERNATIVE_RATIO` of that one's: a shift
    between SCENE and MEASURED contaminates every detector effect downstream,
    so it goes first (a much stronger candidate means the dipoles are the
    leftovers of a mis-modelled effect).

    ``beside(name, best)``, when given, is the evidence of candidate ``name``
    fitted once more with the strongest candidate ``best`` in the model
    (:func:`evidence_beside`): the shift goes first only while it keeps
    :data:`ALTERNATIVE_RATIO` of its own evidence there. A shift that the
    strongest candidate's work takes away was that candidate's leftovers
    (GalSim's silicon diffusion on pixel totals, seed 133: a 0.09 px shift
    at delta BIC 361,810 alone, 144 beside the diffusion; named first, it
    took 72 % of the excess and the diffusion was never named).
    """
    best = max(named or trials, key=lambda n: trials[n].evidence)
    for name, trial in named.items():
        if EFFECTS[name].first and name != best and trial.evidence > max(
                threshold, ALTERNATIVE_RATIO * trials[best].evidence) and (
                beside is None or beside(name, best) > ALTERNATIVE_RATIO * trial.evidence):
            return name
    return best


def evidence_beside(frames, trials, ln_n):
    """The ``beside`` of :func:`choose` for a round's ``trials`` (fitted on
    ``frames``; ``ln_n`` the BIC's penalty per parameter): candidate
    ``name`` fitted again (:func:`~.fitting.fit_candidate`) on the model of
    ``best``'s fit, its delta BIC over that model."""

    def beside(name, best):
        model = trials[best].fit.model
        parts = frames.predict(model)
        sds = sds_of(model, parts)
        return fit_candidate(frames, model, name, parts, sds, chi2_of(frames, model, sds),
                             frames.deviance(model, parts), ln_n).evidence

    return beside


def refuse_noiseless(lab):
    """Refuse a lab file (:class:`~.labdata.LabData`) whose header leaves no
    noise to weigh residuals by (``READNOIS = 0`` and ``SHOTNOIS = F``)."""
    if lab.readnoise == 0 and not lab.shot_noise:
        raise IPCInputError(f"{lab.path}[PRIMARY]: READNOIS = 0 with SHOTNOIS = F leaves no "
                            "noise to weigh residuals by")


@dataclass(frozen=True)
class Refusal:
    """Why a named candidate is refused once it joins: ``why`` for the
    verdict's list of effects not named, ``reason`` for the search's stop."""

    why: str
    reason: str
    of_effect: bool = False  # refused for what its own fit says of it, not for the gap


def scatters_below_floor(frames, model, parts, gap_now, seed, n_sim=8):
    """How many floor scatters ``gap_now`` lies below the floor of ``model``
    (negative when above); the floor simulated with its own seed, so the
    search's other draws stay as they were."""
    floor, sigma, _ = frames.floor(model, np.random.default_rng(seed + 7919), n_sim, parts)
    return (floor - gap_now) / sigma if sigma > 0 else 0.0


def refusal(frames, rnd, joined, names, readnoise, seed):
    """Why the candidate a round chose (``rnd``, a :class:`~.records.Round`)
    may not join after all, given its joint refit (``joined``, a
    :class:`~.fitting.Joined`), as a :class:`Refusal`; ``None`` when it may.

    In this order: it is needed only by the smooth picture of pixel-total
    light (:data:`~.fitting.FRAGILE`); the refit leaves one of ``names`` (the
    effects the search named, this one included) contradicting its meaning or
    outside its physical range (:func:`refit_gate`); the gap lies more than 3
    floor scatters above the floor and the step removes under
    :data:`MIN_EXPLAINED_FRACTION` of that excess; or, with a noise effect in
    the model, the gap ends more than :data:`COMPLETE_SIGMAS` scatters below
    its floor (a variance inflated to absorb a wrong mean; the floor simulated
    with ``seed``, :func:`scatters_below_floor`).
    """
    best, fraction, refit = rnd.best, rnd.explained(joined.gap_after), joined.fit
    unphysical = refit_gate(refit, names, readnoise)
    if best in joined.gone:
        return Refusal(FRAGILE, f"is {FRAGILE}", of_effect=True)
    if unphysical:
        name, why = unphysical
        whose = "its" if name == best else f"{name}'s"
        return Refusal(f"after the joint refit {whose} fit {why}",
                       f"would leave {name} after the joint refit with a fit that {why}",
                       of_effect=True)
    if rnd.above_floor > 3.0 and (fraction is None or fraction < MIN_EXPLAINED_FRACTION):
        share = f"{100 * (fraction or 0.0):.1f} %"
        return Refusal(f"it would remove only {share} of the excess",
                       f"removes only {share} of the gap's excess over the floor (needs "
                       f"{100 * MIN_EXPLAINED_FRACTION:g} %): a symptom of something the "
                       "vocabulary lacks, not a finding")
    if any(is_noise_effect(e) for e in refit.model.effects):
        below = scatters_below_floor(frames, refit.model, joined.parts, joined.gap_after, seed)
        if below > COMPLETE_SIGMAS:
            return Refusal(f"it would leave the gap {below:.1f} scatters below the floor: a "
                           "variance inflated to absorb a wrong mean",
                           f"would leave the gap {joined.gap_after:.4f} {below:.1f} scatters "
                           "below its floor: the model's variance would absorb a mis-modelled "
                           "mean")
    return None


def is_complete(gap_now, floor, floor_sigma):
    """The verdict: the gap lies within :data:`COMPLETE_SIGMAS` floor scatters
    of the floor."""
    return bool(abs(gap_now - floor) <= COMPLETE_SIGMAS * floor_sigma)

"""Name the missing effect: fit each candidate, weigh the evidence, add, repeat.

Procedure (:func:`discover`)
----------------------------
1. Start from the model the file's header describes (law ``IPCLAW``, read
   noise, shot noise, nothing else) and compute the baseline gap.
2. For every effect of the vocabulary not yet in the model, fit its
   parameters starting "off", the rest of the model fixed except the
   parameters of effects already in the model that are near-degenerate with
   it (:data:`~.pairs.DEGENERATE`: diffusion and brighter-fatter,
   anisotropy and diagonal coupling, ...), which are refitted jointly.
   Effects that change the mean are fitted by least squares with the
   current model's variance held fixed; effects that change only the noise
   (``flat_field``, ``excess_read_noise``) by the Gaussian likelihood with
   the mean held fixed, with the response map's correlation between the
   pairs of a file written out exactly (:func:`~.blocks.deviance`). Evidence:
   ``delta BIC = -2 delta lnL - k ln n`` (``k`` new parameters, ``n`` valid
   pixels). ``signal_dependent_ipc`` is a candidate only while the law is
   constant.
3. A candidate can be named only if its fit does not contradict the
   effect's meaning (:func:`~.effects.contradiction`; a noise effect also
   needs residuals of zero mean where it adds variance), and, for
   ``anisotropic_ipc`` and ``signal_dependent_ipc``, its own signature is
   significant at 5 sigma. ``misregistration`` goes first whenever its
   evidence reaches half the best candidate's and, fitted again with that
   candidate in the model, it keeps half its own (:func:`~.gates.choose`):
   a shift between SCENE and MEASURED contaminates every detector effect
   downstream (a much stronger candidate, or one whose work takes the shift
   away, means the dipoles are the leftovers of a mis-modelled effect).
4. The best candidate is added when ``delta BIC >``
   :data:`~.fitting.EVIDENCE_THRESHOLD` and, after the joint refit of every
   parameter, it removes at least :data:`~.gates.MIN_EXPLAINED_FRACTION` of the
   gap's excess over the floor (when that excess is significant): an
   effect that explains little of a large excess is a symptom of something
   the vocabulary lacks, not a finding.
   After that refit, an earlier effect whose removal no longer costs
   evidence (:func:`~.fitting.prune`: its parameters fell back to "off", or its
   work is now done by the newcomer) is dropped and recorded under ``pruned``.
5. The loop repeats until no candidate qualifies; the noise floor is then
   the final model simulated :data:`FLOOR_SIMULATIONS` times with fresh
   noise. ``complete`` is true when the final gap lies within
   :data:`~.gates.COMPLETE_SIGMAS` floor scatters of the floor; otherwise
   ``unexplained`` describes the remaining residual
   (:func:`~.report.describe_unexplained`).

The jobs live apart: the data blocks and the likelihood in :mod:`.blocks`,
fitting and the joint refit of step 4 in :mod:`.fitting`, the naming gates
of step 3 and the refusals of step 4 in :mod:`.gates`, the records of the
search (its setting and state, each round, step, pruning and stop) in
:mod:`.records`, the words of ``unexplained`` and the report's assembly in
:mod:`.report`; this module is the loop.
"""


import os
from dataclasses import dataclass, field, replace

import numpy as np

from ..model import CouplingModel
from .blocks import PairBlocks
from .diagnostics import gap
from .fitting import (
    EVIDENCE_THRESHOLD,
    FRAGILE,
    candidates,
    chi2_of,
    fit_candidate,
    full_evidence,
    join,
    judged_without_spots,
    params_report,
    partners,
    sds_of,
)
from .gates import (
    ALTERNATIVE_RATIO,
    choose,
    evidence_beside,
    gate,
    nameable,
    refusal,
    refuse_noiseless,
)
from .labdata import LabData, read_lab
from .model import DetectorModel, effects_from_document
from .pairs import SEPARATION
from .records import Pruning, Round, Setting, State, Step, Stop
from .report import assemble

__all__ = ["discover", "Discovery", "EVIDENCE_THRESHOLD", "FLOOR_SIMULATIONS", "MAX_STEPS"]

FLOOR_SIMULATIONS = 24
MAX_STEPS = 4
FALLBACKS = 2  # further candidates tried in a round whose choice is refused (_choices)


@dataclass
class Discovery:
    """The outcome of :func:`discover`: the JSON-ready ``report`` and the
    arrays the figures need (``baseline`` and ``final`` diagnostics)."""

    report: dict
    model: DetectorModel
    baseline: dict = field(repr=False, default_factory=dict)
    final: dict = field(repr=False, default_factory=dict)
    gaps: list = field(default_factory=list)


def discover(data, seed=0, threshold=EVIDENCE_THRESHOLD, max_steps=MAX_STEPS,
             floor_simulations=FLOOR_SIMULATIONS, log=None, start=None):
    """Find the effects missing from the starting model of a lab file.

    Parameters
    ----------
    data : str or LabData
        A lab FITS file (``docs/discovery_format.md``) or its :func:`read_lab` result.
    seed : int
        Seed of the noise-floor simulations.
    threshold : float
        Minimum delta BIC for an effect to be added.
    log : callable, optional
        Called with one progress line per step.
    start : CouplingModel, (CouplingModel, dict) or str, optional
        The starting coupling (a :class:`~ipc_taichi.model.CouplingModel`,
        the pair :meth:`~ipc_taichi.model.CouplingModel.load` returns with
        ``with_document``, or a coupling-model file), replacing the file's
        ``IPCLAW`` (:meth:`DetectorModel.from_coupling`). A file's measured
        ``brighter_fatter`` kernel and ``classical_nonlinearity`` join the
        starting model as those effects (:func:`~.model.effects_from_document`;
        the report's ``seeded_from_model_file`` says what was converted).

    Returns
    -------
    Discovery
        ``.report`` is the JSON report (``baseline_gap``, ``steps``,
        ``missing_effects``, ``final_gap``, ``gap_floor``, ``gap_floor_sigma``,
        ``complete``, ``unexplained``, ...); ``brighter_fatter``, when the
        final model holds that effect, gives it as the kernel calibrate
        measures (:func:`~.report.brighter_fatter_section`).
    """
    lab = data if isinstance(data, LabData) else read_lab(data)
    refuse_noiseless(lab)
    say = log or (lambda line: None)
    setting, state, baseline = _begin(lab, seed, threshold, floor_simulations, start)
    say(f"baseline gap {state.gap:.4f} over {setting.frames.n} pixels "
        f"({setting.starting_model})")
    rng = np.random.default_rng(seed)
    stop, search = None, setting
    while stop is None and len(state.steps) < max_steps:
        state, stop = _round(search, state, rng, say)
        if stop is None and state.steps[-1].picture and search is setting:
            search, state = _set_spots_aside(setting, state, say)
    frames = setting.frames
    if search is not setting:  # the verdict is on every pixel
        parts = frames.predict(state.model)
        state = replace(state, parts=parts, gap=gap(frames.residuals(state.model, parts)[0]))
    floor, floor_sigma, floor_bins = frames.floor(state.model, rng, floor_simulations,
                                                  state.parts)
    final = frames.diagnostics(state.model, setting.probes, setting.masks, state.parts)
    final["floor_chi2_vs_signal"] = floor_bins
    report = assemble(setting, state, stop, baseline, final, (floor, floor_sigma))
    return Discovery(report, state.model, baseline, final,
                     [baseline["gap"]] + [s.gap_after for s in state.steps])


def _begin(lab, seed, threshold, floor_simulations, start):
    """The search's :class:`~.records.Setting`, its first
    :class:`~.records.State` and the baseline diagnostics (step 1)."""
    frames = PairBlocks.from_lab(lab)
    probes, masks = frames.probes()
    model, seeded = _starting_model(lab, start)
    setting = Setting(lab, frames, probes, masks, threshold, seed, floor_simulations,
                      model.describe(), seeded)
    parts = frames.predict(model)
    baseline = frames.diagnostics(model, probes, masks, parts)
    return setting, State(model, parts, baseline["gap"]), baseline


def _set_spots_aside(setting, state, say):
    """The setting and state for the rest of a search once an effect was named
    without the pixel-total SCENEs' single-pixel sources (:data:`~.fitting.WITHOUT_SPOTS`):
    the later rounds leave those pixels out too, so that no effect is named for
    the misfit there that the sub-pixel light, which SCENE does not give, may
    cause (a signal-dependent coupling fitted to GalSim's pinhole spots once its
    brighter-fatter had been named). The verdict is made on every pixel again."""
    frames = setting.frames.without_single_pixel_sources()
    parts = frames.predict(state.model)
    say(f"the rest of the search leaves out the {setting.frames.n - frames.n} pixels at and "
        "around single-pixel sources")
    return (replace(setting, frames=frames),
            replace(state, parts=parts, gap=gap(frames.residuals(state.model, parts)[0])))


def _starting_model(lab, start):
    """The starting model and what a coupling-model file's measured sections put
    in it (``{effect: what was converted}``, empty without them)."""
    if start is None:
        return lab.model(), {}
    document, source = None, "model file"
    if isinstance(start, (str, os.PathLike)):
        source = os.fspath(start)
        start = CouplingModel.load(start, with_document=True)
    if isinstance(start, tuple):  # CouplingModel.load(path, with_document=True)
        start, document = start
    seeded = effects_from_document(document, source)[1]
    return DetectorModel.from_coupling(start, lab.readnoise, lab.shot_noise, document), seeded


def _round(setting, state, rng, say):
    """One round (steps 2-4): the state after it and, when the search stops
    there, its :class:`~.records.Stop` (else ``None``)."""
    rnd = _candidates(setting, state, rng)
    if rnd is None:
        return state, Stop.exhausted()
    say(rnd.line())
    for name, why in rnd.contradicting.items():  # a strong fit with the wrong sign is a clue
        if rnd.trials[name].evidence > setting.threshold:
            state = state.rejecting(name, why)
    if not (rnd.named and rnd.trial.evidence > setting.threshold):
        return state, _said(Stop.unqualified(rnd, setting.threshold), say)
    stop = None
    for choice in _choices(setting, rnd):
        joined = join(setting.frames, choice.trial.fit.model, choice.best, setting.threshold)
        names = {s.effect for s in state.steps} | {choice.best}
        refused = refusal(setting.frames, choice, joined, names, setting.lab.readnoise,
                          setting.seed)
        if not refused:
            return _accept(setting, state, choice, joined, say), None
        state = state.rejecting(choice.best, refused.why)
        stop = stop or Stop.refused(choice, refused, choice.explained(joined.gap_after))
        if not refused.of_effect:  # about the gap: a weaker candidate would fare no better
            break
        say(f"refused {choice.best}: {refused.why}")
    return state, _said(stop, say)


def _choices(setting, rnd):
    """The round's choice, then the other nameable candidates above the
    threshold, strongest first (at most :data:`FALLBACKS`): a candidate refused
    for what its own joint refit says of it (:class:`~.gates.Refusal`
    ``of_effect``) does not stop the search while another qualifies (GalSim's
    brighter-fatter with diffusion on pixel totals: the brighter-fatter refused
    for its kernel used to leave a diffusion at delta BIC 1e6 unnamed)."""
    others = sorted((n for n in rnd.named if n != rnd.best
                     and rnd.trials[n].evidence > setting.threshold),
                    key=lambda n: -rnd.trials[n].evidence)
    return [rnd] + [replace(rnd, best=n) for n in others[:FALLBACKS]]


def _said(stop, say):
    say(stop.line())
    return stop


def _candidates(setting, state, rng):
    """Steps 2-3 of a round: the floor of the current model, every candidate
    fitted, gated and the best chosen, as a :class:`~.records.Round`; ``None``
    when no candidate is left (every effect is in the model or was pruned)."""
    frames, model, parts = setting.frames, state.model, state.parts
    floor, floor_sigma, _ = frames.floor(model, rng, max(4, setting.floor_simulations // 3),
                                         parts)
    sds = sds_of(model, parts)
    chi2_now = chi2_of(frames, model, sds)
    dev_now = frames.deviance(model, parts)
    skip = {p.effect for p in state.pruned}
    trials = {n: judged_without_spots(
        frames, model, fit_candidate(frames, model, n, parts, sds, chi2_now, dev_now,
                                     setting.ln_n), sds, chi2_now, setting.ln_n)
              for n in candidates(model) if n not in skip}
    if not trials:
        return None
    contradicting = gate(frames, model, parts, trials, setting.probes, setting.masks)
    named = nameable(trials, contradicting)
    return Round(state.gap, floor, floor_sigma, dev_now, trials, contradicting, named,
                 choose(trials, named, setting.threshold,
                        evidence_beside(frames, trials, setting.ln_n)))


def _accept(setting, state, rnd, joined, say):
    """The state once the round's choice joins (``joined``, its
    :class:`~.fitting.Joined`): its step, what it pruned, the new model."""
    best, trial, after = rnd.best, rnd.trial, len(state.steps) + 1
    params, errors = params_report(joined.fit, best, setting.lab.readnoise)
    step = Step(rnd, joined.gap_after, params, errors,
                full_evidence(setting.frames, trial.fit.model, rnd.dev_now, trial.n_params,
                              setting.ln_n),
                partners(best, trial.fit.model), tuple(e for e, _, _ in joined.dropped),
                _alternatives(setting, rnd), joined.fit.picture)
    pruned = tuple(Pruning(e, after, best, values, worth, setting.threshold)
                   for e, values, worth in joined.dropped) + tuple(
        Pruning(e, after, best, values, worth, setting.threshold, fragile=True)
        for e, values, worth in joined.fragile)
    for p in pruned:
        say(p.line())
        if p.fragile:
            state = state.rejecting(p.effect, FRAGILE)
    say(step.line())
    return replace(state.naming(best), model=joined.fit.model, parts=joined.parts,
                   gap=joined.gap_after, fit=joined.fit, steps=state.steps + (step,),
                   pruned=state.pruned + pruned)


def _alternatives(setting, rnd):
    """The other nameable candidates of the round whose evidence reached
    :data:`~.gates.ALTERNATIVE_RATIO` of the chosen one's (and the threshold),
    for the step's report: parameters, both evidences and what tells them apart."""
    bar = max(setting.threshold, ALTERNATIVE_RATIO * rnd.trial.evidence)
    out = []
    for name, t in sorted(rnd.named.items(), key=lambda item: -item[1].evidence):
        if name == rnd.best or t.evidence < bar:
            continue
        params, errors = params_report(t.fit, name, setting.lab.readnoise)
        out.append({"effect": name, "evidence": round(t.evidence, 2), "params": params,
                    "evidence_with_variance": round(full_evidence(
                        setting.frames, t.fit.model, rnd.dev_now, t.n_params, setting.ln_n), 2),
                    "uncertainties": errors,
                    "separated_by": SEPARATION.get(frozenset({rnd.best, name}),
                                                   "the stacked windows per signal bin")})
    return out

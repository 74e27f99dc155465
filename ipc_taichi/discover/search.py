"""Name the missing effect: fit each candidate, weigh the evidence, add, repeat.

Procedure (:func:`discover`)
----------------------------
1. Start from the model the file's header describes (law ``IPCLAW``, read
   noise, shot noise, nothing else) and compute the baseline gap.
2. For every effect of the vocabulary not yet in the model, fit its
   parameters starting "off", the rest of the model fixed except the
   parameters of effects already in the model that are near-degenerate with
   it (:data:`~.effects.DEGENERATE`: diffusion and brighter-fatter,
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
   evidence reaches half the best candidate's: a shift between SCENE and
   MEASURED contaminates every detector effect downstream (a much stronger
   candidate means the dipoles are the leftovers of a mis-modelled effect).
4. The best candidate is added when ``delta BIC >``
   :data:`~.fitting.EVIDENCE_THRESHOLD` and, after the joint refit of every
   parameter, it removes at least :data:`MIN_EXPLAINED_FRACTION` of the
   gap's excess over the floor (when that excess is significant): an
   effect that explains little of a large excess is a symptom of something
   the vocabulary lacks, not a finding.
   After that refit, an earlier effect whose removal no longer costs
   evidence (:func:`~.fitting.prune`: its parameters fell back to "off", or its
   work is now done by the newcomer) is dropped and recorded under ``pruned``.
5. The loop repeats until no candidate qualifies; the noise floor is then
   the final model simulated :data:`FLOOR_SIMULATIONS` times with fresh
   noise. ``complete`` is true when the final gap lies within
   :data:`COMPLETE_SIGMAS` floor scatters of the floor; otherwise
   ``unexplained`` describes the remaining residual
   (:func:`~.report.describe_unexplained`).

The jobs live apart: the data blocks and the likelihood in :mod:`.blocks`,
fitting in :mod:`.fitting`, the naming gates of step 3 in :mod:`.gates`, the
words of ``unexplained`` and the report in :mod:`.report`; this module is the
loop.
"""


import math
import os
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import IPCInputError
from ..model import CouplingModel
from .blocks import PairBlocks
from .diagnostics import (
    SIGNAL_BINS,
    after_images,
    dipoles,
    find_probes,
    gap,
    pair_correlation,
    probe_masks,
    residual_vs_signal,
    residuals_by_probe,
    stacked_windows,
)
from .effects import EFFECTS, SEPARATION
from .fitting import (
    EVIDENCE_THRESHOLD,
    candidates,
    chi2_of,
    fit_candidate,
    full_evidence,
    is_noise_effect,
    only_with_smooth_light,
    params_report,
    partners,
    prune,
    refit_all,
    sds_of,
)
from .gates import SIGNATURE_Z2, gate, refit_gate, signature
from .labdata import LabData, read_lab
from .model import CHAIN_ORDER, DetectorModel, effects_from_document
from .report import brighter_fatter_section, describe_unexplained, json_diagnostics

__all__ = ["discover", "Discovery", "EVIDENCE_THRESHOLD", "MIN_EXPLAINED_FRACTION",
           "COMPLETE_SIGMAS", "FLOOR_SIMULATIONS", "MAX_STEPS"]

MIN_EXPLAINED_FRACTION = 0.25  # a step must remove this share of the gap's excess
COMPLETE_SIGMAS = 3.0  # complete: final gap within this many floor scatters of the floor
FLOOR_SIMULATIONS = 24
MAX_STEPS = 4
ALTERNATIVE_RATIO = 0.5
FRAGILE = ("needed only while the pixel-total SCENE's light is taken as smooth across pixels "
           "(the spline shift): it absorbs the error of that picture, not a detector effect")


@dataclass
class Discovery:
    """The outcome of :func:`discover`: the JSON-ready ``report`` and the
    arrays the figures need (``baseline`` and ``final`` diagnostics)."""

    report: dict
    model: DetectorModel
    baseline: dict = field(repr=False, default_factory=dict)
    final: dict = field(repr=False, default_factory=dict)
    gaps: list = field(default_factory=list)


def _alternatives(frames, named, best, bar, dev_now, ln_n, readnoise):
    """The other nameable candidates whose evidence reached ``bar``, for the
    step's report: parameters, both evidences and what tells them apart."""
    out = []
    for name, (ev, _, kk, f) in sorted(named.items(), key=lambda t: -t[1][0]):
        if name == best or ev < bar:
            continue
        params, errors = params_report(f, name, readnoise)
        out.append({"effect": name, "evidence": round(ev, 2), "params": params,
                    "evidence_with_variance": round(full_evidence(frames, f.model, dev_now, kk,
                                                                  ln_n), 2),
                    "uncertainties": errors,
                    "separated_by": SEPARATION.get(frozenset({best, name}),
                                                   "the stacked windows per signal bin")})
    return out


def _report_head(lab, frames, model_start):
    """What the report says about its input."""
    return {"input": lab.path, "readnoise": lab.readnoise, "shot_noise": lab.shot_noise,
            "ipclaw": lab.law, "starting_model": model_start,
            "gap_statistic": "mean over valid pixels of ((MEASURED - mean)/sd)^2, mean and sd "
                             "the model's prediction of SCENE with shot and read noise "
                             "propagated",
            "n_pixels": frames.n, "n_pairs": len(lab.pairs),
            "oversample": {str(ver): n for (ver, _, _), n in zip(lab.pairs, lab.oversample)}}


def _scatters_below_floor(frames, model, parts, gap_now, seed, n_sim=8):
    """How many floor scatters ``gap_now`` lies below the floor of ``model``
    (negative when above); the floor simulated with its own seed, so the
    search's other draws stay as they were."""
    floor, sigma, _ = frames.floor(model, np.random.default_rng(seed + 7919), n_sim, parts)
    return (floor - gap_now) / sigma if sigma > 0 else 0.0


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


def _bf_report(model, final_fit, steps, seeded):
    """The report's ``brighter_fatter`` kernel (``None`` when the final model has none)."""
    if "brighter_fatter" not in model.effects:
        return None
    params = model.effects["brighter_fatter"]
    keys = [("brighter_fatter", p.name) for p in EFFECTS["brighter_fatter"].params]
    cov, source = None, "the model file's kernel, as discover's parameters (not refitted)"
    if final_fit is not None and all(k in final_fit.keys for k in keys):
        idx = [final_fit.keys.index(k) for k in keys]
        cov = final_fit.cov[np.ix_(idx, idx)]
        source = ("fitted" if any(s["effect"] == "brighter_fatter" for s in steps) else
                  "the model file's kernel, refitted with the effects named after it")
    elif "brighter_fatter" not in seeded:
        source = "fitted"
    return brighter_fatter_section(params, cov, source)


def _diagnostics(frames, model, probes, masks, parts=None):
    res, means = frames.residuals(model, parts)
    stacks, counts = stacked_windows(res, probes)
    centres, mean_r, mean_r2, n = residual_vs_signal(res, means)
    blocks, i = [], 0
    for s in frames.scenes:
        blocks.append(res[i:i + len(s)])
        i += len(s)
    return {"residuals": res, "means": means, "stacks": stacks, "counts": counts,
            "signal": centres, "mean_residual": mean_r, "mean_residual2": mean_r2,
            "signal_counts": n, "gap": gap(res), "by_probe": residuals_by_probe(res, masks),
            "dipoles": dipoles(res, probes),
            "after_images": after_images(blocks, frames.scenes, frames.valid),
            "pair_correlation": pair_correlation(blocks)}



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
    if lab.readnoise == 0 and not lab.shot_noise:
        raise IPCInputError(f"{lab.path}[PRIMARY]: READNOIS = 0 with SHOTNOIS = F leaves no "
                            "noise to weigh residuals by")
    say = log or (lambda line: None)
    frames = PairBlocks.from_lab(lab)
    rng = np.random.default_rng(seed)
    ln_n = math.log(frames.n)
    probes, masks = [], []
    for block_s, block_v in zip(frames.scenes, frames.valid):
        for s, v in zip(block_s, block_v):
            probes.append(find_probes(s, v))
            masks.append(probe_masks(s, v, probes[-1]))
    model, seeded = _starting_model(lab, start)
    parts = frames.predict(model)
    baseline = _diagnostics(frames, model, probes, masks, parts)
    current_gap = baseline["gap"]
    model_start = model.describe()
    say(f"baseline gap {current_gap:.4f} over {frames.n} pixels ({model_start})")
    steps, final_fit, stop, rejected, pruned = [], None, None, [], []
    while len(steps) < max_steps:
        floor, floor_sigma, _ = frames.floor(model, rng, max(4, floor_simulations // 3), parts)
        sds = sds_of(model, parts)
        chi2_now = chi2_of(frames, model, sds)
        dev_now = frames.deviance(model, parts)
        trials = {n: fit_candidate(frames, model, n, parts, sds, chi2_now, dev_now, ln_n)
                  for n in candidates(model) if n not in {p["effect"] for p in pruned}}
        if not trials:
            stop = {"reason": "every effect of the vocabulary is in the model"}
            break
        contradicting = gate(frames, model, parts, trials, probes, masks)
        named = {n: t for n, t in trials.items()
                 if n not in contradicting and signature(n, t[3]) > SIGNATURE_Z2}
        say("candidates: " + ", ".join(f"{n} {trials[n][0]:.1f}" + (" (contradicts)" if n in
                                                                    contradicting else "")
                                       for n in sorted(trials, key=lambda n: -trials[n][0])))
        best = max(named or trials, key=lambda n: trials[n][0])
        shift = named.get("misregistration")
        if shift and shift[0] > max(threshold, ALTERNATIVE_RATIO * trials[best][0]):
            best = "misregistration"  # first: a shift contaminates every detector effect
        evidence, delta, k, fit = trials[best]
        above_floor = (current_gap - floor) / floor_sigma if floor_sigma > 0 else math.inf
        for n, why in contradicting.items():  # a strong fit with the wrong sign is a clue
            if trials[n][0] > threshold:
                rejected[:] = [(m, w) for m, w in rejected if m != n] + [(n, why)]
        if not (named and evidence > threshold):
            why = ("" if named else "no candidate qualifies (signature or sign); ") + (
                   f"best candidate {best} has delta BIC {evidence:.1f} "
                   f"(threshold {threshold:g}); gap {current_gap:.4f} is {above_floor:.1f} "
                   f"scatters above the floor {floor:.4f}")
            stop = {"reason": why, "best_candidate": best, "evidence": round(evidence, 2),
                    "gap_scatters_above_floor": round(above_floor, 2),
                    "contradicting": contradicting}
            say("stop: " + why)
            break
        refit = refit_all(frames, fit.model)
        # an earlier effect whose work the newcomer now does is dropped (its
        # parameters fall back to "off" or to values the data no longer need)
        kept, dropped = prune(frames, refit.model, threshold, keep=(best,))
        if dropped:
            refit = refit_all(frames, kept)
        # with pixel-total scenes, what only the smooth picture of their light needs
        fragile = only_with_smooth_light(frames, refit.model, threshold)
        gone = {name for name, _, _ in fragile}
        if fragile and best not in gone:
            smooth = refit.model.effects
            fragile = [(name, dict(smooth[name]), worth) for name, _, worth in fragile]
            refit = refit_all(frames, replace(refit.model, effects={
                e: p for e, p in smooth.items() if e not in gone}))
        new_parts = frames.predict(refit.model)
        gap_after = gap(frames.residuals(refit.model, new_parts)[0])
        excess = current_gap - floor
        fraction = (current_gap - gap_after) / excess if excess > 0 else None
        refusal = None
        unphysical = refit_gate(refit, {s["effect"] for s in steps} | {best}, lab.readnoise)
        if best in gone:
            refusal = (FRAGILE, f"is {FRAGILE}")
        elif unphysical:
            name, why = unphysical
            whose = "its" if name == best else f"{name}'s"
            refusal = (f"after the joint refit {whose} fit {why}",
                       f"would leave {name} after the joint refit with a fit that {why}")
        elif above_floor > 3.0 and (fraction is None or fraction < MIN_EXPLAINED_FRACTION):
            refusal = (f"it would remove only {100 * (fraction or 0.0):.1f} % of the excess",
                       f"removes only {100 * (fraction or 0.0):.1f} % of the gap's excess over "
                       f"the floor (needs {100 * MIN_EXPLAINED_FRACTION:g} %): a symptom of "
                       "something the vocabulary lacks, not a finding")
        elif any(is_noise_effect(e) for e in refit.model.effects):
            below = _scatters_below_floor(frames, refit.model, new_parts, gap_after, seed)
            if below > COMPLETE_SIGMAS:
                refusal = (f"it would leave the gap {below:.1f} scatters below the floor: a "
                           "variance inflated to absorb a wrong mean",
                           f"would leave the gap {gap_after:.4f} {below:.1f} scatters below "
                           "its floor: the model's variance would absorb a mis-modelled mean")
        if refusal:
            why = f"best candidate {best} (delta BIC {evidence:.1f}) {refusal[1]}"
            stop = {"reason": why, "best_candidate": best, "evidence": round(evidence, 2),
                    "explained_fraction": fraction,
                    "gap_scatters_above_floor": round(above_floor, 2),
                    "contradicting": contradicting}
            rejected[:] = [(m, w) for m, w in rejected if m != best] + [(best, refusal[0])]
            say("stop: " + why)
            break
        best_full = full_evidence(frames, fit.model, dev_now, k, ln_n)
        alternatives = _alternatives(frames, named, best, max(threshold, ALTERNATIVE_RATIO *
                                                                evidence), dev_now, ln_n,
                                     lab.readnoise)
        final_fit, model, parts = refit, refit.model, new_parts
        for name, values, worth in dropped:
            pruned.append({"effect": name, "after_step": len(steps) + 1, "replaced_by": best,
                           "params_before": values, "evidence": round(worth, 2),
                           "reason": f"after {best} joined and every parameter was refitted, "
                                     f"keeping {name} was worth delta BIC {worth:.1f} "
                                     f"(threshold {threshold:g}): {best} does its work"})
            say(f"dropped {name}: keeping it was worth delta BIC {worth:.1f}")
        for name, values, worth in fragile:
            pruned.append({"effect": name, "after_step": len(steps) + 1, "replaced_by": best,
                           "params_before": values,
                           "evidence": round(worth, 2),
                           "reason": f"{FRAGILE}: with the light uniform within each pixel, "
                                     f"keeping it was worth delta BIC {worth:.1f} (threshold "
                                     f"{threshold:g})"})
            rejected[:] = [(m, w) for m, w in rejected if m != name] + [(name, FRAGILE)]
            say(f"dropped {name}: {FRAGILE}")
        params, errors = params_report(final_fit, best, lab.readnoise)
        steps.append({"effect": best, "params": params, "uncertainties": errors,
                      "gap_before": current_gap, "gap_after": gap_after,
                      "explained_fraction": fraction,
                      "evidence": evidence, "evidence_kind": "delta_BIC",
                      "evidence_with_variance": best_full,
                      "delta_chi2": delta, "n_params": k,
                      "refitted_with": partners(best, fit.model),
                      "pruned": [name for name, _, _ in dropped],
                      "floor_before": floor, "floor_sigma_before": floor_sigma,
                      "alternatives": alternatives,
                      "candidates": {n: round(t[0], 2) for n, t in trials.items()},
                      "contradicting": contradicting,
                      "without_signature": sorted(set(trials) - set(named)
                                                  - set(contradicting))})
        say(f"added {best}: delta BIC {evidence:.1f}, gap {current_gap:.4f} -> {gap_after:.4f}"
            + (f" ({100 * fraction:.0f} % of the excess)" if fraction is not None else ""))
        current_gap = gap_after
        rejected[:] = [(m, w) for m, w in rejected if m != best]  # named now
    floor, floor_sigma, floor_bins = frames.floor(model, rng, floor_simulations, parts)
    final = _diagnostics(frames, model, probes, masks, parts)
    final["floor_chi2_vs_signal"] = floor_bins
    complete = bool(abs(current_gap - floor) <= COMPLETE_SIGMAS * floor_sigma)
    pixel_totals = [ver for (ver, _, _), n in zip(lab.pairs, lab.oversample) if n == 1]
    unexplained = [] if complete else describe_unexplained(
        final, rejected, list(model.effects), pixel_totals, len(lab.pairs),
        (floor - current_gap) / floor_sigma if floor_sigma > 0 else 0.0)
    final_params = {}
    final_errors = {}
    if final_fit is not None:
        for e in model.effects:
            final_params[e], final_errors[e] = params_report(final_fit, e, lab.readnoise)
    report = {
        **_report_head(lab, frames, model_start),
        "baseline_gap": baseline["gap"],
        "gap_floor": floor,
        "gap_floor_sigma": floor_sigma,
        "floor_simulations": floor_simulations,
        "steps": steps,
        "missing_effects": [s["effect"] for s in steps if s["effect"] in model.effects],
        "pruned": pruned,
        "final_gap": current_gap,
        "complete": complete,
        "unexplained": unexplained,
        "final_model": {"law": model.ipc_law().describe(), "effects": final_params,
                        "uncertainties": final_errors},
        "stop": stop,
        "brighter_fatter": _bf_report(model, final_fit, steps, seeded),
        "seeded_from_model_file": seeded,
        "evidence_threshold": {"delta_bic": threshold,
                               "min_explained_fraction": MIN_EXPLAINED_FRACTION,
                               "complete_within_floor_sigmas": COMPLETE_SIGMAS},
        "chain_order": list(CHAIN_ORDER),
        "diagnostics": {"signal_bins": [b if b < 1e8 else None for b in SIGNAL_BINS],
                        "n_probes": int(sum(len(p) for p in probes)),
                        "baseline": json_diagnostics(baseline), "final": json_diagnostics(final)},
    }
    gaps = [baseline["gap"]] + [s["gap_after"] for s in steps]
    return Discovery(report, model, baseline, final, gaps)


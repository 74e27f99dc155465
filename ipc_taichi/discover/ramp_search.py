"""Name what a ramp file's time structure shows and the frame model lacks:
``persistence``, ``dark_current``, ``correlated_read_noise``, ``bias_drift``,
``random_telegraph_noise`` (:mod:`.ramp_effects`) and the frame effects
``brighter_fatter``, ``signal_dependent_ipc``, ``classical_nonlinearity`` and
the IPC geometry terms (``diagonal_ipc``, ``anisotropic_ipc``,
``second_neighbor_ipc``) evaluated read by read (:mod:`.ramp_chain`), on top of
the frame model read by read (:mod:`.ramps`).

Procedure (:func:`discover_ramps`)
----------------------------------
1. The starting model (the header's, or ``start``) and its gap from the
   whitened increments with its floor (:func:`~.ramps.ramp_gap`).
2. Each ramp effect not in the model is fitted to the increments, the rest
   of the model fixed:

   - ``persistence``: ``tau`` scanned on a geometric grid (then refined),
     ``fraction`` by weighted least squares at each ``tau`` (the after-image
     is linear in it), the increments whitened by the current model's
     covariance; evidence ``delta chi^2 - 2 ln n``.
   - ``dark_current``: the rate by weighted least squares (the dark charge
     is linear in it), and again from the pixels above and at or under the
     median SCENE apart (its contradiction); evidence ``delta chi^2 - ln n``.
   - ``correlated_read_noise``: the means over each row (column) of the
     increments' residuals, read by read; their variance beyond what the
     pixels' own noise gives, ``2 q`` (a shared offset enters two
     increments), is the moment estimate of ``q``; evidence the Gaussian
     deviance of those means with and without ``q``, less ``ln n`` per
     parameter; the adjacent columns' correlation from the lag-1
     covariance of the columns' means.
   - ``bias_drift``: the same from the frame's means of the residuals, read
     by read (the rows' and columns' means are then taken less the frame's).
   - ``random_telegraph_noise``: the pixels whose whitened increments lie
     in the ``1e-4`` chi-square tail, when chance (Poisson) gives as many
     with a probability under that of 5 sigma; each is given its own
     levels (one parameter per pixel), evidence its chi-square excess over
     its degrees of freedom less
     ``ln n`` per pixel; ``jump_e`` the median of their largest departures.
   - ``brighter_fatter``, ``signal_dependent_ipc`` (on a constant law),
     ``classical_nonlinearity``, and the geometry terms (on a law with a
     nearest coupling, ``alpha(0, 0) > 0``): least squares of the whitened
     increments (:func:`~.ramp_chain.fit_frame_effect`), evidence
     ``delta chi^2 - k ln n``; their contradictions, ranges and signatures
     (:func:`~.ramp_chain.signature_refusal`: a rescaled coupling is not
     anisotropy) are the frame vocabulary's, and brighter-fatter and
     signal-dependent IPC are judged against each other
     (:func:`~.ramp_chain.rival_contradiction`).

3. A candidate is named when its evidence passes the threshold (25), its fit
   does not contradict the effect and lies inside its physical range
   (:meth:`~.ramp_effects.RampEffect.contradiction`,
   :meth:`~.ramp_effects.RampEffect.implausible`), and once added it removes at
   least 25 % of the gap's excess over the floor and does not leave the gap
   more than 3 floor scatters below its floor (the frames' rules). The
   strongest such one is added; the search repeats until the gap lies within
   3 floor scatters of the floor or nothing qualifies.

The other frame effects (diffusion, reciprocity, misregistration, flat
field...) are not searched on ramps: a ramp file's starting model carries
them from a coupling-model file (``start``) or not at all.
"""

import math

import numpy as np

from ..model import CouplingModel
from .effects import EFFECTS, contradiction, implausible
from .model import DetectorModel
from .ramp_chain import fit_frame_effect, offered, rival_contradiction, signature_refusal
from .ramp_effects import RAMP_EFFECTS
from .ramps import RampData, RampModel, ramp_gap, read_ramps

__all__ = ["discover_ramps", "fit_ramp_effect"]

THRESHOLD = 25.0  # delta BIC, as for frames
MIN_EXPLAINED_FRACTION = 0.25


def fit_ramp_effect(name, model, ramps, ln_n):
    """One ramp effect fitted to ``ramps`` beside ``model``: ``(params,
    evidence, new model, extra)`` with ``extra`` what the gates need; ``None``
    when there is nothing to fit (:meth:`~.ramp_effects.RampEffect.fit`)."""
    return RAMP_EFFECTS[name].fit(model, ramps, ln_n)


def _trials(model, ramps, data, ln_n, threshold, refused, say, stats=None):
    """Every effect not in ``model`` fitted beside it: ``{name: (evidence,
    params, new model)}`` of those no gate refuses (refusals of candidates
    above ``threshold`` go into ``refused``, with why)."""
    duration = float(ramps[0].times[-1])
    fitted = {}
    for name, effect in RAMP_EFFECTS.items():
        if name in model.effects:
            continue
        found = effect.fit(model, ramps, ln_n)
        if found is not None:
            params, evidence, newer, extra = found
            fitted[name] = (evidence, params, newer, effect.contradiction(params, extra)
                            or effect.implausible(params, data.readnoise, duration=duration), {})
    for name in offered(model):
        params, evidence, newer, fit = fit_frame_effect(name, model, ramps, ln_n, cross=stats)
        fitted[name] = (evidence, params, newer, contradiction(name, params)
                        or implausible(name, params, data.readnoise)
                        or signature_refusal(name, fit), _fit_extras(name, params, fit))
    evidence = {name: f[0] for name, f in fitted.items()}
    trials = {}
    for name, (ev, params, newer, why, extras) in fitted.items():
        why = why or (rival_contradiction(name, evidence, threshold) if ev > threshold
                      else None)
        say(f"candidate {name}: delta BIC {ev:.1f} {params}" + (f" ({why})" if why else ""))
        if why:
            if ev > threshold:
                refused[name] = why
            continue
        trials[name] = (ev, params, newer, extras)
    return trials


def _fit_extras(name, params, fit):
    """A frame effect's step extras: its fitted parameters' ``uncertainties``
    and, for an effect whose record reports a section (brighter-fatter's
    kernel and its errors), that section under its name."""
    out = {"uncertainties": {key: float(fit.errors[(name, key)]) for _, key in fit.keys}}
    record = EFFECTS[name]
    if record.reports_section:
        order = [p.name for p in record.params]
        cov = np.zeros((len(order), len(order)))
        at = [order.index(key) for _, key in fit.keys]
        cov[np.ix_(at, at)] = fit.cov
        out[name] = record.report_section(params, cov, "fitted to the ramps")
    return out


_TIME_KEYS = ("gap", "gap_per_read", "neighbour_correlation", "gap_per_read_floor",
              "neighbour_floor", "cross_read",
              "cross_read_floor")  # kept for the baseline and each step (the figures)


def _verdict(stats):
    return {key: stats[key] for key in ("gap", "gap_floor", "gap_floor_sigma", "complete")}


def _starting_model(data, start):
    """The frame model read by read: the header's, a
    :class:`~.model.DetectorModel`, or a coupling-model file's
    (:meth:`~.model.DetectorModel.from_coupling`, its measured sections included)."""
    if start is None:
        return data.model()
    if isinstance(start, DetectorModel):
        return start
    coupling, document = CouplingModel.load(start, with_document=True)
    return DetectorModel.from_coupling(coupling, data.readnoise, data.shot_noise, document)


def discover_ramps(data, seed=0, n_sim=8, threshold=THRESHOLD, max_steps=3, start=None,
                   log=None):
    """Find the ramp effects missing from the starting model of a ramp file
    (module docstring); ``start`` replaces the header's model
    (:func:`_starting_model`). Returns the report (``docs/discovery_format.md``):
    ``baseline_gap``, ``gap_floor``, ``gap_floor_sigma``, ``steps``,
    ``missing_effects``, ``final_gap``, ``complete``, ``unexplained``, and
    ``not_named`` (the fitted candidates refused, with why)."""
    data = data if isinstance(data, RampData) else read_ramps(data)
    say = log or (lambda line: None)
    model = RampModel(_starting_model(data, start))
    ramps = data.ramps
    stats = ramp_gap(data, model, n_sim, seed)
    baseline, steps, refused = stats["gap"], [], {}
    first = {key: stats[key] for key in _TIME_KEYS}
    ln_n = math.log(sum(r.valid.sum() * len(r.times) for r in ramps))
    while not stats["complete"] and len(steps) < max_steps:
        trials = _trials(model, ramps, data, ln_n, threshold, refused, say, stats)
        best = max(trials, key=lambda n: trials[n][0], default=None)
        if best is None or trials[best][0] <= threshold:
            break
        evidence, params, newer, extras = trials[best]
        after = ramp_gap(data, newer, n_sim, seed + len(steps) + 1)
        excess = stats["gap"] - stats["gap_floor"]
        fraction = (stats["gap"] - after["gap"]) / excess if excess > 0 else None
        if excess > 3 * stats["gap_floor_sigma"] and (fraction or 0) < MIN_EXPLAINED_FRACTION:
            refused[best] = f"it would remove only {100 * (fraction or 0):.1f} % of the excess"
            break
        below = (after["gap_floor"] - after["gap"]) / max(after["gap_floor_sigma"], 1e-12)
        if below > 3.0:  # the frames' rule: a variance inflated to absorb a wrong mean
            refused[best] = (f"it would leave the gap {below:.1f} floor scatters below its "
                             "floor: a variance inflated to absorb a mis-modelled mean")
            break
        steps.append({"effect": best, "params": params, **extras, "evidence": evidence,
                      "evidence_kind": "delta_BIC", "gap_before": stats["gap"],
                      "gap_after": after["gap"], "explained_fraction": fraction,
                      "floor_before": stats["gap_floor"],
                      **{key: after[key] for key in _TIME_KEYS}})
        say(f"added {best}: gap {stats['gap']:.4f} -> {after['gap']:.4f}")
        model, stats = newer, after
    unexplained = [] if stats["complete"] else stats["unexplained"] + [
        f"not named {n}: {why}" for n, why in refused.items()]
    return {"input": data.path, "baseline_gap": baseline, "gap_floor": stats["gap_floor"],
            "gap_floor_sigma": stats["gap_floor_sigma"], "steps": steps,
            "missing_effects": [s["effect"] for s in steps], "final_gap": stats["gap"],
            "complete": stats["complete"], "unexplained": unexplained,
            "not_named": refused, "gap_per_read": stats["gap_per_read"],
            "neighbour_correlation": stats["neighbour_correlation"],
            "gap_per_read_floor": stats["gap_per_read_floor"],
            "neighbour_floor": stats["neighbour_floor"],
            "baseline": first,
            "final_model": {"frame": model.frame.describe(), "effects": model.effects,
                            "own_level_pixels": 0 if model.odd is None
                            else int(model.odd.sum())}}

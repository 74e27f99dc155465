"""Name the missing effect: fit each candidate, weigh the evidence, add, repeat.

Procedure (:func:`discover`)
----------------------------
1. Start from the model the file's header describes (law ``IPCLAW``, read
   noise, shot noise, nothing else) and compute the baseline gap.
2. For every effect of the vocabulary not yet in the model, fit its
   parameters (starting "off"; the rest of the model fixed; the variance of
   the current model held fixed, so chi-squares compare) and compute the
   evidence ``delta BIC = delta chi2 - k ln n`` (``k`` parameters, ``n``
   valid pixels). ``signal_dependent_ipc`` is a candidate only while the law
   is constant.
3. The best candidate is added when it is significant: ``delta BIC >``
   :data:`EVIDENCE_THRESHOLD` (25; null simulations give about -10, the
   ``-ln n`` of one parameter fitted to noise) **and**, after the first step,
   its ``delta chi2`` is at least :data:`RELATIVE_EVIDENCE` (2 %) of the
   chi-square the earlier steps removed: a model that names the main effect
   with a slightly different functional form than whatever made the data
   leaves a structured residual in proportion to that effect, which should
   not be named as a second effect. ``anisotropic_ipc`` and
   ``signal_dependent_ipc`` must also show their own signature at 5 sigma
   (see :func:`_signature`). Candidates whose evidence reaches half the
   best one's are reported as near-degenerate alternatives, with what
   tells them apart.
4. All parameters of the model are refitted together (twice, updating the
   propagated variance in between) and the loop repeats until no candidate
   is significant.
5. The noise floor: the final model simulated with fresh noise
   :data:`FLOOR_SIMULATIONS` times, the gap of each against the same
   prediction; its mean and standard deviation.

Uncertainties are from the Gauss-Newton covariance ``(J^T J)^-1`` of the
whitened residuals, inflated by the reduced chi-square when it exceeds 1.
"""

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ..errors import GeometryError, IPCInputError, LawError
from .diagnostics import (fill_scene, find_probes, gap, residual, residual_vs_signal,
                          stacked_windows, valid_mask)
from .effects import EFFECTS, SEPARATION, derived_params
from .labdata import LabData, read_lab
from .model import CHAIN_ORDER, DetectorModel, is_constant_law

__all__ = ["discover", "Discovery", "Frames", "fit_parameters", "EVIDENCE_THRESHOLD",
           "RELATIVE_EVIDENCE", "FLOOR_SIMULATIONS", "MAX_STEPS"]

EVIDENCE_THRESHOLD = 25.0  # delta BIC; null simulations give < 0 (see docs/discover.md)
RELATIVE_EVIDENCE = 0.02  # a later effect must explain 2 % of what earlier ones did
FLOOR_SIMULATIONS = 24
MAX_STEPS = 4
ALTERNATIVE_RATIO = 0.5
SIGNATURE_Z2 = 25.0  # an effect's own signature must be 5 sigma (see _signature)
_FAILED = 1e6  # whitened residual returned for a parameter set the engine rejects


@dataclass
class Frames:
    """Prepared data: same-shape pairs stacked into 3-D blocks."""

    scenes: list
    measured: list
    valid: list
    n: int

    @classmethod
    def from_lab(cls, lab):
        groups = {}
        for ver, scene, measured in lab.pairs:
            valid = valid_mask(scene, measured)
            if not valid.any():
                raise IPCInputError(f"{lab.path}[MEASURED,{ver}]: no valid pixel left after "
                                    "masking NaNs and the border")
            groups.setdefault(scene.shape, []).append(
                (fill_scene(scene), np.where(valid, measured, 0.0), valid))
        scenes, measured, valid = [], [], []
        for items in groups.values():
            scenes.append(np.stack([s for s, _, _ in items]))
            measured.append(np.stack([m for _, m, _ in items]))
            valid.append(np.stack([v for _, _, v in items]))
        return cls(scenes, measured, valid, int(sum(v.sum() for v in valid)))

    def predict(self, model):
        return [model.predict(s) for s in self.scenes]

    def whitened(self, model, sds):
        """Residual vector ``(M - mean) / sd`` over valid pixels, ``sds`` fixed."""
        parts = []
        for s, m, v, sd in zip(self.scenes, self.measured, self.valid, sds):
            parts.append(((m - model.expected(s)) / sd)[v])
        return np.concatenate(parts)

    def residuals(self, model, predictions=None):
        """Per-frame residual maps (NaN outside valid) and expected means."""
        predictions = predictions or self.predict(model)
        res, means = [], []
        for (mean, var), m, v in zip(predictions, self.measured, self.valid):
            res.extend(residual(m, mean, var, v))
            means.extend(mean)
        return res, means

    def floor(self, model, rng, n_sim, predictions=None):
        """Gap of ``n_sim`` fresh simulations of ``model`` against its own prediction."""
        predictions = predictions or self.predict(model)
        gaps = []
        for _ in range(n_sim):
            res = []
            for s, v, (mean, var) in zip(self.scenes, self.valid, predictions):
                res.extend(residual(model.simulate(s, rng), mean, var, v))
            gaps.append(gap(res))
        return float(np.mean(gaps)), float(np.std(gaps, ddof=1)) if n_sim > 1 else 0.0


@dataclass
class FitResult:
    model: DetectorModel
    chi2: float
    values: dict            # {(effect, param): value}
    errors: dict            # {(effect, param): 1-sigma}
    cov: np.ndarray
    keys: list
    nfev: int = 0


def _with_values(model, keys, x):
    changes = {}
    for (effect, name), value in zip(keys, x):
        changes.setdefault(effect, dict(model.effects.get(effect, {})))[name] = float(value)
    return model.with_effects(changes)


def fit_parameters(frames, model, keys, sds, max_nfev=40):
    """Least-squares fit of the parameters ``keys`` = ``[(effect, param), ...]``.

    The other parameters and the noise (``sds``, per block) stay fixed.
    """
    specs = [next(p for p in EFFECTS[e].params if p.name == n) for e, n in keys]
    x0 = np.array([model.effects[e][n] for e, n in keys], dtype=np.float64)
    lower = np.array([p.lower for p in specs])
    upper = np.array([p.upper for p in specs])
    scale = np.array([p.scale for p in specs])
    cache = {}

    def resid(x):
        key = tuple(np.round(x, 15))
        if key not in cache:
            try:
                r = frames.whitened(_with_values(model, keys, x), sds)
            except (LawError, GeometryError):
                r = np.full(frames.n, _FAILED)
            if len(cache) > 64:
                cache.clear()
            cache[key] = r
        return cache[key]

    def jac(x):
        f0 = resid(x)
        cols = []
        for i in range(len(x)):
            h = 0.01 * scale[i]
            if x[i] + h > upper[i]:
                h = -h
            xp = x.copy()
            xp[i] += h
            cols.append((resid(xp) - f0) / h)
        return np.column_stack(cols)

    # parameters whose "off" value is a flat point (a blur width) start from the best seed
    for i, p in enumerate(specs):
        if p.seeds and x0[i] == p.off:
            trials = [x0[i], *p.seeds]
            costs = []
            for t in trials:
                xt = x0.copy()
                xt[i] = t
                costs.append(float(np.sum(resid(xt) ** 2)))
            x0[i] = trials[int(np.argmin(costs))]
    x0 = np.clip(x0, lower, upper)
    res = least_squares(resid, x0, jac=jac, bounds=(lower, upper), x_scale=scale,
                        method="trf", xtol=1e-6, ftol=1e-9, gtol=1e-10, max_nfev=max_nfev)
    chi2 = float(np.sum(res.fun ** 2))
    jm = jac(res.x)
    dof = max(frames.n - len(keys), 1)
    try:
        cov = np.linalg.inv(jm.T @ jm) * max(1.0, chi2 / dof)
    except np.linalg.LinAlgError:
        cov = np.full((len(keys), len(keys)), np.inf)
    errors = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return FitResult(_with_values(model, keys, res.x), chi2,
                     dict(zip(keys, map(float, res.x))), dict(zip(keys, map(float, errors))),
                     cov, list(keys), res.nfev)


def _sds(frames, model):
    return [np.sqrt(var) for _, var in frames.predict(model)]


def _chi2(frames, model, sds):
    r = frames.whitened(model, sds)
    return float(r @ r)


def _candidates(model):
    out = []
    for name in EFFECTS:
        if name in model.effects:
            continue
        if name == "signal_dependent_ipc" and not is_constant_law(model.law):
            continue
        out.append(name)
    return out


def _signature(name, fit):
    """Squared significance of what makes ``name`` that effect, not a rescaled IPC.

    A rescaled coupling (``weight_horizontal = weight_vertical != 1``, or a
    constant law with a new floor) would otherwise pass for anisotropy or
    signal dependence whenever anything adds nearest-neighbour charge (e.g.
    diffusion). The signature is the anisotropy for ``anisotropic_ipc``, the
    two amplitudes jointly for ``signal_dependent_ipc``; for one-parameter
    effects, and for the non-linearity, the evidence itself is the signature.
    """
    if name == "anisotropic_ipc":
        params, errors = _params_report(fit, name)
        sigma = errors["anisotropy"]
        return (params["anisotropy"] / sigma) ** 2 if sigma > 0 else math.inf
    if name == "signal_dependent_ipc":
        idx = [fit.keys.index((name, "amp_diff")), fit.keys.index((name, "amp_level"))]
        a = np.array([fit.values[fit.keys[i]] for i in idx])
        try:
            return float(a @ np.linalg.solve(fit.cov[np.ix_(idx, idx)], a))
        except np.linalg.LinAlgError:
            return 0.0
    return math.inf


def _refit_all(frames, model, passes=2):
    """Refit every parameter of the model, updating the propagated variance between passes."""
    keys = [(e, p.name) for e in model.effects for p in EFFECTS[e].params]
    result = None
    for _ in range(passes):
        sds = _sds(frames, model)
        result = fit_parameters(frames, model, keys, sds, max_nfev=60)
        model = result.model
    return result


def _params_report(result, effect):
    keys = [k for k in result.keys if k[0] == effect]
    params = {n: result.values[(e, n)] for e, n in keys}
    errors = {n: result.errors[(e, n)] for e, n in keys}
    idx = [result.keys.index(k) for k in keys]
    extra, extra_err = derived_params(effect, params, cov=result.cov[np.ix_(idx, idx)])
    params.update(extra)
    errors.update(extra_err)
    return params, errors


@dataclass
class Discovery:
    """The outcome of :func:`discover`: the JSON-ready ``report`` and the
    arrays the figures need (``baseline`` and ``final`` diagnostics)."""

    report: dict
    model: DetectorModel
    baseline: dict = field(repr=False, default_factory=dict)
    final: dict = field(repr=False, default_factory=dict)
    gaps: list = field(default_factory=list)


def _diagnostics(frames, model, probes, predictions=None):
    res, means = frames.residuals(model, predictions)
    stacks, counts = stacked_windows(res, probes)
    centres, mean_r, mean_r2, n = residual_vs_signal(res, means)
    return {"residuals": res, "means": means, "stacks": stacks, "counts": counts,
            "signal": centres, "mean_residual": mean_r, "mean_residual2": mean_r2,
            "signal_counts": n, "gap": gap(res)}


def _json_diag(d):
    def clean(a):
        return [None if not np.isfinite(v) else round(float(v), 4) for v in np.ravel(a)]

    return {"stack_mean_residual": [[clean(row) for row in s] for s in d["stacks"]],
            "stack_counts": [int(c) for c in d["counts"]],
            "signal_bin_centres": clean(d["signal"]),
            "mean_residual_vs_signal": clean(d["mean_residual"]),
            "pixels_per_signal_bin": [int(c) for c in d["signal_counts"]]}


def discover(data, seed=0, threshold=EVIDENCE_THRESHOLD, max_steps=MAX_STEPS,
             floor_simulations=FLOOR_SIMULATIONS, log=None):
    """Find the effects missing from the starting model of a lab file.

    Parameters
    ----------
    data : str or LabData
        A lab FITS file (``DISCOVERY_FORMAT.md``) or its :func:`read_lab` result.
    seed : int
        Seed of the noise-floor simulations.
    threshold : float
        Minimum delta BIC for an effect to be added.
    log : callable, optional
        Called with one progress line per step.

    Returns
    -------
    Discovery
        ``.report`` is the JSON report (``baseline_gap``, ``steps``,
        ``missing_effects``, ``final_gap``, ``gap_floor``, ``gap_floor_sigma``, ...).
    """
    lab = data if isinstance(data, LabData) else read_lab(data)
    if lab.readnoise == 0 and not lab.shot_noise:
        raise IPCInputError(f"{lab.path}[PRIMARY]: READNOIS = 0 with SHOTNOIS = F leaves no "
                            "noise to weigh residuals by")
    say = log or (lambda line: None)
    frames = Frames.from_lab(lab)
    rng = np.random.default_rng(seed)
    ln_n = math.log(frames.n)
    probes = [find_probes(s, v) for block_s, block_v in zip(frames.scenes, frames.valid)
              for s, v in zip(block_s, block_v)]
    model = lab.model()
    predictions = frames.predict(model)
    baseline = _diagnostics(frames, model, probes, predictions)
    current_gap = baseline["gap"]
    say(f"baseline gap {current_gap:.4f} over {frames.n} pixels ({model.describe()})")
    steps, final_fit, stop = [], None, None
    while len(steps) < max_steps:
        floor, floor_sigma = frames.floor(model, rng, max(4, floor_simulations // 3), predictions)
        sds = [np.sqrt(var) for _, var in predictions]
        chi2_now = _chi2(frames, model, sds)
        if not steps:
            chi2_baseline = chi2_now
        trials = {}
        for name in _candidates(model):
            trial = model.with_effects({name: model.starting_params(name)})
            keys = [(name, p.name) for p in EFFECTS[name].params]
            fit = fit_parameters(frames, trial, keys, sds)
            k = len(keys)
            trials[name] = (chi2_now - fit.chi2 - k * ln_n, chi2_now - fit.chi2, k, fit)
        if not trials:
            stop = {"reason": "every effect of the vocabulary is in the model"}
            break
        # an effect is only named when its own signature is in the fit (see _signature)
        named = {n: t for n, t in trials.items() if _signature(n, t[3]) > SIGNATURE_Z2}
        best = max(named or trials, key=lambda n: trials[n][0])
        evidence, dchi2, k, fit = trials[best]
        above_floor = (current_gap - floor) / floor_sigma if floor_sigma > 0 else math.inf
        say("candidates: " + ", ".join(f"{n} {trials[n][0]:.1f}" for n in
                                       sorted(trials, key=lambda n: -trials[n][0])))
        explained = chi2_baseline - chi2_now
        if not (named and evidence > threshold and dchi2 > RELATIVE_EVIDENCE * explained):
            why = ("" if named else "no candidate shows its own signature; ") + (
                   f"best candidate {best} has delta BIC {evidence:.1f} "
                   f"(threshold {threshold:g}) and delta chi2 {dchi2:.1f} "
                   f"(needs {RELATIVE_EVIDENCE:g} x {explained:.1f} explained so far); gap "
                   f"{current_gap:.4f} is {above_floor:.1f} scatters above the floor {floor:.4f}")
            stop = {"reason": why, "best_candidate": best, "evidence": round(evidence, 2),
                    "gap_scatters_above_floor": round(above_floor, 2)}
            say("stop: " + why)
            break
        alternatives = []
        for name, (ev, dc, kk, f) in sorted(named.items(), key=lambda t: -t[1][0]):
            if name == best or ev < max(threshold, ALTERNATIVE_RATIO * evidence):
                continue
            params, errors = _params_report(f, name)
            alternatives.append({
                "effect": name, "evidence": round(ev, 2), "params": params,
                "uncertainties": errors,
                "separated_by": SEPARATION.get(frozenset({best, name}),
                                               "the stacked windows per signal bin")})
        final_fit = _refit_all(frames, fit.model)
        model = final_fit.model
        predictions = frames.predict(model)
        gap_after = gap(frames.residuals(model, predictions)[0])
        params, errors = _params_report(final_fit, best)
        steps.append({"effect": best, "params": params, "uncertainties": errors,
                      "gap_before": current_gap, "gap_after": gap_after,
                      "evidence": evidence, "evidence_kind": "delta_BIC",
                      "delta_chi2": dchi2, "n_params": k,
                      "floor_before": floor, "floor_sigma_before": floor_sigma,
                      "alternatives": alternatives,
                      "candidates": {n: round(t[0], 2) for n, t in trials.items()},
                      "without_signature": sorted(set(trials) - set(named))})
        say(f"added {best}: delta BIC {evidence:.1f}, gap {current_gap:.4f} -> {gap_after:.4f}")
        current_gap = gap_after
    floor, floor_sigma = frames.floor(model, rng, floor_simulations, predictions)
    final = _diagnostics(frames, model, probes, predictions)
    final_params = {}
    final_errors = {}
    if final_fit is not None:
        for e in model.effects:
            final_params[e], final_errors[e] = _params_report(final_fit, e)
    report = {
        "input": lab.path,
        "readnoise": lab.readnoise,
        "shot_noise": lab.shot_noise,
        "ipclaw": lab.law,
        "gap_statistic": "mean over valid pixels of ((MEASURED - mean)/sd)^2, mean and sd "
                         "the model's prediction of SCENE with shot and read noise propagated",
        "n_pixels": frames.n,
        "n_pairs": len(lab.pairs),
        "baseline_gap": baseline["gap"],
        "gap_floor": floor,
        "gap_floor_sigma": floor_sigma,
        "floor_simulations": floor_simulations,
        "steps": steps,
        "missing_effects": [s["effect"] for s in steps],
        "final_gap": current_gap,
        "final_model": {"law": model.ipc_law().describe(), "effects": final_params,
                        "uncertainties": final_errors},
        "stop": stop,
        "evidence_threshold": {"delta_bic": threshold,
                               "fraction_of_explained_chi2": RELATIVE_EVIDENCE},
        "chain_order": list(CHAIN_ORDER),
        "diagnostics": {"signal_bins": [1000.0, 4000.0, 12000.0, 30000.0, None],
                        "n_probes": int(sum(len(p) for p in probes)),
                        "baseline": _json_diag(baseline), "final": _json_diag(final)},
    }
    gaps = [baseline["gap"]] + [s["gap_after"] for s in steps]
    return Discovery(report, model, baseline, final, gaps)

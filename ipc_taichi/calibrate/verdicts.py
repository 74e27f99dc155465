"""What held-out data decide: the law written, non-linear IPC claimed, an
empty check explained.

Calibrate fits laws on some hot pixels and tests them on others
(:mod:`.transfer`); these rules turn the tests into the model's choices and
the console's words, each written once.
"""

import numpy as np

from . import lawfit

__all__ = ["transfer_supports", "constant_unless_better", "say_why_empty", "nonlinear_ipc"]


def transfer_supports(transfer_check):
    """Whether the held-out transfer check (:mod:`.transfer`) finds the chosen
    law correcting held-out hot pixels better than the best constant (their
    residuals apart by more than twice their combined error); None when
    there is no check."""
    if not transfer_check:
        return None
    chosen, constant = transfer_check.get("chosen") or {}, transfer_check.get("constant") or {}
    if chosen.get("residual") is None or constant.get("residual") is None:
        return None
    error = float(np.hypot(chosen.get("error") or 0.0, constant.get("error") or 0.0))
    return abs(constant["residual"]) - abs(chosen["residual"]) > 2.0 * error


def constant_unless_better(fit, check, points_for, law, geometry):
    """A law richer than a constant is kept only when its held-out hot-pixel
    residual beats the constant's (smaller in size); otherwise the constant
    fitted on every point is written and the fit says why."""
    if fit["chosen"] == "constant" or not check:
        return law, geometry
    rc, rk = check["chosen"]["residual"], check["constant"]["residual"]
    if rc is None or rk is None or abs(rc) < abs(rk):
        return law, geometry
    full = lawfit.fit_forms(*points_for(None))
    geometry, law = lawfit.model_of(full, "constant")
    note = (f"the held-out folds chose {fit['chosen']}, but on held-out hot pixels its "
            f"residual ({100 * rc:+.4f} %) does not beat the constant's ({100 * rk:+.4f} %): "
            "the constant is written")
    fit["notes"] = list(fit.get("notes") or []) + [note]
    fit["law_choice"] = {**(fit.get("law_choice") or {}), "demoted": fit["chosen"],
                         "demoted_note": note}
    fit["chosen"], fit["law"] = "constant", law.describe()
    return law, geometry


def say_why_empty(check, hot, darks, not_measured):
    """The held-out check is never silently empty: why, and what would make it possible."""
    if not darks or (check and check["chosen"]["n_pixels"] > 0):
        return
    floor = hot.floors["score"]
    above = 0
    if hot.events is not None:
        ids = np.unique(hot.events["pixel"][hot.events["signal"] >= floor])
        above = ids.size
    not_measured.append(
        f"held-out check: empty ({hot.found} hot-pixel candidates, {above} reach the floor of "
        f"{floor:.4g} e- = {hot.floors['source']}; each half needs hot pixels in every "
        "signal bin to fit the law): darks with more or brighter hot pixels (longer "
        "integrations) would make it possible")


def nonlinear_ipc(fit, ramp_evidence, transfer_check=None):
    """Non-linear IPC is claimed where held-out data choose a law richer than
    a constant (brighter-fatter already removed from flat ramps) and the
    held-out transfer check, where there is one, does not find the best
    constant correcting as well; or where the flat ramps' joint fit finds the
    IPC terms changing with signal beside brighter-fatter; the second without
    the first is said: the law written then does not follow it."""
    choice = fit.get("law_choice") or {}
    chosen = fit.get("chosen")
    by_law = bool(choice) and chosen != "constant"
    confirms = transfer_supports(transfer_check) if by_law else None
    if confirms is False:
        by_law = False
        choice = dict(choice, unconfirmed=(
            f"the law choice prefers {chosen}, but on held-out hot pixels the best constant "
            "corrects as well (transfer check): not confirmed"))
    by_ramps = bool(ramp_evidence and ramp_evidence.get("detected"))
    margin = (choice.get("margin_against_constant") or {}).get(chosen) if by_law else None
    if not choice and not by_ramps:
        note = "not tested (no measured points)"
    elif by_law:
        note = (f"the law {chosen} predicts held-out data better than a constant by "
                f"{margin:.1f} standard errors")
    elif by_ramps:
        note = (f"the flat ramps' joint fit finds it beside brighter-fatter "
                f"({ramp_evidence['significance']:+.1f} sigma, "
                f"{ramp_evidence['slope_per_10ke']:+.3g} per 10 ke- in x + y), but the "
                "per-level points are too noisy for the law to follow it: the law written "
                "is a constant (more pixels or integrations would pin its shape)")
    else:
        note = choice.get("unconfirmed") or (
            f"the law choice preferred {choice['demoted']}, but on held-out hot pixels the "
            "best constant corrects as well (transfer check): not confirmed; the constant is "
            "written" if choice.get("demoted") else
            "a constant predicts held-out data as well as any signal-dependent law")
    return {"detected": by_law or by_ramps, "significance": margin, "law_follows": by_law,
            "note": note, "flat_ramps": ramp_evidence, "transfer_confirms": confirms}

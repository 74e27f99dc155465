"""The JSON report and the figures of a :class:`~.search.Discovery`.

:func:`assemble` puts the report together from the search's records
(:mod:`.records`); :func:`describe_unexplained` gives the words of what the
final model leaves. Report and figures are written atomically (a temporary
file renamed into place); the figures use matplotlib's Agg backend and need
no display.

Figures (in the ``--figures`` directory)
----------------------------------------
``gap_per_step.png``
    The gap after each step (baseline first) with the noise floor and its
    1 and 3 sigma bands.
``stacked_windows.png``
    Mean residual (noise units) in the 5x5 window around bright isolated
    scene peaks, one column per signal bin, baseline (top) and final model
    (bottom).
``residual_vs_signal.png``
    Mean residual of pixels binned by expected signal, baseline and final.
``residual_map.png``
    The residual map of the first frame, baseline and final.
``residuals_by_probe.png``
    Mean residual at the centres and surroundings of hot pixels and stars,
    inside flat patches and along their edges, baseline and final; and the
    chi-square per pixel against signal level with the floor's.
"""

import json
import math
import os

import numpy as np

from ..errors import IPCInputError
from ..fitsio import atomic_output
from .diagnostics import SIGNAL_BINS, UNEXPLAINED_Z
from .effects import EFFECTS, brighter_fatter_section, chain_order
from .fitting import params_report
from .gates import COMPLETE_SIGMAS, MIN_EXPLAINED_FRACTION, is_complete

__all__ = ["assemble", "write_report", "write_figures", "to_json", "summary_line",
           "json_diagnostics", "describe_unexplained", "brighter_fatter_section",
           "SUBPIXEL_LIMITS"]

FIGURES = ("gap_per_step.png", "stacked_windows.png", "residual_vs_signal.png",
           "residual_map.png", "residuals_by_probe.png")


def assemble(setting, state, stop, baseline, final, floor):
    """The JSON-ready report of a search.

    ``setting`` and ``state`` are the search's :class:`~.records.Setting` and
    final :class:`~.records.State`, ``stop`` its :class:`~.records.Stop`
    (``None`` when it ran out of steps), ``baseline`` and ``final`` the
    diagnostics of the starting and final models
    (:meth:`~.blocks.PairBlocks.diagnostics`), ``floor`` the final model's
    ``(gap floor, its scatter)``.
    """
    lab, model = setting.lab, state.model
    complete = is_complete(state.gap, *floor)
    return {
        **_head(setting),
        "baseline_gap": baseline["gap"],
        "gap_floor": floor[0],
        "gap_floor_sigma": floor[1],
        "floor_simulations": setting.floor_simulations,
        "steps": [s.as_dict() for s in state.steps],
        "missing_effects": [s.effect for s in state.steps if s.effect in model.effects],
        "pruned": [p.as_dict() for p in state.pruned],
        "final_gap": state.gap,
        "complete": complete,
        "unexplained": [] if complete else _unexplained(lab, state, final, floor),
        "final_model": _final_model(model, state.fit, lab.readnoise),
        "stop": None if stop is None else stop.as_dict(),
        **{e.name: _section(e, state, setting.seeded)
           for e in EFFECTS.values() if e.reports_section},
        "seeded_from_model_file": setting.seeded,
        "evidence_threshold": {"delta_bic": setting.threshold,
                               "min_explained_fraction": MIN_EXPLAINED_FRACTION,
                               "complete_within_floor_sigmas": COMPLETE_SIGMAS},
        "chain_order": list(chain_order()),
        "diagnostics": {"signal_bins": [b if b < 1e8 else None for b in SIGNAL_BINS],
                        "n_probes": int(sum(len(p) for p in setting.probes)),
                        "baseline": json_diagnostics(baseline), "final": json_diagnostics(final)},
    }


def _head(setting):
    """What the report says about its input."""
    lab = setting.lab
    return {"input": lab.path, "readnoise": lab.readnoise, "shot_noise": lab.shot_noise,
            "ipclaw": lab.law, "starting_model": setting.starting_model,
            "gap_statistic": "mean over valid pixels of ((MEASURED - mean)/sd)^2, mean and sd "
                             "the model's prediction of SCENE with shot and read noise "
                             "propagated",
            "n_pixels": setting.frames.n, "n_pairs": len(lab.pairs),
            "oversample": {str(p.extver): p.oversample for p in lab.pairs}}


def _unexplained(lab, state, final, floor):
    """:func:`describe_unexplained` of the final model."""
    pixel_totals = [p.extver for p in lab.pairs if p.oversample == 1]
    below = (floor[0] - state.gap) / floor[1] if floor[1] > 0 else 0.0
    return describe_unexplained(final, state.rejected, list(state.model.effects), pixel_totals,
                                len(lab.pairs), below)


def _final_model(model, fit, readnoise):
    """The report's ``final_model``: the law, and each effect's parameters and
    uncertainties from the last joint refit ``fit`` (none before a step)."""
    params, errors = {}, {}
    if fit is not None:
        for e in model.effects:
            params[e], errors[e] = params_report(fit, e, readnoise)
    return {"law": model.ipc_law().describe(), "effects": params, "uncertainties": errors}


def _section(record, state, seeded):
    """The report's section of an effect that has one (brighter-fatter: its
    kernel), ``None`` when the final model does not hold the effect."""
    model, fit, name = state.model, state.fit, record.name
    if name not in model.effects:
        return None
    params = model.effects[name]
    keys = [(name, p.name) for p in record.params]
    cov, source = None, "the model file's kernel, as discover's parameters (not refitted)"
    if fit is not None and all(k in fit.keys for k in keys):
        idx = [fit.keys.index(k) for k in keys]
        cov = fit.cov[np.ix_(idx, idx)]
        source = ("fitted" if any(s.effect == name for s in state.steps) else
                  "the model file's kernel, refitted with the effects named after it")
    elif name not in seeded:
        source = "fitted"
    return record.report_section(params, cov, source)


def summary_line(report):
    """One line for the terminal: the verdict in words, the effects named and the gap.

    An incomplete model says so first ("INCOMPLETE"), with the first
    description of what remains unexplained.
    """
    named = ", ".join(report["missing_effects"]) or "none"
    gaps = (f"gap {report['baseline_gap']:.4f} -> {report['final_gap']:.4f} (floor "
            f"{report['gap_floor']:.4f} +- {report['gap_floor_sigma']:.4f})")
    if report.get("complete"):
        return f"complete: missing effects {named}; {gaps}"
    left = report.get("unexplained") or ["no description"]
    return (f"INCOMPLETE: the model does not explain the data (final gap above the floor); "
            f"effects named {named}; {gaps}; unexplained: {left[0]}"
            + (f" (+{len(left) - 1} more in the report)" if len(left) > 1 else ""))


def to_json(obj):
    """Plain JSON types: numpy scalars and arrays converted, NaN/inf -> None."""
    if isinstance(obj, dict):
        return {str(k): to_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_json(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


def write_report(report, path, overwrite=False):
    """Write the report as JSON at ``path`` (atomic; refuses to replace without ``overwrite``)."""
    text = json.dumps(to_json(report), indent=2, allow_nan=False)
    with atomic_output(path, overwrite) as tmp:
        with open(tmp, "w") as fh:
            fh.write(text + "\n")


def _save(fig, path):
    with atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, dpi=110, format="png", bbox_inches="tight")  # titles never clipped


def write_figures(discovery, directory):
    """Write the figures (:data:`FIGURES`) into ``directory`` (created if
    missing); return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if os.path.exists(directory) and not os.path.isdir(directory):
        raise IPCInputError(f"{directory}: exists and is not a directory")
    os.makedirs(directory, exist_ok=True)
    paths = [os.path.join(directory, name) for name in FIGURES]
    for path, draw in zip(paths, (_gap_figure, _stacks_figure, _signal_figure, _maps_figure,
                                  _probe_figure)):
        fig = draw(plt, discovery)
        _save(fig, path)
        plt.close(fig)
    return paths


def _gap_figure(plt, discovery):
    """The gap after each step against the noise floor."""
    rep = discovery.report
    fig, ax = plt.subplots(figsize=(6, 4))
    labels = ["baseline"] + ["+ " + s["effect"] for s in rep["steps"]]
    x = np.arange(len(labels))
    floor, sig = rep["gap_floor"], rep["gap_floor_sigma"]
    ax.axhspan(floor - 3 * sig, floor + 3 * sig, color="0.9", label="floor +- 3 sigma")
    ax.axhspan(floor - sig, floor + sig, color="0.75", label="floor +- 1 sigma")
    ax.axhline(floor, color="0.4", lw=1)
    ax.plot(x, discovery.gaps, "o-", color="C3", label="gap (data)")
    ax.set_xticks(x, labels, rotation=20, ha="right")
    if max(discovery.gaps) > 3 * max(floor, 1e-9):  # e.g. a strong blur: gaps of 50
        from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

        ax.set_yscale("log")
        # labels at 1, 2, 5 per decade; unlabelled minor ticks (labelled ones pile up)
        ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(ScalarFormatter())
        ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_ylabel("gap: mean chi-square per pixel")
    ax.set_title("Model-data gap after each added effect")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _stacks_figure(plt, discovery):
    """The stacked 5x5 windows per signal bin, baseline and final."""
    nb = len(SIGNAL_BINS) - 1
    fig, axes = plt.subplots(2, nb, figsize=(2.9 * nb, 6.0), squeeze=False,
                             layout="constrained")
    stacks = [discovery.baseline["stacks"], discovery.final["stacks"]]
    lim = max(1.0, float(np.nanmax(np.abs(stacks[0]))) if np.isfinite(stacks[0]).any() else 1.0)
    for row, (title, st, counts) in enumerate((
            ("baseline", stacks[0], discovery.baseline["counts"]),
            ("final", stacks[1], discovery.final["counts"]))):
        for k in range(nb):
            ax = axes[row, k]
            im = ax.imshow(st[k], cmap="RdBu_r", vmin=-lim, vmax=lim, origin="lower",
                           extent=(-2.5, 2.5, -2.5, 2.5))
            hi = f"{SIGNAL_BINS[k + 1] / 1e3:g}k" if SIGNAL_BINS[k + 1] < 1e8 else "max"
            ax.set_title(f"{title}: {SIGNAL_BINS[k] / 1e3:g}k-{hi} e-\n{counts[k]} peaks",
                         fontsize=8)
            ax.set_xticks([-2, 0, 2])
            ax.set_yticks([-2, 0, 2])
            ax.tick_params(labelsize=7)
            if k == 0:
                ax.set_ylabel("dy [px]")
            else:
                ax.set_yticklabels([])  # "-2" would run into the next panel
            if row == 1:
                ax.set_xlabel("dx [px]")
            else:
                ax.set_xticklabels([])
    fig.colorbar(im, ax=axes, shrink=0.8, label="mean residual [sigma]")
    fig.suptitle("Mean residual around bright isolated peaks, by peak signal")
    return fig


def _signal_figure(plt, discovery):
    """The mean residual against expected signal."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, d, c in (("baseline", discovery.baseline, "C3"), ("final", discovery.final, "C0")):
        ok = d["signal_counts"] > 0
        err = 1.0 / np.sqrt(np.maximum(d["signal_counts"][ok], 1))
        ax.errorbar(d["signal"][ok], d["mean_residual"][ok], yerr=err, fmt="o-", color=c,
                    label=name, ms=3)
    ax.axhline(0, color="0.5", lw=1)
    ax.set_xscale("log")
    ax.set_xlabel("expected signal [e-]")
    ax.set_ylabel("mean residual [sigma]")
    ax.set_title("Residual vs signal level")
    ax.legend()
    fig.tight_layout()
    return fig


def _maps_figure(plt, discovery):
    """The residual maps of the first frame, baseline and final."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6), layout="constrained", sharey=True)
    for ax, (name, d) in zip(axes, (("baseline", discovery.baseline), ("final", discovery.final))):
        im = ax.imshow(d["residuals"][0], cmap="RdBu_r", vmin=-5, vmax=5, origin="lower",
                       interpolation="nearest")
        ax.set_title(f"{name}: residual, first pair")
        ax.set_xlabel("x [px]")
    axes[0].set_ylabel("y [px]")  # shared: one label, not two overlapping ones
    fig.colorbar(im, ax=axes, shrink=0.8, label="(measured - model) / sigma")
    return fig


def _probe_figure(plt, discovery):
    """The residuals by probe type, and the chi-square against signal."""
    from matplotlib.ticker import NullFormatter

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.4), layout="constrained")
    kinds = list(discovery.final["by_probe"])
    xs = np.arange(len(kinds))
    for j, (name, d, c) in enumerate((("baseline", discovery.baseline, "C3"),
                                      ("final", discovery.final, "C0"))):
        for where, marker, off in (("centre", "o", -0.15), ("ring", "s", 0.15)):
            vals = [d["by_probe"][k][where]["mean"] for k in kinds]
            ns = [d["by_probe"][k][where]["n"] for k in kinds]
            err = [1 / math.sqrt(n) if n else np.nan for n in ns]
            ax0.errorbar(xs + off + 0.05 * j, vals, yerr=err, fmt=marker, color=c, ms=4,
                         label=f"{name}, {'centres' if where == 'centre' else 'surroundings'}")
    ax0.axhline(0, color="0.5", lw=1)
    ax0.set_xticks(xs, [k.replace("_", " ") for k in kinds])
    ax0.set_ylabel("mean residual [sigma]")
    ax0.set_title("Residuals by probe type")
    ax0.legend(fontsize=7)
    for name, d, c in (("baseline", discovery.baseline, "C3"), ("final", discovery.final, "C0")):
        ok = d["signal_counts"] > 0
        ax1.plot(d["signal"][ok], d["mean_residual2"][ok], "o-", color=c, ms=3, label=name)
    fb = discovery.final.get("floor_chi2_vs_signal")
    if fb is not None:
        ok = np.isfinite(fb)
        ax1.plot(discovery.final["signal"][ok], fb[ok], "k--", lw=1, label="floor (simulated)")
    ax1.set_xscale("log")
    ax1.set_yscale("log")
    ax1.yaxis.set_minor_formatter(NullFormatter())
    ax1.set_xlabel("expected signal [e-]")
    ax1.set_ylabel("chi-square per pixel")
    ax1.set_title("Chi-square vs signal level (variance problems show here)")
    ax1.legend(fontsize=8)
    return fig


def json_diagnostics(d):
    def clean(a):
        return [None if not np.isfinite(v) else round(float(v), 4) for v in np.ravel(a)]

    def num(v):
        return None if not np.isfinite(v) else round(float(v), 4)

    out = {"stack_mean_residual": [[clean(row) for row in s] for s in d["stacks"]],
           "stack_counts": [int(c) for c in d["counts"]],
           "signal_bin_centres": clean(d["signal"]),
           "mean_residual_vs_signal": clean(d["mean_residual"]),
           "chi2_vs_signal": clean(d["mean_residual2"]),
           "pixels_per_signal_bin": [int(c) for c in d["signal_counts"]],
           "residuals_by_probe": {k: {w: {q: (num(x) if isinstance(x, float) else x)
                                          for q, x in part.items()}
                                      for w, part in v.items()}
                                  for k, v in d["by_probe"].items()},
           "dipole_x": {"mean": num(d["dipoles"]["x"][0]), "z": num(d["dipoles"]["x"][1])},
           "dipole_y": {"mean": num(d["dipoles"]["y"][0]), "z": num(d["dipoles"]["y"][1])},
           "after_image": {"mean": num(d["after_images"][0]), "z": num(d["after_images"][1]),
                           "n": d["after_images"][2]},
           "pair_correlation": {"mean": num(d["pair_correlation"][0]),
                                "z": num(d["pair_correlation"][1])}}
    if d.get("floor_chi2_vs_signal") is not None:
        out["floor_chi2_vs_signal"] = clean(d["floor_chi2_vs_signal"])
    return out


# What SCENE cannot tell the model, per effect in the final model: SCENE holds
# each pixel's integrated charge, not how the light lies within the pixel, and
# these effects move charge by less than a pixel (measured in docs/discover.md):
# each record's own words (Effect.subpixel), as shipped.
SUBPIXEL_LIMITS = {e.name: e.subpixel for e in EFFECTS.values() if e.subpixel}


def _moves_within(name):
    """Whether effect ``name`` moves charge by a fraction of a pixel (its
    :attr:`~.record.Effect.subpixel` words say what SCENE cannot tell it)."""
    return bool(getattr(EFFECTS.get(name), "subpixel", ""))


def describe_unexplained(d, rejected=(), effects=(), pixel_totals=None, n_pairs=None,
                         below_floor=0.0):
    """Words a detector scientist can act on for what the final model leaves.

    ``d`` is the final diagnostics (with ``floor_chi2_vs_signal``, the
    floor simulations' chi-square per signal bin); ``rejected`` the
    candidates that were fitted but not named, ``(effect, why)``;
    ``effects`` the final model's effects, whose known limits
    (:data:`SUBPIXEL_LIMITS`) are named where SCENE held pixel totals
    (``pixel_totals``: those pairs' EXTVER, ``None`` = all of the
    ``n_pairs``); ``below_floor`` the floor scatters by which the final gap
    lies *below* the floor (a variance inflated somewhere). Only patterns
    that stand out at :data:`~.diagnostics.UNEXPLAINED_Z` sigma are described.
    """
    out = []
    if below_floor > 3.0:
        out.append(f"the final gap lies {below_floor:.1f} floor scatters below the floor: the "
                   "model's variance is inflated (a variance effect absorbing a wrong mean, or "
                   "a noise parameter fitted too large)")
    n = d["signal_counts"]
    floor_bins = d.get("floor_chi2_vs_signal")
    expect = floor_bins if floor_bins is not None else np.ones(len(n))
    z_var = (d["mean_residual2"] - expect) / np.sqrt(2.0 / np.maximum(n, 1))
    z_mean = d["mean_residual"] * np.sqrt(np.maximum(n, 1))
    centres = d["signal"]
    ok = (n > 30) & np.isfinite(z_var) & np.isfinite(z_mean)
    for axis in ("x", "y"):
        m, z = d["dipoles"][axis]
        if np.isfinite(z) and abs(z) > UNEXPLAINED_Z:
            out.append(f"dipoles aligned with {axis} around every source (mean "
                       f"{m:+.2f} sigma per side): SCENE and MEASURED offset along {axis}?")
    m, z, cnt = d["after_images"]
    if np.isfinite(z) and z > UNEXPLAINED_Z:
        out.append(f"positive residual where the previous pair's SCENE was bright ({m:+.2f} "
                   f"sigma per pixel over {cnt} pixels, {z:.0f} standard errors): an "
                   "after-image of earlier exposures (persistence or another memory effect)")
    m, z = d["pair_correlation"]
    if np.isfinite(z) and z > UNEXPLAINED_Z:
        out.append(f"residuals repeat pixel by pixel across pairs (mean product {m:.3f}): "
                   "a fixed per-pixel pattern")
    if pixel_totals is None or pixel_totals:
        which = "" if pixel_totals is None or len(pixel_totals) == n_pairs else (
            " (pairs whose SCENE holds pixel totals, EXTVER "
            + ", ".join(str(v) for v in pixel_totals) + ")")
        out += [f"{name} is in the model, but {EFFECTS[name].subpixel}{which}"
                for name in effects if _moves_within(name)]
    var_bad = ok & (z_var > UNEXPLAINED_Z) & (np.abs(z_mean) < np.maximum(3.0, 0.3 * z_var))
    if var_bad.any():
        lo, hi = centres[var_bad].min(), centres[var_bad].max()
        low_only = hi < 3000
        shape = ("at low signal" if low_only else "growing with signal"
                 if z_var[var_bad][-1] > z_var[var_bad][0] else "across signal levels")
        out.append(f"variance excess {shape} ({lo:.0f}-{hi:.0f} e-; chi-square up to "
                   f"{np.nanmax(d['mean_residual2'][var_bad]):.2f} per pixel), zero mean")
    mean_bad = ok & (np.abs(z_mean) > UNEXPLAINED_Z)
    if mean_bad.any():
        sign = np.sign(np.sum(z_mean[mean_bad]))
        lo, hi = centres[mean_bad].min(), centres[mean_bad].max()
        out.append(f"mean residual {'positive' if sign > 0 else 'negative'} at "
                   f"{lo:.0f}-{hi:.0f} e- (measured {'above' if sign > 0 else 'below'} "
                   "the model there)")
    for kind, parts in d["by_probe"].items():
        c, r = parts["centre"], parts["ring"]
        for where, part in (("centres", c), ("surroundings", r)):
            if part["n"] > 5 and np.isfinite(part["z"]) and abs(part["z"]) > UNEXPLAINED_Z:
                out.append(f"{kind.replace('_', ' ')}: {where} {part['mean']:+.2f} sigma on "
                           f"average ({part['n']} pixels, chi-square {part['chi2']:.2f})")
    totals = pixel_totals is None or bool(pixel_totals)
    for name, why in rejected:
        # an effect that moves charge by a fraction of a pixel, fitted from pixel
        # totals, may be absorbing where the light lies: say what would tell
        hint = ("; its fit from pixel-total SCENEs may absorb how the light lies within "
                "each pixel (it moves charge by a fraction of a pixel): a SCENE with "
                "OVERSAMP would let it be judged" if totals and _moves_within(name)
                and "pixel-total" not in why else "")
        out.append(f"not named {name}: {why}{hint}")
    if not out:
        out.append("an excess spread over the frame without a localised pattern "
                   "(no signal range, probe type or direction stands out at "
                   f"{UNEXPLAINED_Z:g} sigma)")
    return out


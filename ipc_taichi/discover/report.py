"""The JSON report and the figures of a :class:`~.search.Discovery`.

Both are written atomically (a temporary file renamed into place); the
figures use matplotlib's Agg backend and need no display.

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
from .diagnostics import SIGNAL_BINS

__all__ = ["write_report", "write_figures", "to_json", "summary_line"]

FIGURES = ("gap_per_step.png", "stacked_windows.png", "residual_vs_signal.png",
           "residual_map.png", "residuals_by_probe.png")


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
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if os.path.exists(directory) and not os.path.isdir(directory):
        raise IPCInputError(f"{directory}: exists and is not a directory")
    os.makedirs(directory, exist_ok=True)
    rep = discovery.report
    paths = [os.path.join(directory, name) for name in FIGURES]

    # gap per step, against the noise floor
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
        from matplotlib.ticker import ScalarFormatter

        from matplotlib.ticker import LogLocator, NullFormatter

        ax.set_yscale("log")
        # labels at 1, 2, 5 per decade; unlabelled minor ticks (labelled ones pile up)
        ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(ScalarFormatter())
        ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_ylabel("gap: mean chi-square per pixel")
    ax.set_title("Model-data gap after each added effect")
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, paths[0])
    plt.close(fig)

    # stacked 5x5 windows per signal bin, before and after
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
    _save(fig, paths[1])
    plt.close(fig)

    # residual vs expected signal
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
    _save(fig, paths[2])
    plt.close(fig)

    # residual maps of the first frame
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6), layout="constrained", sharey=True)
    for ax, (name, d) in zip(axes, (("baseline", discovery.baseline), ("final", discovery.final))):
        im = ax.imshow(d["residuals"][0], cmap="RdBu_r", vmin=-5, vmax=5, origin="lower",
                       interpolation="nearest")
        ax.set_title(f"{name}: residual, first pair")
        ax.set_xlabel("x [px]")
    axes[0].set_ylabel("y [px]")  # shared: one label, not two overlapping ones
    fig.colorbar(im, ax=axes, shrink=0.8, label="(measured - model) / sigma")
    _save(fig, paths[3])
    plt.close(fig)

    # residuals by probe type, and chi-square against signal
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
    ax1.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax1.set_xlabel("expected signal [e-]")
    ax1.set_ylabel("chi-square per pixel")
    ax1.set_title("Chi-square vs signal level (variance problems show here)")
    ax1.legend(fontsize=8)
    _save(fig, paths[4])
    plt.close(fig)
    return paths

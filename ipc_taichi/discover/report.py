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
"""

import json
import math
import os

import numpy as np

from ..errors import IPCInputError
from ..fitsio import atomic_output
from .diagnostics import SIGNAL_BINS

__all__ = ["write_report", "write_figures", "to_json"]

FIGURES = ("gap_per_step.png", "stacked_windows.png", "residual_vs_signal.png",
           "residual_map.png")


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
        fig.savefig(tmp, dpi=110, format="png")


def write_figures(discovery, directory):
    """Write the four figures into ``directory`` (created if missing); return their paths."""
    import matplotlib

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

        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(ScalarFormatter())
        ax.yaxis.set_minor_formatter(ScalarFormatter())
    ax.set_ylabel("gap: mean chi-square per pixel")
    ax.set_title("Model-data gap after each added effect")
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, paths[0])
    plt.close(fig)

    # stacked 5x5 windows per signal bin, before and after
    nb = len(SIGNAL_BINS) - 1
    fig, axes = plt.subplots(2, nb, figsize=(2.4 * nb, 5.2), squeeze=False)
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
            if k == 0:
                ax.set_ylabel("dy [px]")
            if row == 1:
                ax.set_xlabel("dx [px]")
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
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.4))
    for ax, (name, d) in zip(axes, (("baseline", discovery.baseline), ("final", discovery.final))):
        im = ax.imshow(d["residuals"][0], cmap="RdBu_r", vmin=-5, vmax=5, origin="lower",
                       interpolation="nearest")
        ax.set_title(f"{name}: residual, first pair")
        ax.set_xlabel("x [px]")
        ax.set_ylabel("y [px]")
    fig.colorbar(im, ax=axes, shrink=0.8, label="(measured - model) / sigma")
    _save(fig, paths[3])
    plt.close(fig)
    return paths

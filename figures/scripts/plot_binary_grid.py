"""Plot the binary-star grid: flux and separation errors vs separation (paper figs 4.0.1-3).

Reads ``data/binary_grid.json`` (from ``binary_data.py``) and writes
``binary_bright.png``, ``binary_mid.png``, ``binary_dim.png`` (noise-free,
all flux ratios) and ``binary_noise.png`` (noise present, 4:1 pair). Run
from ``figures/``.
"""

import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

WIDE = 20.0        # the isolated reference separation, drawn at X_WIDE on a broken axis
X_WIDE = 6.0
RATIO_LABEL = {1.0: "1:1", 0.5: "2:1", 0.25: "4:1", 0.125: "8:1"}
COLUMNS = [("coupled_optical", "coupled frame, IPC-free PSF\n(the paper's fit)"),
           ("coupled", "coupled frame, coupled ePSF\n(PSF from isolated coupled stars)"),
           ("decoupled", "decoupled frame, decoupled ePSF")]
ROWS = [("primary flux error [%]", lambda e: e["flux_error_pct"][0]),
        ("secondary flux error [%]", lambda e: e["flux_error_pct"][1]),
        ("separation error [mpix]", lambda e: e["separation_error_mpix"])]


def xpos(sep):
    return X_WIDE if sep == WIDE else sep


BREAK = 5.5  # where the separation axis is broken (between 5 and 20 px)


def style_xaxis(ax, separations):
    ticks = [s for s in separations if s != WIDE] + ([WIDE] if WIDE in separations else [])
    ax.set_xticks([xpos(s) for s in ticks])
    ax.set_xticklabels([f"{s:g}" for s in ticks])
    if WIDE in separations:
        ax.axvline(BREAK, color="0.8", lw=0.8, ls=":")
        # the break marks on the x axis: 5 and 20 px are not a scale apart
        ax.plot([BREAK - 0.08, BREAK + 0.02], [-0.015, 0.015], transform=ax.get_xaxis_transform(),
                color="k", lw=1, clip_on=False)
        ax.plot([BREAK - 0.02, BREAK + 0.08], [-0.015, 0.015], transform=ax.get_xaxis_transform(),
                color="k", lw=1, clip_on=False)


def draw(ax, seps, mean, err, **kw):
    """Errorbars joined by lines up to 5 px; the isolated 20 px reference unjoined, beyond the
    break."""
    seps, mean, err = np.asarray(seps), np.asarray(mean), np.asarray(err)
    near = seps != WIDE
    dx = kw.pop("_dx", 0.0)
    line = ax.errorbar(seps[near] + dx, mean[near], yerr=err[near], marker="o", ms=3, capsize=2,
                       **kw)
    if (~near).any():
        ax.errorbar([xpos(WIDE) + dx], mean[~near], yerr=err[~near], marker="o", ms=3, capsize=2,
                    ls="none", color=line[0].get_color())


def plot_brightness(data, name, path):
    rows = [r for r in data["rows"] if r["brightness"] == name and not r["noise"]]
    ratios = sorted({r["ratio"] for r in rows}, reverse=True)
    seps = sorted({r["separation"] for r in rows})
    fig, axes = plt.subplots(3, 3, figsize=(13, 10), sharex=True)
    for j, (fit, title) in enumerate(COLUMNS):
        for i, (label, pick) in enumerate(ROWS):
            ax = axes[i, j]
            for ratio in ratios:
                sel = sorted((r for r in rows if r["ratio"] == ratio),
                             key=lambda r: r["separation"])
                mean = np.array([pick(r[fit])[0] for r in sel])
                std = np.array([pick(r[fit])[1] for r in sel])
                draw(ax, [r["separation"] for r in sel], mean, std,
                     label=f"flux ratio {RATIO_LABEL.get(ratio, ratio)}")
            ax.axhline(0, color="k", lw=0.6)
            ax.grid(alpha=0.3)
            style_xaxis(ax, seps)
            if i == 0:
                ax.set_title(title, fontsize=10)
            if j == 0:
                ax.set_ylabel(label)
            if i == 2:
                ax.set_xlabel("separation [px]  (axis broken: 20 = isolated reference)")
    axes[0, 0].legend(fontsize=8)
    flux = data["flux"][name]
    fig.suptitle(f"Binary star, '{name}' primary ({flux:.2g} e-), noise-free, photutils PSF fit: "
                 f"error vs separation\n(mean over 16 sub-pixel positions; bars: spread = std). "
                 f"Note the decoupled column's scale.", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_noise(data, path, ratio=0.25):
    names = [b for b in ("bright", "mid", "dim") if any(r["brightness"] == b for r in data["rows"])]
    fig, axes = plt.subplots(3, len(names), figsize=(4.3 * len(names), 10), sharex=True,
                             squeeze=False)
    fits = [("truth", "truth frame"), ("coupled", "coupled (coupled ePSF)"),
            ("coupled_optical", "coupled (IPC-free PSF)"), ("decoupled", "decoupled")]
    n = None
    for j, name in enumerate(names):
        rows = sorted((r for r in data["rows"] if r["brightness"] == name and r["noise"]
                       and r["ratio"] == ratio), key=lambda r: r["separation"])
        seps = [r["separation"] for r in rows]
        for i, (label, pick) in enumerate(ROWS):
            ax = axes[i, j]
            for k, (fit, flabel) in enumerate(fits):
                n = rows[0][fit]["n"]
                mean = np.array([pick(r[fit])[0] for r in rows])
                sem = np.array([pick(r[fit])[1] for r in rows]) / np.sqrt(n)
                draw(ax, seps, mean, sem, label=flabel, _dx=0.06 * (k - 1.5))
            ax.axhline(0, color="k", lw=0.6)
            ax.grid(alpha=0.3)
            style_xaxis(ax, seps)
            if i == 0:
                ax.set_title(f"'{name}' primary ({data['flux'][name]:.2g} e-)", fontsize=10)
            if j == 0:
                ax.set_ylabel(label)
            if i == 2:
                ax.set_xlabel("separation [px]  (axis broken before 20)")
    axes[0, 0].legend(fontsize=8)
    rn = data["study"]["read_noise"]
    fig.suptitle(f"Binary star {RATIO_LABEL[ratio]}, noise present (Poisson + {rn:g} e- read "
                 f"noise): mean error over {n} fits\n(16 sub-pixel positions x "
                 f"{data['study']['n_noise']} realisations; bars: standard error of the mean)",
                 fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv):
    src = argv[1] if len(argv) > 1 else "data/binary_grid.json"
    with open(src) as f:
        data = json.load(f)
    for name in ("bright", "mid", "dim"):
        if any(r["brightness"] == name for r in data["rows"]):
            plot_brightness(data, name, f"binary_{name}.png")
    plot_noise(data, "binary_noise.png")


if __name__ == "__main__":
    main(sys.argv)

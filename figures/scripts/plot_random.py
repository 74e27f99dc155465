"""Figures of the random-frame experiment (reads data/30_random.npz).

Usage: plot_random.py FIGURE.png with FIGURE one of hist_{coupled,decoupled,lr,wiener},
mae_{coupled,decoupled,lr,wiener}.
"""

import sys

from _common import load_npz, pyplot, savefig

LABEL = {"coupled": "IPC present (coupled)", "decoupled": "non-linear iterative decoupling",
         "lr": "Lucy-Richardson (skimage)", "wiener": "Wiener (skimage)"}
DIFF = {"coupled": "coupled - true", "decoupled": "decoupled - true", "lr": "LR - true",
        "wiener": "Wiener - true"}
PAPER_FIG = {"hist_coupled": "Fig. 3.2.2", "hist_decoupled": "Fig. 3.2.1", "hist_lr": "Fig. 3.2.3",
             "mae_coupled": "Fig. 3.2.5", "mae_decoupled": "Fig. 3.2.4", "mae_lr": "Fig. 3.2.6"}
PAPER_MAX = {"coupled": "~3000", "decoupled": "~0.075", "lr": "~1000"}


def histogram(d, m, plt, stem):
    bins, counts = d[f"bins_{m}"], d[f"hist_{m}"]
    lo, hi = d[f"extremes_{m}"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.stairs(counts, bins, fill=True, alpha=0.75)
    ax.set_xlabel(f"pixel error {DIFF[m]} [counts]")
    ax.set_ylabel("pixels per bin")
    note = f"ours: min {lo:.4g}, max {hi:.4g}, mean |error| {d[f'mae_{m}'][0]:.3g}"
    if m in PAPER_MAX:
        note += f"\npaper: max |error| {PAPER_MAX[m]}"
    ax.text(0.98, 0.95, note, transform=ax.transAxes, ha="right", va="top", fontsize=8.5,
            bbox=dict(fc="white", ec="0.7"))
    ref = f" ({PAPER_FIG[stem]})" if stem in PAPER_FIG else " (not in the paper)"
    ax.set_title(f"Pixel errors, {LABEL[m]}, no read noise{ref}\n"
                 f"{int(d['size'])}x{int(d['size'])} frame, uniform 0..60000 counts")
    return fig


def mae(d, m, plt, stem):
    rn = d["read_noise"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(rn, d[f"mae_{m}"], "o-", label="ours")
    if m == "coupled":
        ax.axhline(719, ls="--", color="C3", label="paper: ~719")
    elif m == "decoupled":
        ax.plot([0, 100], [0, 5], "--", color="C3", label="paper: 0 -> 5, linear")
    elif m == "lr":
        ax.plot([0, 100], [133.8, 134.0], "--", color="C3", label="paper: 133.8 -> 134.0")
    ax.set_xlabel("read noise [counts RMS]")
    ax.set_ylabel(f"mean |{DIFF[m]}| [counts]")
    if m in ("coupled", "lr", "wiener"):
        top = max(d[f"mae_{m}"].max(), 719 if m == "coupled" else 134 if m == "lr" else 0)
        ax.set_ylim(0, 1.15 * top)
    ax.legend()
    ref = f" ({PAPER_FIG[stem]})" if stem in PAPER_FIG else " (not in the paper)"
    ax.set_title(f"Mean absolute error vs read noise, {LABEL[m]}{ref}")
    return fig


if __name__ == "__main__":
    name = sys.argv[1]
    stem = name[:-4]
    kind, method = stem.split("_", 1)
    plt = pyplot()
    d = load_npz("30_random")
    savefig((histogram if kind == "hist" else mae)(d, method, plt, stem), name)

"""Figures of the random-frame experiment (reads data/30_random.npz).

Usage: plot_random.py FIGURE.png with FIGURE one of hist_{coupled,decoupled,lr,wiener}
or mae_read_noise.
"""

import sys

import numpy as np
from _common import load_npz, pyplot, savefig

LABEL = {"coupled": "IPC present (coupled)", "decoupled": "non-linear iterative decoupling",
         "lr": "Lucy-Richardson (skimage's update)", "wiener": "Wiener (skimage)"}
DIFF = {"coupled": "coupled - true", "decoupled": "decoupled - true", "lr": "LR - true",
        "wiener": "Wiener - true"}
PAPER_FIG = {"hist_coupled": "Fig. 3.2.2", "hist_decoupled": "Fig. 3.2.1", "hist_lr": "Fig. 3.2.3"}
PAPER_MAX = {"coupled": "~3000", "decoupled": "~0.075", "lr": "~1000"}
TUNING = {"coupled": "nothing tuned", "decoupled": "paper's stopping rule, nothing tuned",
          "lr": "3x3 kernel, alpha = {alpha:.4f} % "
                "(signal-weighted mean over the measured frame),\n"
                "{lr_iter} iterations; not tuned on the truth",
          "wiener": "3x3 kernel, alpha = {alpha:.4f} % (as LR); "
                    "balance from the frame and the read\n"
                    "noise (0, the inverse filter, here); not tuned on the truth"}


def histogram(d, m, plt, stem):
    bins, counts = d[f"bins_{m}"], d[f"hist_{m}"]
    lo, hi = d[f"extremes_{m}"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.stairs(counts, bins, fill=True, alpha=0.75)
    ax.set_ylim(0, 1.4 * counts.max())  # room for the note above the peak
    ax.set_xlabel(f"pixel error {DIFF[m]} [counts]")
    ax.set_ylabel("pixels per bin")
    note = f"ours: min {lo:.4g}, max {hi:.4g}, mean |error| {d[f'mae_{m}'][0]:.3g}"
    if m == "lr":
        note += (f"\nrun to convergence ({int(d['lr_converged_iter'][0])} iterations): "
                 f"mean |error| {float(d['mae_lr_converged'][0]):.3g}")
    if m in PAPER_MAX:
        note += f"\npaper: max |error| {PAPER_MAX[m]}"
    ax.text(0.98, 0.95, note, transform=ax.transAxes, ha="right", va="top", fontsize=8.5,
            bbox=dict(fc="white", ec="0.7"))
    ref = f" ({PAPER_FIG[stem]})" if stem in PAPER_FIG else " (not in the paper)"
    ax.set_title(f"Pixel errors, {LABEL[m]}, no read noise{ref}\n"
                 f"{int(d['size'])}x{int(d['size'])} frame, uniform 0..60000 e-; "
                 + TUNING[m].format(alpha=100 * float(d["alpha"][0]), lr_iter=int(d["lr_iter"])),
                 fontsize=9)
    return fig


def mae_read_noise(d, plt):
    rn = d["read_noise"].astype(float)
    pos = rn > 0
    # zero read noise cannot sit on a log axis: it gets its own narrow panel, unconnected,
    # so that no line segment pretends to join 0 and 20 RMS
    fig, (ax0, ax) = plt.subplots(1, 2, figsize=(10.5, 5.0), sharey=True,
                                  gridspec_kw=dict(width_ratios=[1, 11], wspace=0.04))
    for k, m in enumerate(("coupled", "decoupled", "lr", "wiener")):
        ax.plot(rn[pos], d[f"mae_{m}"][pos], "o-", color=f"C{k}", ms=4, label=f"{LABEL[m]} (ours)")
        ax0.plot([0], d[f"mae_{m}"][~pos], "o", color=f"C{k}", ms=4)
    ax0.plot([0], [719], "_", color="C0", ms=12, mew=1.5)
    ax0.plot([0], [133.8], "_", color="C2", ms=12, mew=1.5)
    ax0.set_xlim(-1, 1)
    ax0.set_xticks([0])
    ax0.spines["right"].set_visible(False)
    ax.spines["left"].set_visible(False)
    ax.tick_params(axis="y", which="both", left=False)
    for a, x in ((ax0, 1), (ax, 0)):  # the axis-break marks
        a.plot([x, x], [0, 0], transform=a.transAxes, marker=[(-1, -1.5), (1, 1.5)], ms=10,
               color="k", mec="k", mew=1, clip_on=False, ls="none")
    ax.plot([20, 100], [719, 719], "--", color="C0", lw=1, label="paper: coupled ~719 (bar at 0)")
    paper_rn = np.array([20.0, 50, 100])
    ax.plot(paper_rn, 0.05 * paper_rn, "--", color="C1", lw=1,
            label="paper: decoupled 0 -> 5 (slope 0.05)")
    ax.plot([20, 100], [133.9, 134.0], "--", color="C2", lw=1,
            label="paper: LR 133.8 -> 134.0 (bar at 0)")
    ax.axvline(800, color="0.5", lw=0.8, ls=":")
    ax.text(800, 4e-3, " paper: LR wins\n beyond ~800 RMS", fontsize=8, color="0.3")
    ax.set_xscale("log")
    ax0.set_yscale("log")
    ax.set_xlabel("read noise [e- RMS] (log scale; zero read noise in the left panel)")
    ax0.set_ylabel("mean |method - true| [e-]")
    ax.legend(fontsize=7.5, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title("Mean absolute error vs read noise (paper Figs. 3.2.4-3.2.6 in one panel)\n"
                 "\"true\" carries the same read-noise instance as the coupled frame: "
                 "the error is IPC\n"
                 "removal plus what a method does to the noise. "
                 "LR and Wiener: same kernel and edges,\n"
                 "tuned by rules that never see the truth", fontsize=9)
    return fig


if __name__ == "__main__":
    name = sys.argv[1]
    stem = name[:-4]
    plt = pyplot()
    d = load_npz("30_random")
    if stem == "mae_read_noise":
        savefig(mae_read_noise(d, plt), name)
    else:
        savefig(histogram(d, stem.split("_", 1)[1], plt, stem), name)

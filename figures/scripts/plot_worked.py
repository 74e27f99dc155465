"""Figure of the worked example: worked_example.png (reads data/20_worked.npz)."""

import sys

import numpy as np
from _common import load_npz, pyplot, savefig


def main(name):
    from matplotlib.colors import LogNorm

    d = load_npz("20_worked")
    plt = pyplot()
    panels = [("truth", d["truth"])] + [
        (f"after {q} iteration{'s' if q != 1 else ''}" if q else "coupled (0 iterations)", w)
        for q, w in zip(d["iterations"], d["windows"])]
    # one colour scale for every panel: |error| on a log scale, so that 1e-6 and 381 differ
    norm = LogNorm(vmin=1e-6, vmax=1e3)
    fig, axes = plt.subplots(2, 3, figsize=(11.5, 7.2), layout="constrained")
    image = None
    for k, (ax, (title, w)) in enumerate(zip(axes.ravel(), panels)):
        err = np.abs(w - d["truth"])
        shown = np.ma.masked_less(np.clip(err, None, 1e3), 1e-12)
        image = ax.imshow(shown, cmap="viridis", norm=norm)
        for (i, j), v in np.ndenumerate(w):
            light = err[i, j] > 1e-12 and norm(max(err[i, j], 1e-6)) < 0.5
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=8.5,
                    color="white" if light else "black")
        ax.set_xticks(range(4), [str(c) for c in range(23, 27)])
        ax.set_yticks(range(4), [str(r) for r in range(23, 27)])
        ax.grid(False)
        sub = "" if title == "truth" else f"\nmax |error| in window = {err.max():.3g}"
        ax.set_title(title + sub)
        ax.set_xlabel("column x [px]")
        if k % 3 == 0:
            ax.set_ylabel("row y [px]")
    fig.colorbar(image, ax=axes, shrink=0.8, label="|estimate - truth| [e-] (white: exact)")
    fig.suptitle("Worked example: decoupling the 2x2 star (numbers: e-; colour: |error| "
                 "against the truth, one log scale for all panels)\nafter 0, 1, 2, 3 and 7 "
                 "Jacobi iterations (paper section 2.3; nothing tuned)")
    savefig(fig, name)


if __name__ == "__main__":
    main(sys.argv[1])

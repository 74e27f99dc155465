"""Figure of the worked example: worked_example.png (reads data/20_worked.npz)."""

import sys

import numpy as np

from _common import load_npz, pyplot, savefig


def main(name):
    d = load_npz("20_worked")
    plt = pyplot()
    panels = [("truth", d["truth"])] + [
        (f"after {q} iteration{'s' if q != 1 else ''}" if q else "coupled (0 iterations)", w)
        for q, w in zip(d["iterations"], d["windows"])]
    fig, axes = plt.subplots(2, 3, figsize=(10.5, 7.2))
    for ax, (title, w) in zip(axes.ravel(), panels):
        err = w - d["truth"]
        lim = max(np.abs(err).max(), 1e-12)
        ax.imshow(err, cmap="coolwarm", vmin=-lim, vmax=lim)
        for (i, j), v in np.ndenumerate(w):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=8.5)
        ax.set_xticks(range(4), [str(c) for c in range(23, 27)])
        ax.set_yticks(range(4), [str(r) for r in range(23, 27)])
        ax.grid(False)
        sub = "" if title == "truth" else f"\nmax |error| in window = {np.abs(err).max():.3g}"
        ax.set_title(title + sub)
        ax.set_xlabel("column x [px]")
        ax.set_ylabel("row y [px]")
    fig.suptitle("Worked example: decoupling the 2x2 star (counts; colour = error vs truth, own scale per panel)\n"
                 "after 0, 1, 2, 3 and 7 Jacobi iterations (paper section 2.3)")
    fig.tight_layout()
    savefig(fig, name)


if __name__ == "__main__":
    main(sys.argv[1])

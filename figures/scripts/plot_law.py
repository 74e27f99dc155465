"""Figures of the coupling law: alpha_surface.png, alpha_zero_background.png.

Usage: plot_law.py FIGURE.png   (reads data/10_law.npz)
"""

import sys

import numpy as np
from _common import load_npz, pyplot, savefig


def alpha_surface(d, plt):
    s = d["signal"] / 1000
    S, N = np.meshgrid(s, s, indexing="ij")
    fig = plt.figure(figsize=(6.4, 5.0))
    ax = fig.add_subplot(projection="3d")
    surf = ax.plot_surface(S, N, d["alpha"], cmap="viridis", rstride=2, cstride=2, linewidth=0)
    ax.set_xlabel("signal S [10$^3$ counts]")
    ax.set_ylabel("neighbour N [10$^3$ counts]")
    ax.set_zlabel(r"$\alpha$(S, N) [%]")
    ax.view_init(elev=28, azim=-125)
    fig.colorbar(surf, ax=ax, shrink=0.6, pad=0.1, label=r"$\alpha$ [%]")
    ax.set_title("Coupling coefficient $\\alpha$(S, N) of the donlon2018 law\n"
                 "(paper Eq. 7 with 20000$\\sqrt{2}$; Fig. 2.3.1)")
    return fig


def alpha_zero_background(d, plt):
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(d["line"] / 1000, d["line_alpha"], lw=2, label=r"donlon2018 (20000$\sqrt{2}$, default)")
    ax.plot(d["line"] / 1000, d["line_alpha_printed"], "--", lw=1.5,
            label=r"printed Eq. 7 (10000$\sqrt{2}$)")
    ax.set_xlabel("signal S [10$^3$ counts]")
    ax.set_ylabel(r"$\alpha$(S, 0) [%]")
    ax.set_xlim(0, 60)
    ax.legend()
    ax.set_title("Coupling to a zero-signal neighbour, $\\alpha$(S, N=0) (paper Fig. 2.3.2)")
    return fig


FIGURES = {"alpha_surface.png": alpha_surface, "alpha_zero_background.png": alpha_zero_background}

if __name__ == "__main__":
    name = sys.argv[1]
    plt = pyplot()
    savefig(FIGURES[name](load_npz("10_law"), plt), name)

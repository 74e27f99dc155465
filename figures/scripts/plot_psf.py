"""Figures of the PSF study (reads data/40_psf.npz).

Usage: plot_psf.py FIGURE.png with FIGURE one of psf_3d, psf_cross_section,
psf_difference, psf_static8. Cross sections are rows through the peak of the
4x-sampled effective PSF of the paper's point-sampled detector (its Eq. 10, the
model the FWHM table compares), for a unit-flux source: the value is the
fraction of the source's light in a pixel centred there. Nothing in these
figures is tuned.
"""

import sys

import numpy as np
from _common import load_npz, pyplot, savefig

from analysis.psf import continuous_psf

MODEL = "point"
PAPER = {"truth": 2.080, "bright": 2.169, "mid": 2.180, "dim": 2.186, "static8": 2.249}
COLORS = {"bright": "C0", "mid": "C2", "dim": "C3"}


def unit(epsf, o):
    # an effective PSF summing to o**2 holds, at each sample, the fraction of the
    # source's light in a detector pixel centred there (each sub-pixel phase sums to 1)
    return np.asarray(epsf)


def row(epsf):
    return epsf[epsf.shape[0] // 2]


def offsets(epsf, o):
    return (np.arange(epsf.shape[1]) - epsf.shape[1] // 2) / o


def smooth(x, y):
    """The cubic spline through the samples (as the paper draws its PSFs), on a fine grid."""
    from scipy.interpolate import CubicSpline

    t = np.linspace(-4, 4, 801)
    return t, CubicSpline(x, y)(t)


def labels(d):
    return {str(k): float(f) for k, f in zip(d["levels"], d["fluxes"])}


def widths(d, name):
    """Gaussian-fit and half-maximum (spline) FWHM of a measured PSF, from the data file."""
    k = list(d["fwhm_keys"]).index(f"{MODEL}_{name}")
    return float(d["fwhm_gaussian"][k]), 0.5 * float(d["fwhm_x"][k] + d["fwhm_y"][k])


def psf_3d(d, o, plt):
    epsf = unit(d[f"{MODEL}_bright_decoupled"], o)
    spline = continuous_psf(epsf, o)
    t = np.linspace(-3, 3, 121)
    z = spline(t, t)
    X, Y = np.meshgrid(t, t)
    fig = plt.figure(figsize=(6.4, 5.0))
    ax = fig.add_subplot(projection="3d")
    # no facet edges and no antialiasing of them: drawn edges of ~15000 thin facets alias
    # into a moire pattern on the flat base
    ax.plot_surface(X, Y, z, cmap="magma", rcount=z.shape[0], ccount=z.shape[1], linewidth=0,
                    edgecolor="none", antialiased=False, shade=False)
    ax.set_xlabel("x offset [px]")
    ax.set_ylabel("y offset [px]")
    ax.set_zlabel("fraction of flux per pixel")
    ax.view_init(elev=25, azim=-60)
    ax.set_title("Bicubic-spline PSF from quarter-pixel offsets, decoupled bright source\n"
                 "(JWST-like F405N, point-sampled as the paper; paper Fig. 3.3.1)")
    return fig


def psf_cross_section(d, o, plt):
    fl = labels(d)
    truth = unit(d[f"{MODEL}_truth"], o)
    x = offsets(truth, o)
    fig, ax = plt.subplots(figsize=(6.8, 4.4))
    inset = ax.inset_axes([0.70, 0.42, 0.28, 0.53])
    g, h = widths(d, "truth")
    curves = [("k", 2, f"truth = decoupled: {g:.3f} / {h:.3f} px (paper 2.080)", truth)]
    for lv in ("bright", "mid", "dim"):
        e = unit(d[f"{MODEL}_{lv}_coupled"], o)
        g, h = widths(d, f"{lv}_coupled")
        curves.append((COLORS[lv], 1.2,
                       f"{lv} coupled, {fl[lv]:.3g} e-: {g:.3f} / {h:.3f} px "
                       f"(paper {PAPER[lv]:.3f})", e))
    for color, lw, label, e in curves:
        t, v = smooth(x, row(e))
        ax.plot(t, v, "-", color=color, lw=lw, label=label)
        inset.plot(t, v, "-", color=color, lw=lw)
    ax.set_xlim(-4, 4)
    ax.set_xlabel("x offset from the source [detector px]")
    ax.set_ylabel("fraction of flux per pixel")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2,
              title="FWHM: Gaussian fit (the paper's 2.080 cell) / half maximum (spline); "
                    "the same estimator on every row", title_fontsize=8)
    inset.set_xlim(-0.5, 0.5)
    inset.set_ylim(0.95 * row(truth).max(), 1.003 * row(truth).max())
    inset.set_title("peak, zoomed", fontsize=8)
    inset.tick_params(labelsize=7)
    ax.set_title("PSF cross section through the peak, with signal-dependent IPC\n"
                 "(JWST-like F405N, point-sampled as the paper's Eq. 10, 0.063\"/px, 10 ks; "
                 "paper Fig. 3.3.2)", fontsize=9.5)
    return fig


def psf_difference(d, o, plt):
    truth = unit(d[f"{MODEL}_truth"], o)
    x = offsets(truth, o)
    peak = row(truth).max()
    fig, ax = plt.subplots(figsize=(6.8, 4.2))
    for lv in ("bright", "mid", "dim"):
        e = unit(d[f"{MODEL}_{lv}_coupled"], o)
        ax.plot(*smooth(x, 100 * (row(e) - row(truth)) / peak), color=COLORS[lv],
                label=f"{lv}: coupled - truth")
        dec = unit(d[f"{MODEL}_{lv}_decoupled"], o)
        ax.plot(*smooth(x, 100 * (row(dec) - row(truth)) / peak), ":", color=COLORS[lv], lw=1)
    ax.axhline(0, color="k", lw=0.8)
    ax.plot([], [], "k:", lw=1, label="decoupled - truth (all three, ~0)")
    ax.set_xlim(-4, 4)
    ax.set_xlabel("x offset from the source [detector px]")
    ax.set_ylabel("difference [% of the true peak]")
    ax.legend(fontsize=8)
    ax.set_title("IPC lowers the PSF peak and raises its flanks, more for dim sources\n"
                 "(cross section through the peak, point-sampled, 10 ks; paper Fig. 3.3.3)")
    return fig


def psf_static8(d, o, plt):
    truth = unit(d[f"{MODEL}_truth"], o)
    static = unit(d[f"{MODEL}_static8"], o)
    diag = unit(d[f"{MODEL}_static8_diag"], o)
    x = offsets(truth, o)
    fig, ax = plt.subplots(figsize=(6.8, 4.2))
    gt, ht = widths(d, "truth")
    g4, h4 = widths(d, "static8")
    gd, hd = widths(d, "static8_diag")
    ax.plot(*smooth(x, row(truth)), "k-", lw=2,
            label=f"no IPC: {gt:.3f} / {ht:.3f} px (paper 2.080)")
    ax.plot(*smooth(x, row(static)), "C1--", lw=1.5,
            label=f"static $\\alpha$ = 8 %, 4 neighbours: {g4:.3f} / {h4:.3f} px "
                  f"(+{100 * (g4 / gt - 1):.1f} %)")
    ax.plot(*smooth(x, row(diag)), "C1-", lw=2,
            label=f"8 % + 0.75 % to each diagonal: {gd:.3f} / {hd:.3f} px "
                  f"(+{100 * (gd / gt - 1):.1f} %; paper 2.249, +8.1 %)")
    ax.set_xlim(-4, 4)
    ax.set_xlabel("x offset from the source [detector px]")
    ax.set_ylabel("fraction of flux per pixel")
    ax.set_title("PSF cross section with a static H4RG-10-like IPC, $\\alpha$ = 8 %\n"
                 "(35 % of the charge leaves the centre with the diagonals, as the paper says;\n"
                 "JWST-like F405N, point-sampled, 0.063\"/px; paper Fig. 5.0.1)",
                 fontsize=9.5)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=1,
              title="FWHM: Gaussian fit (the paper's 2.080 cell) / half maximum (spline)",
              title_fontsize=8)
    return fig


FIGURES = {"psf_3d.png": psf_3d, "psf_cross_section.png": psf_cross_section,
           "psf_difference.png": psf_difference, "psf_static8.png": psf_static8}

if __name__ == "__main__":
    name = sys.argv[1]
    plt = pyplot()
    d = load_npz("40_psf")
    savefig(FIGURES[name](d, int(d["oversample"]), plt), name)

"""Write ``data/50_binary.results.md``: the binary-star headline tables, paper beside ours.

Reads ``data/binary_grid.json`` and ``data/binary_methods.json``. Run from ``figures/``.
"""

import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))

from ipc_taichi.fitsio import atomic_output  # noqa: E402

FIT_LABEL = {"truth": "truth frame, truth ePSF",
             "coupled_optical": "coupled frame, IPC-free PSF (paper's fit)",
             "coupled": "coupled frame, coupled ePSF",
             "decoupled": "decoupled frame, decoupled ePSF"}
PAPER = {"coupled_optical": "~1.5 % / ~50 mpix (bright, figs 4.0.1-3)",
         "decoupled": "0.01-0.001 % / micro-pixels", "truth": "0 / 0", "coupled": "-"}


def fmt(pair, digits=3):
    mean, std = pair
    return f"{mean:+.{digits}g} ± {std:.2g}"


def grid_row(data, name, ratio, sep, noise):
    return next(r for r in data["rows"] if r["brightness"] == name and r["ratio"] == ratio
                and r["separation"] == sep and r["noise"] == noise)


def headline(data):
    """The issue's headline: 4:1 pair 3 px apart, noise-free, paper beside ours."""
    worst = {}
    for name in ("bright", "dim"):
        row = grid_row(data, name, 0.25, 3.0, False)
        worst[name] = row
    b, d = worst["bright"], worst["dim"]
    e8 = grid_row(data, "dim", 0.125, 3.0, False)["coupled_optical"]["separation_error_mpix"][0]

    def flux(row, fit):
        f = row[fit]["flux_error_pct"]
        return f"{f[0][0]:+.3g} % / {f[1][0]:+.3g} %"

    def sep(row, fit):
        return f"{row[fit]['separation_error_mpix'][0]:+.3g} mpix"

    blend_flux = max(abs(r["coupled"]["flux_error_pct"][1][0]) for r in (b, d))
    blend_sep = max(abs(r["coupled"]["separation_error_mpix"][0]) for r in (b, d))
    dec_flux = max(abs(r["decoupled"]["flux_error_pct"][s][0]) for r in data["rows"]
                   if not r["noise"] for s in (0, 1))
    dec_sep = max(abs(r["decoupled"]["separation_error_mpix"][0]) for r in data["rows"]
                  if not r["noise"])
    return [
        "**Headline: 4:1 pair 3 px apart, noise-free** (mean over 16 sub-pixel positions; "
        "flux errors bright star / faint star)", "",
        "| quantity | paper | ours, bright primary | ours, dim primary |", "|---|---|---|---|",
        "| coupled, flux error, IPC-free PSF (paper's fit) | ~1.5 % | "
        f"{flux(b, 'coupled_optical')} "
        f"| {flux(d, 'coupled_optical')} |",
        f"| coupled, separation error, IPC-free PSF | ~50 mpix | {sep(b, 'coupled_optical')} | "
        f"{sep(d, 'coupled_optical')} (8:1: {e8:+.3g} mpix) |",
        f"| coupled, flux error, coupled ePSF | - | {flux(b, 'coupled')} | {flux(d, 'coupled')} |",
        f"| coupled, separation error, coupled ePSF | - | {sep(b, 'coupled')} | "
        f"{sep(d, 'coupled')} |",
        f"| decoupled, flux error | hundredths or thousandths of a % | {flux(b, 'decoupled')} | "
        f"{flux(d, 'decoupled')} |",
        f"| decoupled, separation error | micro-pixels (1e-3 mpix) | {sep(b, 'decoupled')} | "
        f"{sep(d, 'decoupled')} |",
        "",
        f"Over the whole noise-free grid (all brightnesses, ratios, separations) the decoupled "
        f"frames give |flux error| <= {dec_flux:.2g} % and |separation error| <= {dec_sep:.2g} "
        "mpix: the paper's targets hold everywhere. The paper's figures (bright primary) show "
        "~1.5 % / ~50 mpix. Fitting the coupled frames with the IPC-free PSF, as the paper did, "
        f"we get {b['coupled_optical']['flux_error_pct'][0][0]:+.2g} % / "
        f"{b['coupled_optical']['separation_error_mpix'][0]:+.2g} mpix for the bright primary "
        f"and {d['coupled_optical']['flux_error_pct'][0][0]:+.2g} % / "
        f"{d['coupled_optical']['separation_error_mpix'][0]:+.2g} mpix for the dim one "
        f"({e8:+.2g} mpix for an 8:1 pair): the same size, the bright case "
        f"{1.5 / abs(b['coupled_optical']['flux_error_pct'][0][0]):.1f}x (flux) and "
        f"{50 / abs(b['coupled_optical']['separation_error_mpix'][0]):.1f}x (separation) smaller "
        "than the paper's; none of the fitter choices we could try closes the gap as an IPC "
        "effect (table at the end of this section; the paper's PSF file and fitter are not "
        "ours). Most of "
        "that flux error is the PSF-shape mismatch an isolated star shows too (20 px table). "
        "Fitted with the PSF of isolated coupled stars, the blend-specific IPC error of this pair "
        "is at most "
        f"{blend_flux:.2g} % / {blend_sep:.2g} mpix.",
        "",
    ]


def grid_tables(data):
    out = []
    names = [b for b in ("bright", "mid", "dim") if any(r["brightness"] == b for r in data["rows"])]
    st = data["study"]
    for noise, sep in ((False, 3.0), (False, 20.0), (True, 3.0)):
        title = (f"4:1 pair, {sep:g} px apart, "
                 + (f"noise present (Poisson + {st['read_noise']:g} e-)" if noise
                    else "noise-free"))
        out += [f"**{title}** (mean ± std over "
                f"{grid_row(data, names[0], 0.25, sep, noise)['truth']['n']} fits: 16 sub-pixel "
                f"positions{' x realisations' if noise else ''})", "",
                "| primary | frame, PSF | bright-star flux error [%] | faint-star flux error [%] "
                "| separation error [mpix] | paper (flux / separation) |",
                "|---|---|---|---|---|---|"]
        for name in names:
            row = grid_row(data, name, 0.25, sep, noise)
            for fit in ("truth", "coupled_optical", "coupled", "decoupled"):
                e = row[fit]
                paper = PAPER[fit] if (sep == 3.0 and not noise and name == "bright") else ""
                out.append(f"| {name} | {FIT_LABEL[fit]} | {fmt(e['flux_error_pct'][0])} | "
                           f"{fmt(e['flux_error_pct'][1])} | {fmt(e['separation_error_mpix'])} | "
                           f"{paper} |")
        out.append("")
    out += detection_table(data, names)
    return out


def detection_table(data, names):
    """Detection at explicit min_separation values, coupled and truth frames."""
    seps = sorted({r["separation"] for r in data["rows"]})
    ratios = sorted({r["ratio"] for r in data["rows"]}, reverse=True)
    rows = [r for r in data["rows"] if not r["noise"]]
    min_seps = list(rows[0]["detected"]["coupled"])

    def frac(name, ratio, sep, frame, ms):
        sel = [r for r in rows if r["brightness"] == name and r["ratio"] == ratio
               and r["separation"] == sep]
        return sum(r["detected"][frame][ms] for r in sel) / len(sel)

    out = ["**Detection** (photutils IRAFStarFinder, FWHM 2.1 px, `roundness_range=(0, 1)`, "
           "threshold a fifth of the "
           "faint star's peak, noise-free frames; fraction of the two stars found within 0.5 px "
           "over 16 sub-pixel positions; bright primary, coupled frame (truth frame in "
           "brackets where it differs)). `min_separation` is set explicitly: photutils 3.0 "
           "defaults it to 2.5 x FWHM = 5.25 px, which merges every closer pair whatever the "
           "image holds. The roundness range is widened from photutils' default (0 to 0.2) "
           "because a blended pair's peaks are elongated: in a separate check (coupled bright 1:1 "
           "pair 3 px apart, min_separation 1 px, a simpler matching rule than the table's) the "
           "default range found both stars at 3 of 16 positions, (0, 1) at 16 of 16.", "",
           "| min_separation | ratio | " + " | ".join(f"{s:g} px" for s in seps) + " |",
           "|---|---|" + "---|" * len(seps)]
    for ms in min_seps:
        for ratio in ratios:
            cells = []
            for s in seps:
                c, t = (frac("bright", ratio, s, "coupled", ms),
                        frac("bright", ratio, s, "truth", ms))
                cells.append(f"{c:.2f}" + (f" ({t:.2f})" if abs(c - t) > 1e-9 else ""))
            out.append(f"| {ms} px | {1 / ratio:g}:1 | " + " | ".join(cells) + " |")
    spread = max(abs(frac(n, ratio, s, "coupled", ms) - frac("bright", ratio, s, "coupled", ms))
                 for n in names for ratio in ratios for s in seps for ms in min_seps)
    ipc = max(abs(frac(n, ratio, s, "coupled", ms) - frac(n, ratio, s, "truth", ms))
              for n in names for ratio in ratios for s in seps for ms in min_seps)
    d3 = {ms: (frac("bright", 1.0, 3.0, "coupled", ms), frac("bright", 0.25, 3.0, "coupled", ms))
          for ms in min_seps}
    lo = min_seps[0]
    out += ["",
            f"The mid and dim primaries differ from the bright one by at most {spread:.2f} in any "
            f"cell; coupled and truth frames differ by at most {ipc:.2f} anywhere in the grid. "
            f"With min_separation = {lo} px a 3 px pair is found {100 * d3[lo][0]:.0f} % (1:1) and "
            f"{100 * d3[lo][1]:.0f} % (4:1) of the time; at photutils' default (5.25 px) "
            f"{100 * d3['5.25'][0]:.0f} % and {100 * d3['5.25'][1]:.0f} %, which is the default's "
            "doing, not IPC's: the earlier table here (measured at the default) and its words "
            "\"neither splits a close pair\" were an artefact of that setting. What remains "
            "unsplit at 1 px (the 2 px pairs, the 4:1 pairs at some positions) is unsplit in the "
            f"truth frame too, to within {ipc:.2f}: the optics and the finder, not IPC.", ""]
    return out


def bright_psf(data):
    """The abstract's scenario: the coupled PSF of a bright field star used on fainter pairs."""
    out = ["**The abstract's scenario: a bright field star's PSF used on a fainter blend** "
           "(4:1 pair 3 px apart; coupled frames; the ePSF of an isolated coupled star at the "
           "bright primary's flux, as an observer would build from a bright field star, beside "
           "the ePSF at the pair's own primary flux; mean ± std over the fits)", "",
           "| primary | noise | bright star's PSF: bright-star flux / faint-star flux / sep "
           "| own coupled ePSF: same | IPC-free PSF: same |", "|---|---|---|---|---|"]
    for name in ("bright", "mid", "dim"):
        for noise in (False, True):
            try:
                row = grid_row(data, name, 0.25, 3.0, noise)
            except StopIteration:
                continue
            cells = []
            for fit in ("coupled_brightpsf", "coupled", "coupled_optical"):
                e = row[fit]
                cells.append(f"{fmt(e['flux_error_pct'][0])} % / {fmt(e['flux_error_pct'][1])} % / "
                             f"{fmt(e['separation_error_mpix'])} mpix")
            out.append(f"| {name} | {'Poisson + read' if noise else 'none'} | "
                       + " | ".join(cells) + " |")
    row = grid_row(data, "dim", 0.25, 3.0, False)
    d, own, free = row["coupled_brightpsf"], row["coupled"], row["coupled_optical"]

    def cell(e):
        return (f"{e['flux_error_pct'][0][0]:+.2f} % / {e['flux_error_pct'][1][0]:+.2f} % / "
                f"{e['separation_error_mpix'][0]:+.1f} mpix")

    max_flux = max(abs(grid_row(data, n, 0.25, 3.0, False)["coupled_brightpsf"]
                       ["flux_error_pct"][0][0]) for n in ("bright", "mid", "dim"))
    max_sep = max(abs(grid_row(data, n, 0.25, 3.0, False)["coupled_brightpsf"]
                      ["separation_error_mpix"][0]) for n in ("bright", "mid", "dim"))
    out += ["", f"For the dim pair, noise-free, the bright star's PSF gives {cell(d)} (primary / "
            f"faint star / separation), against {cell(own)} with the pair's own coupled ePSF and "
            f"{cell(free)} with the IPC-free PSF: the bright star's PSF carries its weaker "
            "coupling (alpha falls with signal), so on a fainter blend it leaves part of the "
            "IPC error in place. The abstract quantifies this scenario: flux \"off by upwards of "
            "1.5 %\" and a separation error of 50 mpix for a 4:1 pair 3 px apart. The bias here "
            "is of that kind but smaller (largest primary flux error "
            f"{max_flux:.2f} %, "
            "separation error "
            f"{max_sep:.1f} mpix, noise-free); "
            "the abstract's size is not reproduced.", ""]
    return out


def fitter_table(data, grid):
    """The paper's 50 mpix under the fitter choices we can try."""
    out = ["**The paper's ~50 mpix under fitter choices** (bright 4:1 pair 3 px apart, "
           "noise-free, coupled frames fitted with the IPC-free PSF as the paper did; "
           "`integrated` = pixel-integrated frames and ePSF, `point` = the paper's point-sampled "
           "frames (its Eq. 10) and the 4x optical PSF used directly as ePSF, `mixed` = "
           "pixel-integrated frames fitted with the point-sampled PSF (a PSF file used as if it "
           "were an ePSF); grouped = both stars fitted together, alone = each star on its own; "
           "mean over 16 positions; 'IPC share' = coupled minus truth frame with the same choice)",
           "", "| frames / PSF | grouping | fit box | separation error [mpix] | IPC share [mpix] "
           "| flux error bright / faint [%] |", "|---|---|---|---|---|---|"]
    for r in data["rows"]:
        c, t = r["coupled"], r["truth"]
        out.append(f"| {r['sampling']} | {r['grouping']} | {r['fit_shape']}x{r['fit_shape']} | "
                   f"{c['separation_error_mpix'][0]:+.1f} | "
                   f"{c['separation_error_mpix'][0] - t['separation_error_mpix'][0]:+.1f} | "
                   f"{c['flux_error_pct'][0][0]:+.2f} / {c['flux_error_pct'][1][0]:+.2f} |")
    grouped = [r for r in data["rows"] if r["grouping"] == "grouped"]
    share = [r["coupled"]["separation_error_mpix"][0] - r["truth"]["separation_error_mpix"][0]
             for r in grouped]
    mismatch = [r["truth"]["separation_error_mpix"][0] for r in grouped if r["sampling"] == "mixed"]
    same = max(abs(r["truth"]["separation_error_mpix"][0]) for r in grouped
               if r["sampling"] != "mixed")
    out += ["", f"Grouped fits: the part of the separation error that IPC causes is "
            f"{min(share):+.0f} to {max(share):+.0f} mpix under every choice; the rest is PSF "
            f"mismatch (under {same:.1g} mpix when frames and PSF share a detector model, "
            f"{min(mismatch):+.0f} to {max(mismatch):+.0f} mpix when a point-sampled PSF fits "
            "pixel-integrated frames). Fitted alone, the faint "
            "star's fit slides onto the primary (about -3000 mpix). None of these choices "
            "gives the paper's ~50 mpix as an IPC effect; with the PSF mismatch of `mixed` the "
            "total passes it. Which the paper had is open: its PSF file and fitter are not "
            "ours.", ""]
    return out


def method_tables(data):
    st = data["study"]
    out = [f"**Fitting methods**, {1 / st['ratio']:g}:1 pair {st['separation']:g} px apart: "
           "faint-star "
           "flux error [%] and separation error [mpix], mean ± std over "
           f"16 positions x {st['n_noise']} realisations with Poisson + read noise (noise-free: 16 "
           "positions). (a) plain photutils-style fit of the coupled frame with the coupled ePSF, "
           "(b) decouple then fit with the decoupled ePSF, (c) IPC-aware forward model; one "
           "least-squares fitter, same pixels, weighted on noisy frames by the noise model "
           "(Poisson + read noise, weights from the model, iteratively reweighted; the "
           "noise-free rows are unweighted). Last column: (b) - (c) on the same frames "
           "(mean ± std): what decoupling adds.", "",
           "| primary | read noise [e-] | (a) plain: flux / sep | (b) decoupled: flux / sep "
           "| (c) forward: flux / sep | (b) - (c): flux / sep |",
           "|---|---|---|---|---|---|"]
    for row in data["rows"]:
        rn = "none (noise-free)" if row["read_noise"] < 0 else f"{row['read_noise']:g}"
        cells = [f"{fmt(row[m]['flux_error_pct'][1])} / {fmt(row[m]['separation_error_mpix'])}"
                 for m in ("plain", "decoupled", "forward")]
        d = row["decoupled"]["vs_forward"]
        cells.append(f"{fmt(d['flux_error_pct'][1])} / {fmt(d['separation_error_mpix'])}")
        out.append(f"| {row['brightness']} | {rn} | " + " | ".join(cells) + " |")
    out.append("")
    return out


def main(argv):
    with open("data/binary_grid.json") as f:
        grid = json.load(f)
    with open("data/binary_methods.json") as f:
        methods = json.load(f)
    flux = ", ".join(f"{k} {v:.3g} e-" for k, v in grid["flux"].items())
    lines = [
        "## Binary-star photometry and astrometry (paper section 4)", "",
        "Figures: `binary_bright.png`, `binary_mid.png`, `binary_dim.png` (noise-free grid), "
        "`binary_noise.png` (noise present), `binary_methods.png` (fitting methods). "
        f"Primaries: {flux} (mag 21.4 / 23.1 / 25.3 at 10 ks; the bright star centred on a "
        "pixel puts 60,000 e- in it). "
        "JWST-like F405N PSF (poppy), donlon2018 law, 4 nearest neighbours, zero edge; pair "
        "along x; photutils 3.0.0 PSFPhotometry, both stars in one group, 9x9 fit boxes, "
        "initial guesses 0.1 px / 5 % off. Flux error = 100 (fit - true) / true; separation "
        "error = 1000 (fitted - true separation), negative = pulled together.", "",
    ]
    lines += headline(grid) + bright_psf(grid) + grid_tables(grid) + method_tables(methods)
    if os.path.exists("data/binary_fitter.json"):
        with open("data/binary_fitter.json") as f:
            lines += fitter_table(json.load(f), grid)
    lines.append(f"Runtime: grid {grid['seconds']:g} s, methods {methods['seconds']:g} s with "
                 f"{grid['workers']} worker processes (time of the last run; cached tasks cost "
                 "nothing).")
    lines.append("")
    with atomic_output("data/50_binary.results.md", overwrite=True) as tmp:
        with open(tmp, "w") as f:
            f.write("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv)

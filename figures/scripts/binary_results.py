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
         "decoupled": "<= 0.01 % / <= 1 mpix", "truth": "0 / 0", "coupled": "-"}


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
        f"| coupled, flux error, IPC-free PSF (paper's fit) | ~1.5 % | {flux(b, 'coupled_optical')} "
        f"| {flux(d, 'coupled_optical')} |",
        f"| coupled, separation error, IPC-free PSF | ~50 mpix | {sep(b, 'coupled_optical')} | "
        f"{sep(d, 'coupled_optical')} (8:1: {e8:+.3g} mpix) |",
        f"| coupled, flux error, coupled ePSF | - | {flux(b, 'coupled')} | {flux(d, 'coupled')} |",
        f"| coupled, separation error, coupled ePSF | - | {sep(b, 'coupled')} | {sep(d, 'coupled')} |",
        f"| decoupled, flux error | <= 0.01 % | {flux(b, 'decoupled')} | {flux(d, 'decoupled')} |",
        f"| decoupled, separation error | <= 1 mpix | {sep(b, 'decoupled')} | {sep(d, 'decoupled')} |",
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
        "than the paper's (their WebbPSF file and DAOphot-era fitter are not ours). Most of "
        "that flux error is the PSF-shape mismatch an isolated star shows too (20 px table). "
        "Fitted with the PSF of isolated coupled stars, the blend-specific IPC error of this pair is at most "
        f"{blend_flux:.2g} % / {blend_sep:.2g} mpix.",
        "",
    ]


def grid_tables(data):
    out = []
    names = [b for b in ("bright", "mid", "dim") if any(r["brightness"] == b for r in data["rows"])]
    st = data["study"]
    for noise, sep in ((False, 3.0), (False, 20.0), (True, 3.0)):
        title = (f"4:1 pair, {sep:g} px apart, "
                 + (f"noise present (Poisson + {st['read_noise']:g} e-)" if noise else "noise-free"))
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
    # detection
    seps = sorted({r["separation"] for r in data["rows"]})
    out += ["**Detection** (IRAFStarFinder, FWHM 2.1 px, on noise-free coupled frames): fraction "
            "of the two stars found within 0.5 px, all ratios and positions", "",
            "| primary | " + " | ".join(f"{s:g} px" for s in seps) + " |",
            "|---|" + "---|" * len(seps)]
    for name in names:
        vals = []
        for s in seps:
            rows = [r for r in data["rows"] if r["brightness"] == name and r["separation"] == s
                    and not r["noise"]]
            vals.append(sum(r["detected"] for r in rows) / len(rows))
        out.append(f"| {name} | " + " | ".join(f"{v:.2f}" for v in vals) + " |")
    out.append("")
    return out


def method_tables(data):
    st = data["study"]
    out = [f"**Fitting methods**, {1 / st['ratio']:g}:1 pair {st['separation']:g} px apart: faint-star "
           "flux error [%] and separation error [mpix], mean ± std over "
           f"16 positions x {st['n_noise']} realisations with Poisson + read noise (noise-free: 16 "
           "positions). (a) plain photutils-style fit of the coupled frame with the coupled ePSF, "
           "(b) decouple then fit with the decoupled ePSF, (c) IPC-aware forward model; one "
           "least-squares fitter, same pixels. Last column: (b) - (c) on the same frames "
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
    lines += headline(grid) + grid_tables(grid) + method_tables(methods)
    lines.append(f"Runtime: grid {grid['seconds']:g} s, methods {methods['seconds']:g} s with "
                 f"{grid['workers']} worker processes (time of the last run; cached tasks cost "
                 "nothing).")
    lines.append("")
    with atomic_output("data/50_binary.results.md", overwrite=True) as tmp:
        with open(tmp, "w") as f:
            f.write("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv)

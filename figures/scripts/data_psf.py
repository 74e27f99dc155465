"""Experiment 40: IPC and the PSF (paper section 3.3 and its conclusion's static 8 %).

The JWST-like F405N optical PSF (poppy, analysis.psf), effective PSFs at
quarter-pixel offsets for the bright, mid and dim sources (21.4, 23.1, 25.3
mag at 10 ks, fluxes from analysis.simulate.ZERO_POINT) in the truth, coupled
and decoupled frames, and a static alpha = 8 % kernel; each for the paper's
point-sampled detector (comb, its Eq. 10) and for the pixel-integrated one.
FWHM by cubic splines through the peak (analysis.fwhm.fwhm_spline), checked
by poppy.measure_fwhm (radial profile).
Writes data/40_psf.npz and data/40_psf.results.md.
"""

import numpy as np

from _common import progress, save_npz, write_results

from analysis.fwhm import fwhm_radial, fwhm_spline
from analysis.psf import effective_psf, jwst_f405n_psf, optical_psf, point_source_image
from ipc_taichi import Geometry, get_law
from analysis.simulate import EXPOSURE_TIME, MAGNITUDES, ZERO_POINT, flux_from_mag

O = 4
SAMPLINGS = ("point", "integrated")
LEVELS = ("bright", "mid", "dim")
STATIC = "constant:0.08"
CROP = 10  # detector pixels each side kept in the .npz
PAPER_FWHM = {"truth": 2.080, "dim": 2.186, "mid": 2.180, "bright": 2.169, "static8": 2.249}
SCALES = (0.063, 0.065)
# the paper's 8 % case moves ~35 % of the charge out of the central pixel: 4 x 8 % to the
# sides leaves ~3 % for the 4 diagonals, 0.75 % each = 0.09375 x 8 %
DIAGONAL = Geometry.terms(diagonal=0.75 / 8)
GRID_ROWS = ("truth", "dim", "mid", "bright", "static8", "static8_diag")
ESTIMATORS = (("point", "radial"), ("point", "spline"), ("integrated", "spline"),
              ("integrated", "radial"))


def fwhm_grid(fluxes):
    """FWHM of each paper row for pixel scale x detector model x estimator x 8 % kernel."""
    out, keep = {}, {}
    for scale in SCALES:
        psf = jwst_f405n_psf(O, pixel_scale=scale)[0]
        for sampling in SAMPLINGS:
            for row in GRID_ROWS:
                if row == "truth":
                    epsf = effective_psf(psf, 1.0, "truth", oversample=O, sampling=sampling)
                elif row.startswith("static8"):
                    epsf = effective_psf(psf, 1.0, "coupled", law=STATIC, oversample=O,
                                         sampling=sampling,
                                         geometry=DIAGONAL if row.endswith("diag") else None)
                else:
                    epsf = effective_psf(psf, fluxes[row], "coupled", oversample=O,
                                         sampling=sampling)
                out[(scale, sampling, "spline", row)] = fwhm_spline(epsf, O).mean
                out[(scale, sampling, "radial", row)] = fwhm_radial(epsf, O)
                if scale == SCALES[0] and row == "static8_diag":
                    keep[f"{sampling}_{row}"] = crop(epsf)
    return out, keep


def grid_text(grid):
    """Markdown: the grid, and which cell comes nearest to each paper row."""
    head = " | ".join(f'{sc}"/px {smp[:5]}. {est}' for sc in SCALES for smp, est in ESTIMATORS)
    lines = [f"| PSF | paper [px] | {head} |", "|---|---|" + "---|" * (len(SCALES) * len(ESTIMATORS))]
    paper = dict(PAPER_FWHM, static8_diag=PAPER_FWHM["static8"])
    label = {"truth": "optical / truth", "static8": "static 8 %, 4 neighbours",
             "static8_diag": "static 8 %, + diagonals 0.75 %"}
    best = {}
    for row in GRID_ROWS:
        cells = []
        for sc in SCALES:
            for smp, est in ESTIMATORS:
                v = grid[(sc, smp, est, row)]
                cells.append(f"{v:.3f}")
                d = abs(v - paper[row])
                if row not in best or d < best[row][0]:
                    best[row] = (d, sc, smp, est, v)
        lines.append(f"| {label.get(row, row + ', coupled')} | {paper[row]:.3f} | " + " | ".join(cells) + " |")
    lines += ["", "| paper row | nearest cell | ours | difference [px] | paper broadening | "
              "that cell's broadening |", "|---|---|---|---|---|---|"]
    for row in GRID_ROWS:
        d, sc, smp, est, v = best[row]
        pb = 100 * (paper[row] / PAPER_FWHM["truth"] - 1)
        ob = 100 * (v / grid[(sc, smp, est, "truth")] - 1) if row != "truth" else 0.0
        lines.append(f"| {label.get(row, row)} ({paper[row]:.3f}) | {sc}\"/px, {smp}, {est} | "
                     f"{v:.3f} | {d:.3f} | {pb:.1f} % | {ob:.2f} % |")
    return "\n".join(lines), best


def crop(epsf):
    c = epsf.shape[0] // 2
    r = CROP * O
    return epsf[c - r:c + r + 1, c - r:c + r + 1]


def main():
    psf = optical_psf("jwst_f405n", O)
    fluxes = {k: float(flux_from_mag(m)) for k, m in MAGNITUDES.items()}
    arrays = {"optical": crop(psf * O * O)}
    meas = {}
    jobs = [(s, name) for s in SAMPLINGS for name in
            ["truth", "static8"] + [f"{lv}_{st}" for lv in LEVELS for st in ("coupled", "decoupled")]]
    for sampling, name in progress(jobs, "effective PSFs"):
        if name == "truth":
            epsf = effective_psf(psf, 1.0, "truth", oversample=O, sampling=sampling)
        elif name == "static8":
            epsf = effective_psf(psf, 1.0, "coupled", law=STATIC, oversample=O, sampling=sampling)
        else:
            level, stage = name.split("_")
            epsf = effective_psf(psf, fluxes[level], stage, oversample=O, sampling=sampling)
        f = fwhm_spline(epsf, O)
        meas[(sampling, name)] = dict(x=f.x, y=f.y, mean=f.mean, peak=f.peak,
                                      radial=fwhm_radial(epsf, O))
        arrays[f"{sampling}_{name}"] = crop(epsf)
    images = {k: point_source_image(psf, 20, 20, (41, 41), v, O) for k, v in fluxes.items()}
    central = {k: float(im[20, 20]) for k, im in images.items()}
    central_point = {k: float(point_source_image(psf, 20, 20, (41, 41), v, O, "point")[20, 20])
                     for k, v in fluxes.items()}
    grid, kept = fwhm_grid(fluxes)
    arrays.update(kept)
    grid_table, best = grid_text(grid)
    widest = max(100 * (grid[k[:3] + ("dim",)] / grid[k[:3] + ("truth",)] - 1) for k in grid)
    cell = best["truth"][1:4]
    same = {row: grid[cell + (row,)] for row in GRID_ROWS}
    # the one cell (and 8 % kernel) that fits all five paper rows best, by its worst row
    single = min((max(abs(grid[(sc, smp, est, row)] - PAPER_FWHM[row.replace("_diag", "")])
                      for row in ("truth", "dim", "mid", "bright", k8)),
                  sc, smp, est, "with diagonals" if k8.endswith("diag") else "4 neighbours")
                 for sc in SCALES for smp, est in ESTIMATORS for k8 in ("static8", "static8_diag"))
    gkeys = sorted(grid)
    # alpha between the central pixel and its brightest neighbour, per source
    law = get_law("donlon2018")
    alpha_core = {k: 100 * float(law.alpha(im[20, 20], im[20, 21])) for k, im in images.items()}
    optical = fwhm_spline(psf, O)
    optical_radial = fwhm_radial(psf, O)
    keys = sorted(meas)
    save_npz("40_psf", oversample=np.array(O), crop=np.array(CROP), **arrays,
             fwhm_keys=np.array([f"{s}_{n}" for s, n in keys]),
             fwhm_x=np.array([meas[k]["x"] for k in keys]),
             fwhm_y=np.array([meas[k]["y"] for k in keys]),
             fwhm_radial=np.array([meas[k]["radial"] for k in keys]),
             peak=np.array([meas[k]["peak"] for k in keys]),
             fluxes=np.array([fluxes[k] for k in LEVELS]), levels=np.array(LEVELS),
             grid_keys=np.array(["|".join(map(str, k)) for k in gkeys]),
             grid_fwhm=np.array([grid[k] for k in gkeys]))

    def fw(s, n):
        return meas[(s, n)]["mean"]

    def broad(s, n):
        return 100 * (fw(s, n) / fw(s, "truth") - 1)

    def drop(s, n):
        return 100 * (1 - meas[(s, n)]["peak"] / meas[(s, "truth")]["peak"])

    rows = [f"| optical / truth | 2.080 (WebbPSF) | {fw('point', 'truth'):.3f} | "
            f"{fw('integrated', 'truth'):.3f} | {meas[('point', 'truth')]['radial']:.3f} | "
            f"{meas[('integrated', 'truth')]['radial']:.3f} |"]
    for lv in ("dim", "mid", "bright"):
        rows.append(f"| {lv}, coupled | {PAPER_FWHM[lv]:.3f} | {fw('point', lv + '_coupled'):.3f} | "
                    f"{fw('integrated', lv + '_coupled'):.3f} | "
                    f"{meas[('point', lv + '_coupled')]['radial']:.3f} | "
                    f"{meas[('integrated', lv + '_coupled')]['radial']:.3f} |")
    rows.append(f"| static alpha = 8 % | 2.249 | {fw('point', 'static8'):.3f} | "
                f"{fw('integrated', 'static8'):.3f} | {meas[('point', 'static8')]['radial']:.3f} | "
                f"{meas[('integrated', 'static8')]['radial']:.3f} |")
    for lv in ("dim", "mid", "bright"):
        rows.append(f"| {lv}, decoupled | = truth | {fw('point', lv + '_decoupled'):.3f} | "
                    f"{fw('integrated', lv + '_decoupled'):.3f} | "
                    f"{meas[('point', lv + '_decoupled')]['radial']:.3f} | "
                    f"{meas[('integrated', lv + '_decoupled')]['radial']:.3f} |")
    table1 = "\n".join(rows)

    paper_broad = {k: 100 * (PAPER_FWHM[k] / PAPER_FWHM["truth"] - 1) for k in PAPER_FWHM}
    rows = []
    for lv in ("dim", "mid", "bright"):
        n = lv + "_coupled"
        rows.append(f"| {lv} | {paper_broad[lv]:.1f} % | {broad('point', n):.2f} % | "
                    f"{broad('integrated', n):.2f} % | 1.2-1.4 % | {drop('point', n):.2f} % | "
                    f"{drop('integrated', n):.2f} % |")
    rows.append(f"| static 8 % | {paper_broad['static8']:.1f} % | {broad('point', 'static8'):.2f} % | "
                f"{broad('integrated', 'static8'):.2f} % | (not given) | {drop('point', 'static8'):.2f} % | "
                f"{drop('integrated', 'static8'):.2f} % |")
    table2 = "\n".join(rows)
    bvd = {s: 100 * (meas[(s, "bright_coupled")]["peak"] - meas[(s, "dim_coupled")]["peak"])
           / meas[(s, "truth")]["peak"] for s in SAMPLINGS}
    dec_err = max(abs(fw(s, lv + "_decoupled") - fw(s, "truth")) for s in SAMPLINGS for lv in LEVELS)
    xy = max(abs(m["x"] - m["y"]) for m in meas.values())
    order = all(fw(s, "dim_coupled") > fw(s, "mid_coupled") > fw(s, "bright_coupled") > fw(s, "truth")
                for s in SAMPLINGS)
    src = "\n".join(f"| {lv} | {MAGNITUDES[lv]} | {fluxes[lv]:.4g} | {central[lv]:.0f} |"
                    for lv in LEVELS)
    write_results("40_psf", f"""
## IPC and the PSF: FWHM and peak (paper section 3.3 and conclusion)

Figures: `psf_3d.png` (paper Fig. 3.3.1), `psf_cross_section.png` (3.3.2),
`psf_difference.png` (3.3.3), `psf_static8.png` (5.0.1).
Data: `data/40_psf.npz` (`figures/scripts/data_psf.py`).

Optical PSF: JWST-like F405N pupil computed offline with poppy (described in `docs/analysis.md`),
4.05 um monochromatic, 0.063"/px, 4x oversampled, 40x40 px field (it holds 94.6 % of the
light; normalised to 1 there). Effective PSFs: the source at the 16 quarter-pixel offsets,
each detector image coupled with `donlon2018` (4 nearest neighbours) at its real signal
level, interleaved to 4x sampling and normalised to unit volume; decoupled with the
paper's stopping rule. Two detector models: **point-sampled** (the paper's Eq. 10: the
optical PSF times a Dirac comb, no pixel integration; its truth is the optical PSF itself)
and **pixel-integrated** (Simpson's rule over each pixel: what a real detector records).

Sources ({EXPOSURE_TIME:.0f} s, F405N zero point {ZERO_POINT} mag for 1 count/s, derived in
`analysis/simulate.py` from the paper's "mag 21.4 nearly saturates the central pixel"
with "nearly saturates" = 60000 counts; not a calibration):

| source | mag | counts | central pixel (pixel-integrated, centred) |
|---|---|---|---|
{src}

**Which FWHM.** "spline": the width at half maximum of a 1-D cubic interpolating spline
through the 4x-sampled effective PSF's row (x) and column (y) through its peak, the mean
of x and y (they differ by at most {xy:.1e} px). "radial": `poppy.measure_fwhm`, the
azimuthally averaged radial profile, as an independent check.

| PSF | paper FWHM [px] | ours: point-sampled, spline | ours: pixel-integrated, spline | ours: point-sampled, radial | ours: pixel-integrated, radial |
|---|---|---|---|---|---|
{table1}

(`poppy.measure_fwhm` on poppy's own even 4x grid gives 2.079 px for this optical PSF; on
our odd grid, centred on a sample, it gives {optical_radial:.3f} px; the spline width of the
same optical PSF is {optical.mean:.3f} px.)

| PSF | paper: FWHM broadening | ours: point | ours: integrated | paper: peak drop | ours: point | ours: integrated |
|---|---|---|---|---|---|---|
{table2}

Bright vs dim peak difference (relative to the truth peak): paper ~0.15 %; ours
{bvd['point']:.2f} % (point-sampled), {bvd['integrated']:.2f} % (pixel-integrated).

Checks: decoupled FWHM equals truth to {dec_err:.1e} px (required: 0.001 px);
dim > mid > bright > truth in both detector models: {order}.

**Which setting gives the paper's FWHM numbers? A grid of the alternatives.** The paper's
table gives arcsec beside pixels, and every row's ratio is 0.0650"/px, not the 0.063"/px
used above; its text does not say how it measured a FWHM. So each paper row is compared
with every cell of: pixel scale (0.063 or 0.065"/px, the same pupil) x detector model
(point-sampled, the paper's Eq. 10, or pixel-integrated) x estimator (`radial`:
`poppy.measure_fwhm`; `spline`: cubic splines through the peak's row and column), and for
the static 8 % case the kernel with 4 neighbours only or with 0.75 % to each diagonal (the
paper says ~35 % of the charge leaves the central pixel: 4 x 8 % = 32 %, so ~3 % goes to
the diagonals). Fluxes as above at both scales.

{grid_table}

What the grid says, as strongly as it can: (1) the paper's 2.080 px is matched within
{best['truth'][0]:.3f} px by the cell {best['truth'][1]}"/px, {best['truth'][2]}, {best['truth'][3]}; at the
paper's own implied scale (0.065"/px) no cell gives 2.080 (point radial
{grid[(0.065, 'point', 'radial', 'truth')]:.3f}, point spline {grid[(0.065, 'point', 'spline', 'truth')]:.3f},
integrated spline {grid[(0.065, 'integrated', 'spline', 'truth')]:.3f}). (2) In that same cell the
coupled rows are {same['bright']:.3f} / {same['mid']:.3f} / {same['dim']:.3f} px (paper 2.169 / 2.180 / 2.186)
and the static 8 % row is {same['static8']:.3f} px with 4 neighbours, {same['static8_diag']:.3f} px with
the diagonals (paper 2.249): with the diagonals the 8 % row comes within
{abs(same['static8_diag'] - 2.249):.3f} px, the IPC rows stay {min(PAPER_FWHM[r] - same[r] for r in LEVELS):.3f}-{max(PAPER_FWHM[r] - same[r] for r in LEVELS):.3f} px short. The single cell that
fits all five paper rows best ({single[1]}"/px, {single[2]}, {single[3]}, {single[4]}) still misses
one row by {single[0]:.3f} px. (3) No cell reproduces the paper's broadening: with this law the
widest broadening in any cell is {widest:.2f} % (the dim source), where the paper has 4.3-5.1 %.
The paper's coupled rows sit near cells of *another* estimator or scale than its truth row
(the table above), but nothing in the paper says it changed estimator between rows: that
is a hypothesis this grid cannot confirm (an earlier version of this file stated it as
the explanation; that was too strong). The static 8 % row alone is matched by several
cells, with and without diagonals, so it does not decide the kernel either.
(4) The abstract's 2.080 -> 2.186, the 1.2-1.4 % peak drop for all
sources and the 0.15 % bright-versus-dim difference stay unreproduced: our bright peak drops
by {drop('point', 'bright_coupled'):.2f} %, our dim peak by {drop('point', 'dim_coupled'):.2f} % (point-sampled);
with this law alpha between the central pixel and its neighbour is
{alpha_core['bright']:.2f} % for the bright source and {alpha_core['dim']:.2f} % for the dim one
(central pixels {central['bright']:.0f} and {central['dim']:.0f} e-), and the peak drop follows alpha.
The paper does not give its sources in counts, so a different flux scale is one open
alternative. (5) Pixel integration alone widens the PSF by
{fw('integrated', 'truth') - fw('point', 'truth'):.3f} px (spline, 0.063"/px); the paper's model omits it.
(6) The zero point is set for the pixel-integrated detector (60000 e- in the bright star's
central pixel); in the point-sampled model the same star puts {central_point['bright']:.0f} e- there,
above the 60000 e- the zero point assumes.
""")


if __name__ == "__main__":
    main()

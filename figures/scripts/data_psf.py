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
from analysis.psf import effective_psf, optical_psf, point_source_image
from ipc_taichi import get_law
from analysis.simulate import EXPOSURE_TIME, MAGNITUDES, ZERO_POINT, flux_from_mag

O = 4
SAMPLINGS = ("point", "integrated")
LEVELS = ("bright", "mid", "dim")
STATIC = "constant:0.08"
CROP = 10  # detector pixels each side kept in the .npz
PAPER_FWHM = {"truth": 2.080, "dim": 2.186, "mid": 2.180, "bright": 2.169, "static8": 2.249}


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
             fluxes=np.array([fluxes[k] for k in LEVELS]), levels=np.array(LEVELS))

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
    close = max(abs(fw("point", lv + "_coupled") - PAPER_FWHM[lv]) for lv in LEVELS)
    order = all(fw(s, "dim_coupled") > fw(s, "mid_coupled") > fw(s, "bright_coupled") > fw(s, "truth")
                for s in SAMPLINGS)
    src = "\n".join(f"| {lv} | {MAGNITUDES[lv]} | {fluxes[lv]:.4g} | {central[lv]:.0f} |"
                    for lv in LEVELS)
    write_results("40_psf", f"""
## IPC and the PSF: FWHM and peak (paper section 3.3 and conclusion)

Figures: `psf_3d.png` (paper Fig. 3.3.1), `psf_cross_section.png` (3.3.2),
`psf_difference.png` (3.3.3), `psf_static8.png` (5.0.1).
Data: `data/40_psf.npz` (`figures/scripts/data_psf.py`).

Optical PSF: JWST-like F405N pupil computed offline with poppy (REFERENCE.md section 5),
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

(REFERENCE.md quotes 2.080 px from `poppy.measure_fwhm` on poppy's own even 4x grid; on
our odd grid, centred on a sample, it gives {optical_radial:.3f} px; the spline width of the
same optical PSF is {optical.mean:.3f} px.)

| PSF | paper: FWHM broadening | ours: point | ours: integrated | paper: peak drop | ours: point | ours: integrated |
|---|---|---|---|---|---|---|
{table2}

Bright vs dim peak difference (relative to the truth peak): paper ~0.15 %; ours
{bvd['point']:.2f} % (point-sampled), {bvd['integrated']:.2f} % (pixel-integrated).

Checks: decoupled FWHM equals truth to {dec_err:.1e} px (required: 0.001 px);
dim > mid > bright > truth in both detector models: {order}.

**Where ours differ, and why.** (1) The paper's 2.080 px for the WebbPSF is the
radial-profile FWHM (`poppy.measure_fwhm`, REFERENCE.md section 5), but a cross section
through the peak of the same PSF is {optical.mean:.3f} px wide: the JWST PSF is hexagonal,
not round. Measured the same way as the truth, our point-sampled coupled PSFs
({fw('point', 'bright_coupled'):.3f} / {fw('point', 'mid_coupled'):.3f} /
{fw('point', 'dim_coupled'):.3f} px for bright / mid / dim) lie within {close:.3f} px of the
paper's 2.169 / 2.180 / 2.186, so the paper's 4.3-5.1 % broadening is consistent with
mostly a change of estimator between its first row and the others; IPC with this law
broadens the PSF by {broad('point', 'bright_coupled'):.2f}-{broad('point', 'dim_coupled'):.2f} %
(point-sampled) or {broad('integrated', 'bright_coupled'):.2f}-{broad('integrated', 'dim_coupled'):.2f} %
(pixel-integrated), dim more than bright as the paper says. (2) Pixel integration alone
widens the PSF by {fw('integrated', 'truth') - fw('point', 'truth'):.3f} px; the paper's
model omits it. (3) The static 8 % kernel gives {fw('point', 'static8'):.3f} px by our
spline (paper 2.249; our radial estimate {meas[('point', 'static8')]['radial']:.3f});
we do not know how the paper's value was measured. (4) Our bright peak drops by
{drop('point', 'bright_coupled'):.2f} %, inside the paper's 1.2-1.4 %, but our dim peak drops
by {drop('point', 'dim_coupled'):.2f} %, so bright and dim differ by about {bvd['point']:.1f} %, not 0.15 %.
With this law, alpha between the central pixel and its neighbour is
{alpha_core['bright']:.2f} % for the bright source and {alpha_core['dim']:.2f} % for the dim one
(central pixels {central['bright']:.0f} and {central['dim']:.0f} counts), and the peak drop
follows alpha; we could not reproduce the paper's 0.15 %, and the paper does not give its
source fluxes in counts.
""")


if __name__ == "__main__":
    main()

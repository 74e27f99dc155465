"""Calibrate does not depend on the units given (issue 35, item 4).

The same dark given at gains x0.1, x1 and x10: the floors follow the darks'
own noise (stated in electrons), the held-out check measures the same hot
pixels at every gain, and a law richer than a constant is written only when
its held-out residual beats the constant's."""

import os

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.calibrate import calibrate, hotpixels
from tests.independent import mapgen

NIRSPEC = os.path.join(os.path.dirname(__file__), "data", "jwst_nirspec_nrs1_dark_sub512.fits")


def _check(result):
    t = result["report"]["transfer"]
    fit = result["report"]["fit"]
    if fit["chosen"] != "constant":
        assert abs(t["chosen"]["residual"]) < abs(t["constant"]["residual"])
    return t, result["report"]["hot_pixels"]["floors_e"]


def test_floors_follow_the_noise_and_are_stated():
    assert hotpixels.floors(None)["bins"] == hotpixels.DEFAULT_FLOORS[0]
    f = hotpixels.floors(10.0)
    assert f["bins"] == pytest.approx(10 * hotpixels.BIN_FLOOR_READ_NOISE)
    assert f["score"] == pytest.approx(10 * hotpixels.SCORE_FLOOR_READ_NOISE)
    assert "10 e-" in f["source"]
    frame = np.random.default_rng(1).normal(0.0, 7.0, (64, 64))
    assert hotpixels.frame_noise(frame) == pytest.approx(7.0, rel=0.05)


@pytest.mark.slow
def test_same_dark_at_three_gains_gives_the_same_held_out_check(tmp_path):
    ramp = mapgen.dark_ramp((128, 128), ngroups=4, n_hot=200, mapped=False, seed=11)
    path = str(tmp_path / "dark.fits")
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(ramp["sci"], name="SCI")]).writeto(path)
    counts, chosen, alphas, scaled = [], [], [], []
    for k in (0.1, 1.0, 10.0):
        result = calibrate([path], gain=2.0 * k, bunit="DN", measure_map=False)
        t, floors = _check(result)
        assert t["chosen"]["n_pixels"] >= 20
        counts.append(t["chosen"]["n_pixels"])
        chosen.append(result["report"]["fit"]["chosen"])
        alphas.append(result["model"].law.alpha(1e4 * k, 0.0))
        scaled.append(floors["score"] / k)  # in electrons, it follows the gain
    assert len(set(counts)) == 1 and len(set(chosen)) == 1
    assert np.ptp(scaled) < 1e-6 * scaled[0]
    assert np.ptp(alphas) < 1e-6  # the same law, in electrons


@pytest.mark.slow
def test_real_nirspec_dark_is_the_same_at_three_gains():
    seen = []
    for k in (0.1, 1.0, 10.0):
        result = calibrate([NIRSPEC], gain=k, measure_map=False)
        t, floors = _check(result)
        assert t["chosen"]["n_pixels"] > 0, result["report"]["not_measured"]
        seen.append((t["chosen"]["n_pixels"], result["report"]["fit"]["chosen"],
                     round(floors["score"] / k, 6)))
    assert len(set(seen)) == 1, seen


def test_reference_with_darks_is_compared_and_a_dummy_named(tmp_path):
    from ipc_taichi.calibrate import reffiles
    from ipc_taichi.calibrate.report import summary_lines

    forward = np.array([[0.0, 0.006, 0.0], [0.006, 0.976, 0.006], [0.0, 0.006, 0.0]])
    hdu = fits.PrimaryHDU()
    hdu.header["REFTYPE"] = "IPC"
    hdu.header["TELESCOP"] = "JWST"
    hdu.header["PEDIGREE"] = "DUMMY"
    ref = tmp_path / "jwst_ipc.fits"
    fits.HDUList([hdu, fits.ImageHDU(reffiles.invert_kernel(forward), name="SCI")]).writeto(ref)
    ramp = mapgen.dark_ramp((96, 96), ngroups=3, n_hot=60, mapped=False, seed=12)
    dark = str(tmp_path / "dark.fits")
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(ramp["sci"], name="SCI")]).writeto(dark)
    result = calibrate([dark], reference=str(ref), gain=2.0, bunit="DN", measure_map=False)
    lines = [x for x in summary_lines(result["report"], result["model"])
             if "reference" in x.split(":")[0]]
    assert len(lines) == 1 and lines[0].startswith("DUMMY reference (PEDIGREE = 'DUMMY'")
    assert "0.600 % against" in lines[0] and "measured at (10 ke-, 0)" in lines[0]

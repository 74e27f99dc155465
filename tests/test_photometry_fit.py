"""photutils PSF fitting of single stars and pairs (analysis.photometry)."""

import numpy as np
import pytest

from analysis.photometry import StarFit, detect_stars, fit_stars, image_psf, pair_errors
from analysis.psf import effective_psf, point_source_image

BRIGHT = 4.0e5


@pytest.fixture(scope="module")
def epsf_coupled(psf):
    return effective_psf(psf, BRIGHT, stage="coupled")


def pair_scene(psf, x1, y1, sep, f1, f2, shape=(25, 50)):
    return (point_source_image(psf, x1, y1, shape, f1)
            + point_source_image(psf, x1 + sep, y1, shape, f2))


def test_image_psf_rejects_unit_normalisation(epsf_truth):
    with pytest.raises(ValueError, match=r"sums to 1, expected oversample\*\*2 = 16"):
        image_psf(epsf_truth / 16.0)
    with pytest.raises(ValueError, match="odd side"):
        image_psf(epsf_truth[:-1, :-1])


@pytest.mark.parametrize("x, y", [(12.0, 12.0), (12.25, 11.5), (12.75, 12.5)])
def test_isolated_star_recovered_exactly_from_truth_frame(psf, epsf_truth, x, y):
    frame = point_source_image(psf, x, y, (25, 25), BRIGHT)
    fit = fit_stars(frame, image_psf(epsf_truth), [x + 0.2], [y - 0.15], [0.9 * BRIGHT])
    assert fit.flags[0] == 0
    assert fit.flux[0] == pytest.approx(BRIGHT, rel=1e-9)
    assert fit.x[0] == pytest.approx(x, abs=1e-9)
    assert fit.y[0] == pytest.approx(y, abs=1e-9)


def test_sequential_fits_with_different_psfs_are_not_mixed_up(psf, epsf_truth, epsf_coupled):
    """The photutils 3.0.0 flat-model cache must not carry one ImagePSF into the next fit."""
    import ipc_taichi

    truth = pair_scene(psf, 12.25, 12.5, 3.0, BRIGHT, BRIGHT / 4)
    coupled = ipc_taichi.couple(truth)
    init = ([12.35, 15.15], [12.45, 12.55], [1.05 * BRIGHT, 0.95 * BRIGHT / 4])
    first = fit_stars(truth, image_psf(epsf_truth), *init)
    other = fit_stars(coupled, image_psf(epsf_coupled), *init)
    again = fit_stars(truth, image_psf(epsf_truth), *init)
    np.testing.assert_allclose(first.flux, [BRIGHT, BRIGHT / 4], rtol=1e-9)
    np.testing.assert_allclose(again.flux, first.flux, rtol=1e-12)
    # the coupled fit really used the coupled PSF: it differs from the truth fit
    assert abs(other.flux[1] / first.flux[1] - 1) > 1e-3


def _pair_and_alone(psf, epsf, sep, frame_of):
    """Fluxes of the secondary fitted in the pair and in a frame of its own."""
    f1, f2, x1, y1 = BRIGHT, BRIGHT / 4, 12.25, 12.5
    model = image_psf(epsf)
    pair = fit_stars(frame_of(pair_scene(psf, x1, y1, sep, f1, f2)), model,
                     [x1 + 0.1, x1 + sep - 0.1], [y1 + 0.05, y1 - 0.05], [1.05 * f1, 0.95 * f2])
    alone = fit_stars(frame_of(pair_scene(psf, x1, y1, sep, 0.0, f2)), model,
                      [x1 + sep - 0.1], [y1 - 0.05], [0.95 * f2])
    return pair, alone


def test_20px_pair_shows_no_blending_bias(psf, epsf_truth, epsf_coupled):
    import ipc_taichi

    # truth frame: both stars exact
    pair, _ = _pair_and_alone(psf, epsf_truth, 20.0, lambda s: s)
    flux_error, sep_error = pair_errors(pair, [12.25, 32.25], [12.5, 12.5], [BRIGHT, BRIGHT / 4])
    np.testing.assert_allclose(flux_error, 0.0, atol=1e-7)
    assert abs(sep_error) < 1e-6
    # coupled frame: the faint star in the pair measures as it does alone ...
    pair20, alone20 = _pair_and_alone(psf, epsf_coupled, 20.0, ipc_taichi.couple)
    blend20 = abs(pair20.flux[1] / alone20.flux[0] - 1)
    assert blend20 < 2e-5
    assert abs(pair20.x[1] - alone20.x[0]) < 1e-4
    # ... which is not so 3 px apart, where IPC couples the blend as a whole
    pair3, alone3 = _pair_and_alone(psf, epsf_coupled, 3.0, ipc_taichi.couple)
    assert abs(pair3.flux[1] / alone3.flux[0] - 1) > 50 * blend20


def test_pair_errors_arithmetic():
    fit = StarFit(x=np.array([10.0, 13.004]), y=np.array([5.0, 5.0]),
                  flux=np.array([101.0, 24.5]), flags=np.zeros(2, int))
    flux_error, sep_error = pair_errors(fit, [10.0, 13.0], [5.0, 5.0], [100.0, 25.0])
    np.testing.assert_allclose(flux_error, [1.0, -2.0])
    assert sep_error == pytest.approx(4.0)


def test_detect_stars_splits_a_wide_pair_only(psf):
    wide = pair_scene(psf, 12.0, 12.0, 20.0, BRIGHT, BRIGHT / 4)
    x, y = detect_stars(wide, fwhm=2.1, threshold=1000.0, min_separation=1.0)
    for xt in (12.0, 32.0):
        assert np.min(np.hypot(x - xt, y - 12.0)) < 0.1
    x, y = detect_stars(np.zeros((20, 20)), fwhm=2.1, threshold=1.0, min_separation=1.0)
    assert x.size == 0 and y.size == 0
    with pytest.raises(ValueError, match="unknown finder"):
        detect_stars(wide, 2.1, 1.0, min_separation=1.0, finder="sextractor")
    with pytest.raises(TypeError):
        detect_stars(wide, 2.1, 1.0)          # min_separation must be chosen explicitly
    with pytest.raises(ValueError, match="min_separation"):
        detect_stars(wide, 2.1, 1.0, min_separation=None)


@pytest.mark.parametrize("finder", ["iraf", "dao"])
def test_close_pair_is_split_or_merged_by_min_separation_alone(psf, finder):
    """A noise-free coupled 1:1 pair 3 px apart: found with min_separation = 1 px,
    merged at photutils' default 2.5 x FWHM = 5.25 px (a setting, not IPC)."""
    import ipc_taichi

    x1, y1 = 12.0, 12.0
    frame = ipc_taichi.couple(pair_scene(psf, x1, y1, 3.0, BRIGHT, BRIGHT))
    threshold = 0.02 * frame.max()

    def found(min_sep):
        x, y = detect_stars(frame, 2.1, threshold, min_separation=min_sep, finder=finder)
        return sum(bool(np.any(np.hypot(x - xt, y - y1) < 0.5)) for xt in (x1, x1 + 3.0))

    assert found(1.0) == 2
    assert found(5.25) <= 1

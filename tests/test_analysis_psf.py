"""Known-answer tests for analysis.psf and analysis.fwhm."""

import math

import numpy as np
import pytest
from scipy.special import erf

from analysis.fwhm import fwhm_azimuthal, fwhm_gaussian_fit, fwhm_profile, fwhm_spline
from analysis.psf import (
    airy_psf,
    continuous_psf,
    effective_psf,
    optical_psf,
    point_source_image,
    read_psf_file,
)

OVERSAMPLE = 4


def gaussian_psf(sigma, half=48, o=OVERSAMPLE, samples="point"):
    """A unit Gaussian on the 1/o grid, sum 1: point samples, or the integrals
    over each 1/o x 1/o sub-pixel (poppy's reading of an oversampled array)."""
    t = np.arange(-half, half + 1) / o
    if samples == "point":
        g = np.exp(-0.5 * (t / sigma) ** 2)
    else:
        s = sigma * math.sqrt(2)
        g = 0.5 * (erf((t + 0.5 / o) / s) - erf((t - 0.5 / o) / s))
    psf = np.outer(g, g)
    return psf / psf.sum()


def integrated_gaussian(sigma, offsets):
    """Exact integral of a unit 1-D Gaussian over pixels [u - 1/2, u + 1/2]."""
    s = sigma * math.sqrt(2)
    return 0.5 * (erf((offsets + 0.5) / s) - erf((offsets - 0.5) / s))


def test_fwhm_of_gaussian_matches_analytic():
    sigma = 0.9
    psf = gaussian_psf(sigma)
    f = fwhm_spline(psf, OVERSAMPLE)
    expected = 2 * math.sqrt(2 * math.log(2)) * sigma
    assert f.x == pytest.approx(expected, abs=2e-4)
    assert f.y == pytest.approx(expected, abs=2e-4)
    assert f.peak == pytest.approx(psf.max(), rel=1e-9)


def test_fwhm_profile_off_grid_peak():
    t = np.arange(0, 20, 0.25)
    f = np.exp(-0.5 * ((t - 9.13) / 1.3) ** 2)
    width, peak, centre = fwhm_profile(f, 0.25)
    assert width / 0.25 * 0.25 == pytest.approx(2.3548200 * 1.3, abs=2e-3)
    assert centre == pytest.approx(9.13, abs=2e-3)
    assert peak == pytest.approx(1.0, abs=2e-3)


def test_fwhm_of_airy_disk_matches_analytic():
    psf = airy_psf(OVERSAMPLE)
    lam_over_d = 4.05e-6 / 6.5 * (180 * 3600 / math.pi) / 0.063  # [px]
    f = fwhm_spline(psf, OVERSAMPLE)
    assert f.x == pytest.approx(1.028993 * lam_over_d, abs=1e-3)
    assert f.y == pytest.approx(f.x, abs=1e-9)
    # the azimuthal-profile half maximum measures the same (circular) disk independently
    assert fwhm_azimuthal(psf, OVERSAMPLE) == pytest.approx(1.028993 * lam_over_d, abs=1e-3)
    # poppy's measure_fwhm fits a Gaussian to every sample above 10 % of the peak: for the
    # Airy core that Gaussian is narrower than the half maximum, so it is not one
    assert fwhm_gaussian_fit(psf, OVERSAMPLE) < 0.975 * fwhm_azimuthal(psf, OVERSAMPLE)


def test_fwhm_azimuthal_of_gaussians():
    sigma = 0.9
    expected = 2 * math.sqrt(2 * math.log(2)) * sigma
    assert fwhm_azimuthal(gaussian_psf(sigma), OVERSAMPLE) == pytest.approx(expected, abs=1e-4)
    # a Gaussian fitted to a Gaussian is exact: the two agree only for a Gaussian PSF
    assert fwhm_gaussian_fit(gaussian_psf(sigma), OVERSAMPLE) == pytest.approx(expected, abs=1e-3)
    # off-centre peak: the centre is found, not assumed
    t = np.arange(-40, 41) / OVERSAMPLE
    g = np.exp(-0.5 * ((t[:, None] - 0.13) ** 2 + (t[None, :] + 0.31) ** 2) / sigma ** 2)
    assert fwhm_azimuthal(g, OVERSAMPLE) == pytest.approx(expected, abs=5e-4)
    # elliptical: the azimuthal half maximum lies between the two axes' widths
    ell = np.exp(-0.5 * ((t[:, None] / 0.8) ** 2 + (t[None, :] / 1.1) ** 2))
    f = fwhm_spline(ell, OVERSAMPLE)
    assert f.y < fwhm_azimuthal(ell, OVERSAMPLE) < f.x


def test_fwhm_azimuthal_rejects_bad_input():
    with pytest.raises(ValueError, match="half its maximum"):
        fwhm_azimuthal(np.full((9, 9), 0.6) + np.pad([[0.4]], 4), OVERSAMPLE)
    with pytest.raises(ValueError, match="2-D"):
        fwhm_azimuthal(np.ones(9), OVERSAMPLE)


def test_fwhm_rejects_unresolved_profile():
    with pytest.raises(ValueError, match="half"):
        fwhm_profile(np.array([0.9, 0.95, 1.0, 0.97, 0.2, 0.1]))
    with pytest.raises(ValueError, match="end"):
        fwhm_profile(np.linspace(2, 1, 10))


@pytest.mark.parametrize("o, samples, tol", [(4, "point", 1e-4), (3, "subpixel", 1e-12)])
def test_point_source_image_is_pixel_integrated_gaussian(o, samples, tol):
    sigma = 1.1
    psf = gaussian_psf(sigma, half=14 * o, o=o, samples=samples)
    x, y = 10 + 1 / o, 9 + 2 / o
    image = point_source_image(psf, x, y, (21, 21), flux=500.0, oversample=o)
    gy = integrated_gaussian(sigma, np.arange(21) - y)
    gx = integrated_gaussian(sigma, np.arange(21) - x)
    expected = 500.0 * np.outer(gy, gx) / integrated_gaussian(sigma, np.arange(-14, 15)).sum() ** 2
    # even o: Simpson's rule on point samples, O(h^4); odd o: the midpoint rule,
    # exact when each sample holds the light of its own sub-pixel
    assert np.abs(image - expected).max() < tol * expected.max()
    assert image.sum() == pytest.approx(500.0, rel=1e-9)


def test_point_source_image_total_is_flux_inside_frame():
    psf = optical_psf("airy", OVERSAMPLE)
    full = point_source_image(psf, 20, 20, (41, 41), flux=1.0)
    assert full.sum() == pytest.approx(psf.sum(), rel=1e-12)
    # a Gaussian source on the centre of the corner pixel: the frame holds the
    # quadrant beyond -1/2 pixel in x and y
    sigma = 1.3
    g = gaussian_psf(sigma, half=60)
    corner = point_source_image(g, 0, 0, (41, 41), flux=1.0)
    inside = (0.5 * (1 + erf(0.5 / (sigma * math.sqrt(2))))) ** 2
    assert corner.sum() == pytest.approx(inside, abs=1e-3)
    with pytest.raises(ValueError, match="grid"):
        point_source_image(psf, 20.1, 20, (41, 41))


@pytest.mark.parametrize("o, samples, tol", [(4, "point", 3e-4), (3, "subpixel", 1e-12)])
def test_interleave_reproduces_integrated_gaussian(o, samples, tol):
    sigma = 1.0
    psf = gaussian_psf(sigma, half=10 * o, o=o, samples=samples)
    epsf = effective_psf(psf, 1.0, stage="truth", oversample=o)
    assert epsf.shape[0] % 2 == 1
    assert epsf.sum() == pytest.approx(o * o, rel=1e-12)
    u = (np.arange(epsf.shape[0]) - epsf.shape[0] // 2) / o
    g = integrated_gaussian(sigma, u)
    expected = o * o * np.outer(g, g) / np.outer(g, g).sum()
    assert np.abs(epsf - expected).max() < tol * expected.max()
    # asymmetry would reveal a wrong offset sign in the interleave
    assert np.abs(epsf - epsf[::-1, ::-1]).max() < 1e-12


def test_interleave_point_sampling_returns_optical_psf():
    psf = optical_psf("airy", OVERSAMPLE)
    epsf = effective_psf(psf, 1.0, stage="truth", sampling="point", size=41)
    assert np.allclose(epsf, OVERSAMPLE * OVERSAMPLE * psf / psf.sum(), rtol=0, atol=1e-15)


def test_decoupled_psf_equals_truth(cpu):
    psf = optical_psf("jwst_f405n", OVERSAMPLE)
    truth = effective_psf(psf, 4e5, stage="truth")
    coupled = effective_psf(psf, 4e5, stage="coupled")
    decoupled = effective_psf(psf, 4e5, stage="decoupled", max_iter=40, tol=1e-14)
    assert np.abs(coupled - truth).max() > 1e-3 * truth.max()
    assert np.abs(decoupled - truth).max() < 1e-10 * truth.max()
    assert fwhm_spline(decoupled).x == pytest.approx(fwhm_spline(truth).x, abs=1e-9)


def test_ipc_broadens_dim_more_than_bright(cpu):
    psf = optical_psf("jwst_f405n", OVERSAMPLE)
    widths = [fwhm_spline(effective_psf(psf, flux, "coupled")).x for flux in (1e4, 4e5)]
    truth = fwhm_spline(effective_psf(psf, 1.0, "truth")).x
    assert widths[0] > widths[1] > truth


def test_jwst_psf_properties():
    psf = optical_psf("jwst_f405n", OVERSAMPLE)
    c = psf.shape[0] // 2
    assert psf.shape == (161, 161)
    assert psf.sum() == pytest.approx(1.0, rel=1e-12)
    assert np.unravel_index(psf.argmax(), psf.shape) == (c, c)
    # poppy's Gaussian-fit FWHM is 2.079 px on poppy's even 4x grid (docs/analysis.md), 2.075
    # on ours; the half maximum of the same PSF is 2.162 px (spline and azimuthal profile)
    assert fwhm_gaussian_fit(psf, OVERSAMPLE) == pytest.approx(2.075, abs=0.002)
    assert fwhm_azimuthal(psf, OVERSAMPLE) == pytest.approx(2.162, abs=0.002)
    assert fwhm_spline(psf, OVERSAMPLE).mean == pytest.approx(2.162, abs=0.002)


def test_continuous_psf_interpolates_samples():
    psf = gaussian_psf(1.0, half=20)
    spline = continuous_psf(psf, OVERSAMPLE)
    assert spline(0.0, 0.0)[0, 0] == pytest.approx(psf.max(), rel=1e-12)
    assert spline(0.25, -0.5)[0, 0] == pytest.approx(psf[21, 18], rel=1e-12)


def test_read_psf_file_even_array_recentred(tmp_path):
    from astropy.io import fits

    # poppy/WebbPSF convention: an even array centred between the middle samples
    t = (np.arange(64) - 31.5) / OVERSAMPLE
    g = np.exp(-0.5 * (t / 1.2) ** 2)
    hdu = fits.PrimaryHDU(np.outer(g, g))
    hdu.header["OVERSAMP"] = 4
    path = tmp_path / "psf.fits"
    fits.HDUList([hdu]).writeto(path)
    psf = read_psf_file(str(path), 4)
    c = psf.shape[0] // 2
    assert psf.shape == (65, 65)
    assert np.unravel_index(psf.argmax(), psf.shape) == (c, c)
    assert psf.sum() == pytest.approx(1.0)
    assert fwhm_spline(psf).x == pytest.approx(2.35482 * 1.2, abs=5e-3)
    with pytest.raises(ValueError, match="OVERSAMP"):
        read_psf_file(str(path), 2)
    with pytest.raises(ValueError, match="no such file"):
        optical_psf(str(tmp_path / "missing.fits"))


def test_read_psf_file_prefers_det_samp_over_fft_oversamp(tmp_path):
    """poppy writes OVERSAMP (its FFT oversampling) and DET_SAMP (samples per detector
    pixel); a valid 4x file with OVERSAMP = 2 must load at oversample=4."""
    from astropy.io import fits

    t = (np.arange(65) - 32) / OVERSAMPLE
    g = np.exp(-0.5 * (t / 1.2) ** 2)
    hdu = fits.PrimaryHDU(np.outer(g, g))
    hdu.header["OVERSAMP"] = 2
    hdu.header["DET_SAMP"] = 4
    path = tmp_path / "poppy.fits"
    fits.HDUList([hdu]).writeto(path)
    assert read_psf_file(str(path), 4).shape == (65, 65)
    with pytest.raises(ValueError, match=r"4x \(DET_SAMP\).*pass oversample=4"):
        read_psf_file(str(path), 2)

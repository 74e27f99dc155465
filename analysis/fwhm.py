"""Full width at half maximum of a sampled PSF.

Three estimators, each named for what it measures (the paper does not say
which it used; figures/RESULTS.md compares its numbers with each):

:func:`fwhm_spline` (cross sections)
    A 1-D cubic interpolating spline through the samples of the row (for x)
    and of the column (for y) that hold the PSF's largest sample; the maximum
    of the spline is the peak, and the FWHM is the distance between the two
    points where the spline falls to half of it (found by root bracketing).
:func:`fwhm_azimuthal` (azimuthal-average profile)
    The mean of the PSF over circles about its centre (a bicubic spline of
    the samples, evaluated at equally spaced angles) as a function of radius;
    the FWHM is twice the radius where that mean falls to half the central
    value. For a non-circular PSF it averages all directions, so it differs
    from the x and y cross sections.
:func:`fwhm_gaussian_fit` (Gaussian fitted to the core)
    :func:`poppy.measure_fwhm` (poppy 1.1.2; WebbPSF/stpsf ship the same
    function): a 1-D Gaussian of radius, its mean fixed at the array centre,
    fitted by least squares to *every sample* above 10 % of the peak; the FWHM
    is that Gaussian's. It is not a half-maximum measurement: for an Airy-like
    core with its shoulders the fitted Gaussian is narrower than the profile's
    half-maximum width (by ~4 % for the JWST-like F405N PSF: 2.075 against
    2.16 px). Earlier versions called it ``fwhm_radial``, which it is not.

All take arrays sampled every ``1/oversample`` detector pixel and return
widths in detector pixels.
"""

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline, RectBivariateSpline
from scipy.optimize import brentq, minimize, minimize_scalar

__all__ = ["FWHM", "fwhm_spline", "fwhm_profile", "fwhm_azimuthal", "fwhm_gaussian_fit"]

AZIMUTHS = 360
"""Angles at which :func:`fwhm_azimuthal` samples each circle (every 1 degree)."""


@dataclass(frozen=True)
class FWHM:
    """FWHM of a sampled PSF along x and y [detector pixels] and its peak.

    Attributes
    ----------
    x, y : float
        Width of the cross section through the peak along x (a row) and y (a column).
    peak : float
        Maximum of the spline through the peak's row (same units as the PSF).
    """

    x: float
    y: float
    peak: float

    @property
    def mean(self):
        """Mean of the x and y widths."""
        return 0.5 * (self.x + self.y)


def fwhm_profile(profile, spacing=1.0):
    """FWHM and peak of a 1-D profile by a cubic spline through its samples.

    Parameters
    ----------
    profile : 1-D array
        Samples with one maximum well inside the array that falls below half
        of it on both sides.
    spacing : float
        Distance between samples (e.g. 0.25 pixel for 4x oversampling).

    Returns
    -------
    fwhm, peak, centre : float
        Width (in units of ``spacing``), the spline's maximum and its position.
    """
    f = np.asarray(profile, dtype=np.float64)
    if f.ndim != 1 or f.size < 5 or not np.all(np.isfinite(f)):
        raise ValueError(f"profile must be a finite 1-D array of >= 5 samples, got shape {f.shape}")
    t = np.arange(f.size) * float(spacing)
    spline = CubicSpline(t, f)
    k = int(np.argmax(f))
    if k == 0 or k == f.size - 1:
        raise ValueError("the profile's maximum is at its end; cannot measure a FWHM")
    best = minimize_scalar(lambda v: -spline(v), bounds=(t[k - 1], t[k + 1]), method="bounded",
                           options={"xatol": 1e-10 * max(spacing, 1.0)})
    centre, peak = float(best.x), float(-best.fun)
    half = 0.5 * peak
    below = np.nonzero(f < half)[0]
    left, right = below[below < k], below[below > k]
    if left.size == 0 or right.size == 0:
        raise ValueError("the profile does not fall to half its maximum on both sides")
    i, j = left[-1], right[0]
    # the half-maximum points lie in the last sample intervals that cross half
    lo = brentq(lambda v: spline(v) - half, t[i], max(t[i + 1], t[i]), xtol=1e-12)
    hi = brentq(lambda v: spline(v) - half, t[j - 1], t[j], xtol=1e-12)
    return hi - lo, peak, centre


def fwhm_spline(psf, oversample=4):
    """FWHM of a 2-D PSF along x and y by cubic splines through its peak.

    Parameters
    ----------
    psf : 2-D array
        Sampled every ``1/oversample`` detector pixel, ``psf[y, x]``.
    oversample : int
        Samples per detector pixel.

    Returns
    -------
    FWHM
    """
    a = np.asarray(psf, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"psf must be 2-D, got shape {a.shape}")
    iy, ix = np.unravel_index(int(np.argmax(a)), a.shape)
    wx, peak, _ = fwhm_profile(a[iy, :], 1.0 / oversample)
    wy, _, _ = fwhm_profile(a[:, ix], 1.0 / oversample)
    return FWHM(x=wx, y=wy, peak=peak)


def fwhm_azimuthal(psf, oversample=4, azimuths=AZIMUTHS):
    """FWHM [detector pixels] at the half maximum of the azimuthal-average profile.

    Parameters
    ----------
    psf : 2-D array
        Sampled every ``1/oversample`` detector pixel, ``psf[y, x]``, one
        maximum well inside the array.
    oversample : int
        Samples per detector pixel.
    azimuths : int
        Equally spaced angles on each circle.

    Returns
    -------
    float
        Twice the radius at which the mean of the PSF over the circle about
        its centre falls to half the central value. The centre and the central
        value are the maximum of a bicubic interpolating spline of the samples
        (found within one sample of the largest sample).
    """
    a = np.asarray(psf, dtype=np.float64)
    if a.ndim != 2 or min(a.shape) < 5 or not np.all(np.isfinite(a)):
        raise ValueError("psf must be a finite 2-D array of at least 5x5 samples, "
                         f"got shape {a.shape}")
    h = 1.0 / oversample
    ty, tx = np.arange(a.shape[0]) * h, np.arange(a.shape[1]) * h
    spline = RectBivariateSpline(ty, tx, a, kx=3, ky=3, s=0)
    iy, ix = np.unravel_index(int(np.argmax(a)), a.shape)
    best = minimize(lambda p: -spline.ev(p[0], p[1]), x0=[ty[iy], tx[ix]], method="L-BFGS-B",
                    bounds=[(ty[iy] - h, ty[iy] + h), (tx[ix] - h, tx[ix] + h)],
                    options={"ftol": 1e-15, "gtol": 1e-12})
    (cy, cx), half = best.x, -0.5 * float(best.fun)
    theta = np.linspace(0.0, 2 * np.pi, int(azimuths), endpoint=False)
    cos, sin = np.cos(theta), np.sin(theta)
    r_max = min(cy - ty[0], ty[-1] - cy, cx - tx[0], tx[-1] - cx)

    def excess(r):
        return float(spline.ev(cy + r * sin, cx + r * cos).mean()) - half

    radii = np.arange(h / 4, r_max, h / 4)
    below = [r for r in radii if excess(r) < 0]
    if not below:
        raise ValueError("the azimuthal profile does not fall to half its maximum inside the array")
    r_hi = below[0]
    return 2.0 * brentq(excess, r_hi - h / 4, r_hi, xtol=1e-12)


def fwhm_gaussian_fit(psf, oversample=4):
    """FWHM [detector pixels] of a Gaussian fitted to the core (:func:`poppy.measure_fwhm`).

    poppy fits ``A exp(-r^2 / 2 s^2)``, ``r`` the distance from the array
    centre, to every sample above 10 % of the peak and returns
    ``2 sqrt(2 ln 2) s``; not a half-maximum measurement (module docstring).
    """
    import poppy
    from astropy.io import fits

    a = np.asarray(psf, dtype=np.float64)
    hdu = fits.PrimaryHDU(a)
    # poppy reports in the unit of PIXELSCL: one sample = 1/oversample detector pixel
    hdu.header["PIXELSCL"] = 1.0 / oversample
    return float(poppy.measure_fwhm(fits.HDUList([hdu]), ext=0))

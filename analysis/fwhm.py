"""Full width at half maximum of a sampled PSF.

Two estimators, so that each checks the other:

:func:`fwhm_spline` (the paper's method)
    A 1-D cubic interpolating spline through the samples of the row (for x)
    and of the column (for y) that hold the PSF's largest sample; the maximum
    of the spline is the peak, and the FWHM is the distance between the two
    points where the spline falls to half of it (found by root bracketing).
:func:`fwhm_radial` (independent)
    :func:`poppy.measure_fwhm`: an azimuthally averaged radial profile about
    the PSF centre, interpolated to half its central value. It averages over
    all directions, so for a non-circular PSF it differs from the x and y
    cross sections.

Both take arrays sampled every ``1/oversample`` detector pixel and return
widths in detector pixels.
"""

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import brentq, minimize_scalar

__all__ = ["FWHM", "fwhm_spline", "fwhm_profile", "fwhm_radial"]


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


def fwhm_radial(psf, oversample=4):
    """FWHM [detector pixels] from the azimuthal radial profile (:func:`poppy.measure_fwhm`)."""
    import poppy
    from astropy.io import fits

    a = np.asarray(psf, dtype=np.float64)
    hdu = fits.PrimaryHDU(a)
    # poppy reports in the unit of PIXELSCL: one sample = 1/oversample detector pixel
    hdu.header["PIXELSCL"] = 1.0 / oversample
    return float(poppy.measure_fwhm(fits.HDUList([hdu]), ext=0))

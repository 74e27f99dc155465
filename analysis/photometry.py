"""PSF photometry of blended stars with photutils, and star detection.

Simultaneous PSF fitting of a group of stars with photutils 3.0.0
(``PSFPhotometry`` + ``ImagePSF`` + ``SourceGrouper``) on one frame, given
initial positions and fluxes, plus the star finders (``IRAFStarFinder``,
``DAOStarFinder``) for the cases where detection works.

Conventions: images are ``image[y, x]``, 0-based, integer coordinates at pixel
centres (the photutils and ``ipc_taichi`` convention). An *effective PSF*
(ePSF) here is a pixel-integrated PSF sampled every ``1/oversample`` detector
pixel and normalised to sum to ``oversample**2``: photutils' ``ImagePSF``
evaluates it with a bicubic spline so that a star of flux ``F`` has total
``F`` in detector pixels (docs/photometry.md).

photutils 3.0.0 bug (fixed in 3.1): in one process, a grouped fit may reuse a
cached flat model built for an earlier, *different* ``ImagePSF``. Every fit
here clears ``photutils.psf._components._FLAT_MODEL_CACHE`` first, which is
the workaround photutils' maintainers give (docs/photometry.md); it costs a model-class
rebuild per fit (well under a millisecond).
"""

import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ["StarFit", "image_psf", "fit_stars", "detect_stars", "pair_errors"]


@dataclass(frozen=True)
class StarFit:
    """Result of fitting ``n`` stars in one frame.

    Attributes
    ----------
    x, y, flux : ndarray, shape (n,)
        Fitted positions (detector pixels) and total fluxes, in the order of
        the initial guesses.
    flags : ndarray of int, shape (n,)
        photutils' fit flags (0 = clean; see ``PSFPhotometry``). For the
        forward-model fitter: 0 = converged, 1 = not converged.
    x_err, y_err, flux_err : ndarray, shape (n,), or None
        Standard errors from the fit's covariance, where the fitter gives them
        (the weighted forward-model fit); ``None`` otherwise.
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    flags: np.ndarray
    x_err: np.ndarray = None
    y_err: np.ndarray = None
    flux_err: np.ndarray = None


def image_psf(epsf, oversample=4):
    """Wrap an effective PSF as a photutils ``ImagePSF``.

    Parameters
    ----------
    epsf : ndarray, shape (n, n)
        Pixel-integrated PSF sampled every ``1/oversample`` pixel, centred on
        the middle element, summing to ``oversample**2``.
    oversample : int
        Samples per detector pixel along each axis.

    Returns
    -------
    photutils.psf.ImagePSF

    Raises
    ------
    ValueError
        If ``epsf`` is not a finite, odd-sided square array summing to
        ``oversample**2`` within 1e-6 (a PSF normalised to 1 would give fluxes
        ``oversample**2`` times too large).
    """
    from photutils.psf import ImagePSF

    epsf = np.asarray(epsf, dtype=np.float64)
    if epsf.ndim != 2 or epsf.shape[0] != epsf.shape[1] or epsf.shape[0] % 2 == 0:
        raise ValueError(f"effective PSF must be a square array with an odd side, got {epsf.shape}")
    if not np.all(np.isfinite(epsf)):
        raise ValueError("effective PSF has non-finite values")
    total = float(epsf.sum())
    if abs(total - oversample ** 2) > 1e-6 * oversample ** 2:
        raise ValueError(f"effective PSF sums to {total:.6g}, expected oversample**2 = "
                         f"{oversample ** 2} (normalise it for "
                         f"ImagePSF(oversampling={oversample}))")
    return ImagePSF(epsf, oversampling=oversample)


def fit_stars(frame, psf_model, x_init, y_init, flux_init, fit_shape=(9, 9), min_separation=None,
              maxiters=200):
    """Fit stars simultaneously (per group) with photutils ``PSFPhotometry``.

    Parameters
    ----------
    frame : ndarray, shape (ny, nx)
        Measured image (no background: the simulated frames have none).
    psf_model : photutils.psf.ImagePSF
        From :func:`image_psf`.
    x_init, y_init, flux_init : array_like, shape (n,)
        Initial positions and fluxes, one entry per star (the study supplies
        them, so that a fit's error does not depend on a finder's settings).
    fit_shape : tuple of int
        ``(ny, nx)`` box around each star whose pixels enter the fit (odd).
    min_separation : float or None
        Stars closer than this (pixels) are grouped and fitted together
        (``SourceGrouper``); ``None`` (default) fits all the given stars as one
        group, so that even a wide pair's wings (the F405N PSF's horizontal
        diffraction spikes reach 20 px) are modelled rather than left in the
        other star's fit box.
    maxiters : int
        Fitter iterations per group.

    Returns
    -------
    StarFit
        In the order of the initial guesses.
    """
    from astropy.table import QTable
    from photutils.psf import PSFPhotometry, SourceGrouper, _components

    init = QTable({"x_init": np.atleast_1d(np.asarray(x_init, float)),
                   "y_init": np.atleast_1d(np.asarray(y_init, float)),
                   "flux_init": np.atleast_1d(np.asarray(flux_init, float))})
    if min_separation is None:
        init["group_id"] = np.ones(len(init), dtype=int)
        grouper = None
    else:
        grouper = SourceGrouper(min_separation=min_separation)
    phot = PSFPhotometry(psf_model, fit_shape, grouper=grouper, fitter_maxiters=maxiters)
    # photutils 3.0.0 reuses a cached flat model of an earlier ImagePSF in grouped fits
    # (docs/photometry.md): clear it before every fit.
    _components._FLAT_MODEL_CACHE.clear()
    with warnings.catch_warnings():
        # non-convergence is reported in `flags`; the warning would repeat it per frame
        warnings.filterwarnings("ignore", message=".*(converge|flags).*")
        table = phot(np.asarray(frame, dtype=np.float64), init_params=init)
    order = np.argsort(np.asarray(table["id"]))
    return StarFit(x=np.asarray(table["x_fit"], float)[order],
                   y=np.asarray(table["y_fit"], float)[order],
                   flux=np.asarray(table["flux_fit"], float)[order],
                   flags=np.asarray(table["flags"], int)[order])


def detect_stars(frame, fwhm, threshold, *, min_separation, finder="iraf"):
    """Find stars with photutils' ``IRAFStarFinder`` or ``DAOStarFinder``.

    Parameters
    ----------
    frame : ndarray, shape (ny, nx)
    fwhm : float
        Kernel FWHM in pixels (~2.1 for the F405N PSF).
    threshold : float
        Detection threshold in frame units (for noise-free frames, a small
        fraction of the fainter star's peak).
    min_separation : float
        Detections closer than this [px] are merged into the brighter one.
        Required: photutils 3.0's default (``None`` = 2.5 x ``fwhm``, 5.25 px
        for the F405N PSF) merges every pair closer than that whatever the
        image holds, so a detection rate measured at the default measures the
        default, not the blend (the binary study sweeps it).
    finder : {"iraf", "dao"}

    Returns
    -------
    x, y : ndarray
        Centroids of the detections (empty arrays when nothing is found).
    """
    from photutils.detection import DAOStarFinder, IRAFStarFinder

    if min_separation is None or not np.isfinite(min_separation) or min_separation < 0:
        raise ValueError(f"min_separation must be a number >= 0 [px], got {min_separation!r}")
    if finder == "iraf":
        find = IRAFStarFinder(threshold, fwhm, roundness_range=(0.0, 1.0),
                              min_separation=float(min_separation))
    elif finder == "dao":
        find = DAOStarFinder(threshold, fwhm, min_separation=float(min_separation))
    else:
        raise ValueError(f"unknown finder {finder!r}; choose 'iraf' or 'dao'")
    with warnings.catch_warnings():
        # "no sources found" is an answer here (empty arrays), not a warning
        warnings.filterwarnings("ignore", message="No sources were found")
        table = find(np.asarray(frame, dtype=np.float64))
    if table is None:
        return np.empty(0), np.empty(0)
    return np.asarray(table["x_centroid"], float), np.asarray(table["y_centroid"], float)


def pair_errors(fit, x_true, y_true, flux_true):
    """Photometric and astrometric errors of a fitted pair.

    Parameters
    ----------
    fit : StarFit
        Two stars: primary first, secondary second.
    x_true, y_true, flux_true : array_like, shape (2,)
        The truth.

    Returns
    -------
    flux_error_pct : ndarray, shape (2,)
        ``100 (flux_fit - flux_true) / flux_true`` for each star.
    separation_error_mpix : float
        ``1000 (|r2 - r1|_fit - |r2 - r1|_true)`` in millipixels.
    """
    x_true, y_true, flux_true = (np.asarray(a, float) for a in (x_true, y_true, flux_true))
    flux_error = 100.0 * (fit.flux - flux_true) / flux_true
    sep_fit = np.hypot(fit.x[1] - fit.x[0], fit.y[1] - fit.y[0])
    sep_true = np.hypot(x_true[1] - x_true[0], y_true[1] - y_true[0])
    return flux_error, 1000.0 * (sep_fit - sep_true)

"""IPC-aware forward-model PSF fitting: couple the model, not decouple the data.

Signal-dependent IPC makes a blended pair more than the sum of two coupled
PSFs: the detector measures ``couple(S1 + S2)``, not ``couple(S1) + couple(S2)``
(paper section 4). Instead of decoupling the measured frame (which turns its
white read noise into correlated noise, paper section 3.1), this fitter
models what the detector records and compares it with the measured frame as
it is::

    model = couple(f1 P(x - x1, y - y1) + f2 P(x - x2, y - y2) + ...)

where ``P`` is the pixel-integrated optical PSF and ``couple`` is
:func:`ipc_taichi.couple` with the known law, geometry and edge. With
``law=None`` the coupling step is skipped and the fitter is an ordinary
linear-superposition PSF fit; the study uses that to compare plain fitting,
decouple-then-fit and forward fitting with one fitter, one pixel set and one
interpolant.

Continuous positions need ``P`` between the samples of the 4x effective PSF.
We use the bicubic spline of photutils' ``ImagePSF`` (the interpolant
photutils itself fits with), so that forward and photutils fits differ only
in how they treat IPC. The spline passes through the samples: on the
quarter-pixel grid the model equals the pixel-integrated PSF exactly;
between samples its error is that of cubic interpolation of a PSF sampled at
~8 points per FWHM. (A Fourier shift would be exact for a band-limited PSF,
but pixel integration and the finite PSF support make it ring; the spline
keeps the two fitters comparable.)

The model is computed on the bounding box of the fit windows padded by two
pixels (the farthest a :class:`ipc_taichi.Geometry` couples), so every fitted
pixel sees all its coupling neighbours; where the box meets the frame border
the frame's ``edge`` rule applies, as it did for the data.
"""

import numpy as np

from .photometry import StarFit, image_psf

__all__ = ["SceneModel", "fit_stars_forward"]

# farthest coupling offset a Geometry supports (second neighbours), in pixels
_COUPLING_REACH = 2


class SceneModel:
    """Model image of a few stars, optionally coupled by IPC.

    Parameters
    ----------
    epsf : ndarray
        Pixel-integrated PSF sampled every ``1/oversample`` pixel, summing to
        ``oversample**2`` (as for :func:`analysis.photometry.image_psf`).
    box : tuple of slice
        ``(rows, cols)`` of the frame on which the model is computed.
    law, geometry, edge
        The IPC model (see :func:`ipc_taichi.couple`); ``law=None`` means no
        coupling.
    oversample : int
    """

    def __init__(self, epsf, box, law="donlon2018", geometry=None, edge="zero", oversample=4):
        self.psf = image_psf(epsf, oversample)
        self.box = box
        self.law, self.geometry, self.edge = law, geometry, edge
        rows, cols = box
        self.yy, self.xx = np.mgrid[rows, cols].astype(np.float64)

    def __call__(self, params):
        """Model over ``box`` for ``params = [x1, y1, f1, x2, y2, f2, ...]``."""
        signal = np.zeros(self.xx.shape)
        for x, y, flux in np.reshape(params, (-1, 3)):
            signal += self.psf.evaluate(self.xx, self.yy, flux, x, y)
        if self.law is None:
            return signal
        import ipc_taichi

        return ipc_taichi.couple(signal, law=self.law, geometry=self.geometry, edge=self.edge)


def _fit_window(shape, x_init, y_init, fit_shape):
    """Union of the ``fit_shape`` boxes around the initial positions (as photutils)."""
    window = np.zeros(shape, dtype=bool)
    hy, hx = fit_shape[0] // 2, fit_shape[1] // 2
    for x, y in zip(x_init, y_init):
        cx, cy = int(np.floor(x + 0.5)), int(np.floor(y + 0.5))
        window[max(cy - hy, 0):cy + hy + 1, max(cx - hx, 0):cx + hx + 1] = True
    if not window.any():
        raise ValueError("no initial position lies inside the frame")
    return window


def fit_stars_forward(frame, epsf, x_init, y_init, flux_init, law="donlon2018", geometry=None,
                      edge="zero", fit_shape=(9, 9), oversample=4, xtol=1e-10, max_nfev=400):
    """Fit stars by least squares against a (coupled) model of the frame.

    Parameters
    ----------
    frame : ndarray, shape (ny, nx)
        The measured frame, as recorded (coupled) when ``law`` is given.
    epsf : ndarray
        Effective PSF of the *signal*: pixel-integrated optical PSF, 4x
        sampled, summing to ``oversample**2``.
    x_init, y_init, flux_init : array_like, shape (n,)
        Initial guesses, one per star.
    law, geometry, edge
        IPC model applied to the model image (:func:`ipc_taichi.couple`);
        ``law=None`` fits without coupling (a plain PSF fit).
    fit_shape : tuple of int
        Box around each initial position whose pixels enter the fit; the
        fitted pixels are the union of the boxes (unweighted least squares,
        as photutils without ``error``).
    oversample : int
    xtol : float
        Passed to :func:`scipy.optimize.least_squares` (also ``ftol``).
    max_nfev : int
        Evaluation budget of the least-squares solver.

    Returns
    -------
    StarFit
        ``flags`` is 0 when the solver converged, 1 otherwise.
    """
    from scipy.optimize import least_squares

    frame = np.asarray(frame, dtype=np.float64)
    x_init, y_init, flux_init = (np.atleast_1d(np.asarray(a, float)) for a in (x_init, y_init, flux_init))
    window = _fit_window(frame.shape, x_init, y_init, fit_shape)
    rows, cols = np.nonzero(window)
    box = (slice(max(rows.min() - _COUPLING_REACH, 0), rows.max() + _COUPLING_REACH + 1),
           slice(max(cols.min() - _COUPLING_REACH, 0), cols.max() + _COUPLING_REACH + 1))
    model = SceneModel(epsf, box, law=law, geometry=geometry, edge=edge, oversample=oversample)
    inside = window[box]
    data = frame[box][inside]

    def residual(params):
        return model(params)[inside] - data

    start = np.column_stack([x_init, y_init, flux_init]).ravel()
    # positions move by ~0.1 px, fluxes by their own size: scale steps accordingly
    scale = np.column_stack([np.full_like(x_init, 0.1), np.full_like(y_init, 0.1),
                             np.maximum(np.abs(flux_init), 1.0)]).ravel()
    result = least_squares(residual, start, x_scale=scale, xtol=xtol, ftol=xtol, gtol=xtol,
                           max_nfev=max_nfev, method="trf")
    params = result.x.reshape(-1, 3)
    flags = np.full(len(x_init), 0 if result.status > 0 else 1, dtype=int)
    return StarFit(x=params[:, 0].copy(), y=params[:, 1].copy(), flux=params[:, 2].copy(), flags=flags)

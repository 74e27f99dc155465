"""Optical PSFs and the effective (detector + IPC) PSF at quarter-pixel offsets.

Public functions (signatures as implemented)::

    optical_psf(source="jwst_f405n", oversample=4) -> ndarray
    point_source_image(psf, x, y, shape, flux=1.0, oversample=4, sampling="integrated") -> ndarray
    effective_psf(psf, flux, stage="coupled", law="donlon2018", oversample=4, size=None,
                  sampling="integrated", geometry=None, edge="zero", max_iter=20, tol=1e-5)
                  -> ndarray
    continuous_psf(epsf, oversample=4) -> scipy.interpolate.RectBivariateSpline
    jwst_f405n_psf(oversample=4, fov_pixels=40, wavelength=4.05e-6) -> (ndarray, float)
    airy_psf(oversample=4, fov_pixels=40, wavelength=4.05e-6, diameter=6.5) -> ndarray

Conventions
-----------
*Optical PSF* arrays (what :func:`optical_psf` returns and the other
functions take) are sampled every ``1/oversample`` detector pixel, have an odd
side, the source sits exactly on the middle element, and they sum to 1. Each
element is the optical intensity at that point times the area of one
sub-sample (``1/oversample**2`` pixel), so a ``oversample x oversample`` group
of elements holds about one detector pixel's flux.

*Detector images* are ``image[y, x]`` with integer coordinates at pixel
centres (as everywhere in ipc_taichi). A point source at ``(x, y)`` must sit
on the ``1/oversample`` grid, which is what lets a detector image be read off
the optical PSF without interpolation.

*Pixel sampling.* The samples of an optical PSF are read as point values of
the intensity (what poppy's MFT computes). ``sampling="integrated"``
(default) integrates the PSF over each detector pixel (a square of side 1
pixel, uniform response) with Simpson's rule on the ``1/oversample`` grid
(even ``oversample``: the pixel edges fall on samples; error O(h^4), about
1e-4 of the peak for the JWST-like PSF, where the trapezoid rule would be
1 % off). An odd ``oversample`` uses the midpoint rule (pixel edges fall
half-way between samples). The integrated values at each of the
``oversample**2`` sub-pixel phases are then rescaled (by less than 1e-4 for
the PSFs here) so that the total of an image is exactly ``flux`` times the
part of the PSF inside the frame, wherever the source sits.
``sampling="point"`` is the paper's model (its Eqs. 9-10): the optical PSF
multiplied by a Dirac comb at the pixel pitch, i.e. each detector pixel holds
``oversample**2`` times the optical sample at its centre; no pixel
integration. Its totals are ``flux`` only to the accuracy of a Riemann sum.

*Effective PSF* (:func:`effective_psf`): the ``oversample``-times sampled
PSF built from ``oversample**2`` detector images of the source at offsets
``(a/oversample, b/oversample)``, each taken through IPC at detector-pixel
scale and interleaved; element ``[o*i - a, o*j - b]`` (``o = oversample``) is
pixel ``(i, j)`` of the image whose source is offset by ``(a/o, b/o)``. It is
normalised to sum ``oversample**2``, the convention of photutils
``ImagePSF(oversampling=oversample)``, so it is a unit-flux PSF model.
"""

import functools
import math
import os

import numpy as np
from scipy import ndimage

__all__ = [
    "optical_psf",
    "jwst_f405n_psf",
    "airy_psf",
    "read_psf_file",
    "point_source_image",
    "effective_psf",
    "continuous_psf",
    "PIXEL_SCALE",
    "WAVELENGTH",
    "STAGES",
]

PIXEL_SCALE = 0.063
"""NIRCam long-wavelength detector pixel scale [arcsec/pixel] (docs/analysis.md). The
paper's FWHM table implies 0.065"/px (its arcsec column over its pixel column); pass
``pixel_scale=0.065`` to :func:`jwst_f405n_psf` for that."""

WAVELENGTH = 4.05e-6
"""F405N central wavelength [m]; the PSF is computed monochromatic at this wavelength."""

JWST_DIAMETER = 6.5
"""Nominal JWST primary diameter [m]: the ``D`` of the Airy disk of ``source="airy"``."""

STAGES = ("truth", "coupled", "decoupled")


def _check_oversample(oversample):
    o = int(oversample)
    if o != oversample or o < 1:
        raise ValueError(f"oversample must be a positive integer, got {oversample!r}")
    return o


@functools.lru_cache(maxsize=8)
def _jwst_cached(oversample, fov_pixels, wavelength, pixel_scale=PIXEL_SCALE):
    import astropy.units as u
    import poppy

    # a JWST-like pupil (docs/analysis.md): 18 hexagonal segments in 2 rings, no
    # central segment, 7 mm gaps, a 0.74 m secondary on three 0.1 m struts.
    segments = poppy.MultiHexagonAperture(rings=2, flattoflat=1.32 * u.m, gap=0.007 * u.m,
                                          center=False)
    secondary = poppy.SecondaryObscuration(secondary_radius=0.37 * u.m, n_supports=3,
                                           support_width=0.1 * u.m)
    pupil = poppy.CompoundAnalyticOptic([segments, secondary], mergemode="and",
                                        name="JWST-like pupil")
    osys = poppy.OpticalSystem(npix=1024, oversample=2)
    osys.add_pupil(pupil)
    # An odd number of samples at pixelscale/oversample puts the optical axis on
    # the middle sample (poppy's MFT centres odd arrays on a sample).
    osys.add_detector(pixelscale=pixel_scale / oversample,
                      fov_pixels=oversample * fov_pixels + 1, oversample=1)
    data = np.asarray(osys.calc_psf(wavelength)[0].data, dtype=np.float64)
    enclosed = float(data.sum())  # poppy normalises the entrance pupil to 1
    data = data / enclosed
    data.setflags(write=False)
    return data, enclosed


def jwst_f405n_psf(oversample=4, fov_pixels=40, wavelength=WAVELENGTH, pixel_scale=PIXEL_SCALE):
    """A JWST-like NIRCam F405N optical PSF computed offline with poppy.

    Parameters
    ----------
    oversample : int
        Samples per detector pixel (4 as in the paper's WebbPSF file).
    fov_pixels : int
        Field of view in detector pixels; the array side is
        ``oversample * fov_pixels + 1``.
    wavelength : float
        Monochromatic wavelength [m] (F405N is 1 % wide).
    pixel_scale : float
        Detector pixel scale [arcsec/pixel].

    Returns
    -------
    psf : ndarray
        Normalised to sum 1 inside the field of view.
    enclosed : float
        The fraction of the total light poppy puts inside that field (about
        0.94 for 40 pixels: the rest is in the far wings and spikes).
    """
    o = _check_oversample(oversample)
    data, enclosed = _jwst_cached(o, int(fov_pixels), float(wavelength), float(pixel_scale))
    return data.copy(), enclosed


def airy_psf(oversample=4, fov_pixels=40, wavelength=WAVELENGTH, diameter=JWST_DIAMETER):
    """An Airy disk ``(2 J1(v)/v)^2``, ``v = pi D theta / lambda``, point-sampled.

    Same sampling, field and ``lambda/D`` as the default JWST-like PSF (``D``
    the nominal 6.5 m), normalised to sum 1. Its FWHM is
    ``1.02899 lambda/D`` (= 2.102 pixels at 4.05 um, 0.063"/px).
    """
    from scipy.special import j1

    o = _check_oversample(oversample)
    side = o * int(fov_pixels) + 1
    c = side // 2
    yy, xx = np.mgrid[:side, :side]
    theta = np.hypot(yy - c, xx - c) / o * PIXEL_SCALE * math.pi / (180 * 3600)  # [rad]
    v = math.pi * diameter * theta / wavelength
    with np.errstate(invalid="ignore", divide="ignore"):
        psf = np.where(v > 0, (2 * j1(v) / np.where(v > 0, v, 1)) ** 2, 1.0)
    return psf / psf.sum()


def read_psf_file(path, oversample=4, hdu=None):
    """Read an oversampled optical PSF from FITS (e.g. a WebbPSF/stpsf product).

    The HDU is ``hdu``, else the one named ``OVERSAMP`` (WebbPSF's oversampled
    extension), else the first image HDU. Its detector sampling must equal
    ``oversample``: the ``DET_SAMP`` keyword when present (poppy and WebbPSF
    write the detector oversampling there), else ``OVERSAMP`` (which poppy
    uses for the oversampling of its Fourier transforms, not of the pixels). An
    even-sided array (WebbPSF and poppy centre those between the four middle
    samples) is shifted by half a sample with a cubic spline and padded to an odd
    side so the source falls on the middle element. The result is renormalised
    to sum 1.
    """
    from astropy.io import fits

    from ipc_taichi.fitsio import read_image

    o = _check_oversample(oversample)
    if hdu is None and os.path.exists(path):
        try:
            with fits.open(path) as hdul:
                if "OVERSAMP" in hdul:
                    hdu = "OVERSAMP"
        except Exception:
            pass  # read_image reports unreadable files in one line
    data, header, label = read_image(path, hdu)
    if data.ndim != 2:
        raise ValueError(f"{label}: a PSF must be a 2-D image, got shape {data.shape}")
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{label}: PSF holds {np.sum(~np.isfinite(data))} non-finite values")
    key = "DET_SAMP" if "DET_SAMP" in header else "OVERSAMP" if "OVERSAMP" in header else None
    if key is not None and int(header[key]) != o:
        raise ValueError(f"{label}: PSF samples each detector pixel {header[key]}x ({key}) but "
                         f"oversample={o} was asked; pass oversample={int(header[key])}")
    if data.sum() <= 0:
        raise ValueError(f"{label}: PSF has no positive flux (sum {data.sum():.3g})")
    for axis in (0, 1):
        if data.shape[axis] % 2 == 0:
            shift = [0.0, 0.0]
            shift[axis] = 0.5
            data = np.pad(data, [(0, 1) if k == axis else (0, 0) for k in (0, 1)])
            data = ndimage.shift(data, shift, order=3, mode="constant")
    return data / data.sum()


def optical_psf(source="jwst_f405n", oversample=4):
    """The diffraction PSF of the simulation, pluggable.

    Parameters
    ----------
    source : str
        ``"jwst_f405n"`` (default; :func:`jwst_f405n_psf`, computed offline
        with poppy in about a second and cached in the process), ``"airy"``
        (:func:`airy_psf`) or the path of an oversampled PSF FITS file
        (:func:`read_psf_file`).
    oversample : int
        Samples per detector pixel.

    Returns
    -------
    psf : ndarray, float64
        Odd side, source on the middle element, sum 1 (module docstring).
    """
    o = _check_oversample(oversample)
    if not isinstance(source, (str, os.PathLike)):
        raise ValueError(f"PSF source must be 'jwst_f405n', 'airy' or a FITS path, got {source!r}")
    key = str(source).strip().lower()
    if key == "jwst_f405n":
        return jwst_f405n_psf(o)[0]
    if key == "airy":
        return airy_psf(o)
    if not os.path.exists(str(source)):
        raise ValueError(f"PSF source {str(source)!r}: not 'jwst_f405n' or 'airy' and no such file")
    return read_psf_file(str(source), o)


def _check_psf(psf):
    psf = np.asarray(psf, dtype=np.float64)
    if psf.ndim != 2 or psf.shape[0] % 2 == 0 or psf.shape[1] % 2 == 0:
        raise ValueError(f"PSF must be a 2-D array with odd sides (source on the middle "
                         f"element), got shape {psf.shape}")
    if not np.all(np.isfinite(psf)):
        raise ValueError("PSF holds non-finite values")
    return psf


def _pixel_weights(o):
    """Quadrature weights of one detector pixel on the 1/o grid, in units of a
    sample (they sum to o): Simpson's rule for even o, midpoint rule for odd o."""
    if o % 2:
        return np.ones(o)
    w = np.tile([2.0, 4.0], o // 2 + 1)[: o + 1]  # 1, 4, 2, 4, ..., 4, 1
    w[0] = w[-1] = 1.0
    return w / 3.0


def _pixel_integrated(psf, o):
    """The PSF integrated over a detector pixel centred on each sample (padded
    by half a pixel), each sub-pixel phase rescaled to hold the PSF's total."""
    w = _pixel_weights(o)
    h = len(w) // 2
    table = np.pad(psf, h)
    for axis in (0, 1):
        table = ndimage.correlate1d(table, w, axis=axis, mode="constant")
    cy, cx = table.shape[0] // 2, table.shape[1] // 2
    total = psf.sum()
    for a in range(o):
        for b in range(o):
            phase = table[(cy + a) % o::o, (cx + b) % o::o]
            s = phase.sum()
            if s != 0:
                phase *= total / s
    return table


def _grid_index(coord, o, name):
    k = coord * o
    r = round(k)
    if abs(k - r) > 1e-9 * max(1.0, abs(k)):
        raise ValueError(f"{name}={coord!r} is not on the 1/{o} pixel grid of the PSF")
    return int(r)


def point_source_image(psf, x, y, shape, flux=1.0, oversample=4, sampling="integrated"):
    """Detector image of one point source.

    Parameters
    ----------
    psf : ndarray
        Optical PSF (odd sides, centred, see module docstring).
    x, y : float
        Source position in detector pixels (pixel centres at integers); must
        be multiples of ``1/oversample``.
    shape : (ny, nx)
        Frame shape.
    flux : float
        Total counts of the source.
    oversample : int
        Sampling of ``psf``.
    sampling : {"integrated", "point"}
        Pixel-integrated (default) or the paper's comb (module docstring).

    Returns
    -------
    image : ndarray, shape ``shape``
        With ``sampling="integrated"`` its total is ``flux`` times the part of
        the PSF that falls inside the frame. Sum several for a scene.
    """
    o = _check_oversample(oversample)
    psf = _check_psf(psf)
    if sampling == "integrated":
        table = _pixel_integrated(psf, o)
    elif sampling == "point":
        table = psf * (o * o)
    else:
        raise ValueError(f"sampling must be 'integrated' or 'point', got {sampling!r}")
    ny, nx = (int(v) for v in shape)
    ky0 = _grid_index(y, o, "y")
    kx0 = _grid_index(x, o, "x")
    cy, cx = table.shape[0] // 2, table.shape[1] // 2
    ky = cy + o * np.arange(ny) - ky0
    kx = cx + o * np.arange(nx) - kx0
    vy = (ky >= 0) & (ky < table.shape[0])
    vx = (kx >= 0) & (kx < table.shape[1])
    image = np.zeros((ny, nx))
    image[np.ix_(vy, vx)] = float(flux) * table[np.ix_(ky[vy], kx[vx])]
    return image


def effective_psf(psf, flux, stage="coupled", law="donlon2018", oversample=4, size=None,
                  sampling="integrated", geometry=None, edge="zero", max_iter=20, tol=1e-5):
    """The ``oversample``-times sampled effective PSF of a source of ``flux`` counts.

    The paper's section 3.3 construction: the source is placed at each of the
    ``oversample**2`` sub-pixel offsets, imaged (:func:`point_source_image`),
    taken through IPC at detector-pixel scale at its real signal level, and
    the detector images are interleaved (module docstring).

    Parameters
    ----------
    psf : ndarray
        Optical PSF (odd sides, centred, sum 1).
    flux : float
        Source counts: sets the signal levels that the law sees.
    stage : {"truth", "coupled", "decoupled"}
        No IPC; :func:`ipc_taichi.couple`; couple then :func:`ipc_taichi.decouple`.
    law, geometry, edge :
        The IPC model (as for :func:`ipc_taichi.couple`); ``law`` may be
        ``"constant:0.08"`` for a static kernel.
    oversample : int
        Sampling of ``psf`` and of the result.
    size : int, optional
        Odd side of the detector frame (default: the PSF's footprint plus one
        pixel each side). The result has side ``oversample * (size - 1) + 1``.
    sampling : {"integrated", "point"}
        See :func:`point_source_image`.
    max_iter, tol :
        Stopping rule of the decoupler (``stage="decoupled"``).

    Returns
    -------
    epsf : ndarray
        Sums to ``oversample**2``; the source is on the middle element.
    """
    import ipc_taichi

    o = _check_oversample(oversample)
    psf = _check_psf(psf)
    if stage not in STAGES:
        raise ValueError(f"stage must be one of {', '.join(STAGES)}, got {stage!r}")
    if not (np.isfinite(flux) and flux > 0):
        raise ValueError(f"flux must be finite and > 0, got {flux!r}")
    if size is None:
        size = (max(psf.shape) - 1) // o + 3
        size += 1 - size % 2
    size = int(size)
    if size < 3 or size % 2 == 0:
        raise ValueError(f"size must be an odd number >= 3, got {size}")
    centre = size // 2
    frames = np.empty((o * o, size, size))
    for a in range(o):
        for b in range(o):
            frames[a * o + b] = point_source_image(psf, centre + b / o, centre + a / o,
                                                   (size, size), flux, o, sampling)
    if stage != "truth":
        frames = ipc_taichi.couple(frames, law=law, geometry=geometry, edge=edge)
    if stage == "decoupled":
        frames = ipc_taichi.decouple(frames, law=law, geometry=geometry, edge=edge,
                                     max_iter=max_iter, tol=tol)
    side = o * (size - 1) + 1
    epsf = np.zeros((side, side))
    index = o * np.arange(size)
    for a in range(o):
        rows = index - a
        vr = rows >= 0
        for b in range(o):
            cols = index - b
            vc = cols >= 0
            epsf[np.ix_(rows[vr], cols[vc])] = frames[a * o + b][np.ix_(vr, vc)]
    return epsf * (o * o / epsf.sum())


def continuous_psf(epsf, oversample=4):
    """Bicubic interpolating spline of a sampled PSF (the paper's 3-D surface).

    Returns a :class:`scipy.interpolate.RectBivariateSpline` ``f(y, x)`` with
    ``x, y`` in detector pixels from the source (the middle element at 0, 0).
    """
    from scipy.interpolate import RectBivariateSpline

    o = _check_oversample(oversample)
    epsf = _check_psf(epsf)
    y = (np.arange(epsf.shape[0]) - epsf.shape[0] // 2) / o
    x = (np.arange(epsf.shape[1]) - epsf.shape[1] // 2) / o
    return RectBivariateSpline(y, x, epsf, kx=3, ky=3, s=0)

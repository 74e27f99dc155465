"""The paper's image simulation (its section 3.1 flow chart), seeded.

::

    sources + background      -> flux map (optical PSF, detector pixels)
    flux map + dark signal    -> simulated scene (mean counts per pixel)
    Poisson(scene)            -> signal (collected charge)
    signal + read noise       -> truth image
    couple(signal) + read noise (the same instance) -> coupled image
    decouple(coupled)         -> decoupled image

The Poisson draw, the coupling and the read noise are the project's shared
detector chain (:func:`ipc_taichi.detector.expose`): one seeded generator draws
the Poisson variates first and the read noise next.

The same read-noise instance is added to the truth and to the coupled frame,
as the paper's text prescribes ("This distribution is added to the original
scene image and the coupled copy"): ``coupled - truth`` is then IPC alone,
and ``decoupled - truth`` shows how decoupling spreads the read noise.

Units: counts are electrons (gain 1) and the coupling law sees them directly;
the paper calls them "values".

Photometric zero point (F405N)
------------------------------
:data:`ZERO_POINT` is the magnitude of a source giving 1 count/s in F405N.
We found no authoritative F405N count-rate zero point that we could cite from
here (the JWST documentation tabulates zero points in MJy/sr, not counts),
so it is *derived from the paper itself*: "the bright point source [...]
would nearly saturate the central pixel at a 10 ks exposure time. This
corresponds to a source of magnitude ~21.4." We take "nearly saturate" to mean
60000 counts in the central pixel (the top of the paper's own 0..60000 test
range) for the source centred on a pixel of the pixel-integrated JWST-like
F405N PSF of :mod:`analysis.psf`, whose central pixel holds a fraction
``f = 0.14517`` of the source's light (inside a 40-pixel field). Then

    flux(21.4 mag, 10 ks) = 60000 / f = 4.133e5 counts = 41.33 counts/s
    ZERO_POINT = 21.4 + 2.5 log10(41.33) = 25.44

With it, the mid (23.1) and dim (25.3) sources give 8.63e4 and 1.14e4 counts
in 10 ks (central pixels 12530 and 1650 counts). The value is a consistency
choice, not a calibration: a real F405N zero point would shift all three
fluxes together.
"""

from dataclasses import dataclass, field

import numpy as np

from .psf import optical_psf, point_source_image

__all__ = [
    "ZERO_POINT",
    "EXPOSURE_TIME",
    "SATURATION",
    "MAGNITUDES",
    "flux_from_mag",
    "mag_from_flux",
    "Source",
    "SimulatedImages",
    "simulate",
]

ZERO_POINT = 25.44
"""F405N magnitude of a source giving 1 count/s (derived above; not a calibration)."""

EXPOSURE_TIME = 1.0e4
"""The paper's exposure time [s]."""

SATURATION = 60000.0
"""Central-pixel counts of the 'bright' source that define :data:`ZERO_POINT`."""

MAGNITUDES = {"bright": 21.4, "mid": 23.1, "dim": 25.3}
"""The paper's three point-source brightnesses (section 3.3) [mag]."""


def flux_from_mag(mag, exptime=EXPOSURE_TIME, zero_point=ZERO_POINT):
    """Counts collected from a source of magnitude ``mag`` in ``exptime`` seconds."""
    return np.asarray(exptime, float) * 10.0 ** (0.4 * (zero_point - np.asarray(mag, float)))


def mag_from_flux(flux, exptime=EXPOSURE_TIME, zero_point=ZERO_POINT):
    """Inverse of :func:`flux_from_mag`."""
    return zero_point - 2.5 * np.log10(np.asarray(flux, float) / exptime)


@dataclass(frozen=True)
class Source:
    """A point source at detector position ``(x, y)`` (on the 1/oversample grid)."""

    x: float
    y: float
    mag: float


@dataclass
class SimulatedImages:
    """What :func:`simulate` returns (all ``image[y, x]``, counts).

    Attributes
    ----------
    flux_map : ndarray
        Sources through the optical PSF plus sky background (expected counts).
    scene : ndarray
        ``flux_map`` plus dark signal: the mean of the Poisson draw.
    signal : ndarray
        The Poisson draw (or ``scene`` when ``poisson=False``).
    read_noise : ndarray
        The read-noise instance added to both truth and coupled.
    truth, coupled, decoupled : ndarray
        The paper's three images.
    fluxes : ndarray
        Counts of each source.
    info : dict
        Parameters and the decoupler's iteration count.
    """

    flux_map: np.ndarray
    scene: np.ndarray
    signal: np.ndarray
    read_noise: np.ndarray
    truth: np.ndarray
    coupled: np.ndarray
    decoupled: np.ndarray
    fluxes: np.ndarray
    info: dict = field(default_factory=dict)


def simulate(sources, shape, exptime=EXPOSURE_TIME, psf="jwst_f405n", background=0.05, dark=0.03,
             read_noise=10.0, poisson=True, law="donlon2018", geometry=None, edge="zero",
             seed=0, oversample=4, sampling="integrated", zero_point=ZERO_POINT,
             max_iter=20, tol=1e-5):
    """Simulate truth, coupled and decoupled images of point sources (flow chart).

    Parameters
    ----------
    sources : iterable of Source or (x, y, mag)
        Positions in detector pixels (multiples of ``1/oversample``) and magnitudes.
    shape : (ny, nx)
    exptime : float
        Exposure time [s].
    psf : str or ndarray
        An optical PSF array, or a source for :func:`analysis.psf.optical_psf`
        (``"jwst_f405n"``, ``"airy"`` or a FITS path).
    background, dark : float
        Sky background and dark current [counts/s/pixel]. Defaults are
        illustrative NIRCam-like levels (a narrow 4 um filter sees little sky).
    read_noise : float
        RMS of the Gaussian read noise [counts].
    poisson : bool
        Draw shot noise (``False``: the mean scene, as for the paper's PSFs).
    law, geometry, edge :
        The IPC model, for both :func:`ipc_taichi.couple` and :func:`ipc_taichi.decouple`.
    seed : int
        Seeds the one generator used for Poisson and read noise.
    oversample, sampling :
        See :func:`analysis.psf.point_source_image`.
    zero_point : float
        Magnitude giving 1 count/s.
    max_iter, tol :
        The decoupler's stopping rule.

    Returns
    -------
    SimulatedImages
    """
    import ipc_taichi
    from ipc_taichi.detector import expose
    from ipc_taichi.model import CouplingModel

    if isinstance(psf, str):
        psf = optical_psf(psf, oversample)
    shape = tuple(int(v) for v in shape)
    sources = [s if isinstance(s, Source) else Source(*s) for s in sources]
    fluxes = np.array([float(flux_from_mag(s.mag, exptime, zero_point)) for s in sources])
    for name, value in (("exptime", exptime), ("background", background), ("dark", dark),
                        ("read_noise", read_noise)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    model = CouplingModel.resolve(law, geometry, edge)
    flux_map = np.full(shape, background * exptime)
    for s, f in zip(sources, fluxes):
        flux_map += point_source_image(psf, s.x, s.y, shape, f, oversample, sampling)
    scene = flux_map + dark * exptime
    # the shared detector chain: Poisson draw, then read noise, from one generator
    exposure = expose(scene, model, read_noise, np.random.default_rng(seed), shot_noise=poisson)
    signal, noise = exposure.signal, exposure.noise
    truth = signal + noise
    coupled = exposure.measured
    decoupled, dinfo = ipc_taichi.decouple(coupled, model=model, max_iter=max_iter, tol=tol,
                                           full_output=True)
    info = dict(exptime=exptime, background=background, dark=dark, read_noise=read_noise,
                poisson=poisson, law=dinfo.law, edge=edge, seed=seed, zero_point=zero_point,
                sampling=sampling, iterations=dinfo.iterations, converged=dinfo.converged)
    return SimulatedImages(flux_map, scene, signal, noise, truth, coupled, decoupled, fluxes, info)

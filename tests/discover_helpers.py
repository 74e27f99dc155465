"""Helpers shared by the discover tests (``tests/test_discover_*.py``).

Lab files from the independent generator (``tests/independent/peerlab.py``)
are made once per session and shared: a file with a sub-pixel SCENE is
written together with its pixel-total twin (the same MEASURED frames, SCENE
summed over each pixel by the generator itself), so the blind tests of the
two samplings pay for GalSim's photon shooting once.
"""

import functools

import numpy as np
from astropy.io import fits

from ipc_taichi.discover import discover
from tests.independent import peerlab

# GalSim's SiliconSensor recomputes the pixel boundaries every ``nrecalc``
# photons: at 100000 a hot pixel of up to 60 ke- (drawn alone) never sees its
# own charge, an isolated pixel without brighter-fatter; at 10000 a 50 ke-
# spot loses 2.1 % of its charge (2.6 % with every photon), as a real sensor does
SILICON_BF = {"strength": 1.0, "diffusion_factor": 0.0, "nrecalc": 10000}
# GalSim's silicon diffusion alone (no brighter-fatter)
DIFFUSION = {"strength": 1e-6, "diffusion_factor": 0.5, "nrecalc": 10 ** 9}

_PEER_FILES = {}  # (generator arguments but OVERSAMP) -> {OVERSAMP: path}


def peer_file(tmp_path_factory, oversample=1, **hidden):
    """A lab file of the independent generator (``peerlab.make_file(**hidden)``)
    with SCENE at ``oversample``; made once per session. Asked first with
    ``oversample > 1``, its pixel-total twin is written at the same time."""
    key = tuple(sorted((k, repr(v)) for k, v in hidden.items()))
    made = _PEER_FILES.setdefault(key, {})
    if oversample not in made:
        folder = tmp_path_factory.mktemp("peer")
        made[oversample] = str(folder / f"peer{oversample}.fits")
        totals = None
        if oversample > 1 and 1 not in made:
            totals = made[1] = str(folder / "peer1.fits")
        peerlab.make_file(made[oversample], oversample=oversample, totals_path=totals, **hidden)
    return made[oversample]


def peer_report(tmp_path_factory, **hidden):
    """:func:`discover`'s report on :func:`peer_file`'s file."""
    return discover(peer_file(tmp_path_factory, **hidden)).report


def final(report, effect):
    """The final model's ``(parameters, uncertainties)`` of ``effect``."""
    model = report["final_model"]
    return model["effects"][effect], model["uncertainties"][effect]


def assert_complete(report, min_fraction=0.25):
    """The verdict is complete, nothing is unexplained, the final gap lies
    within 3 floor scatters of the floor, and every step removed at least
    ``min_fraction`` of the excess it faced."""
    floor, sigma = report["gap_floor"], report["gap_floor_sigma"]
    assert report["complete"] is True and report["unexplained"] == [], report["unexplained"]
    assert abs(report["final_gap"] - floor) <= 3 * sigma
    for step in report["steps"]:
        assert step["explained_fraction"] >= min_fraction


def assert_not_below_floor(report):
    """No variance effect inflated the model: the final gap is not more than 3
    floor scatters below the floor."""
    assert report["final_gap"] >= report["gap_floor"] - 3 * report["gap_floor_sigma"]


def write_hdus(path, hdus, **header):
    """A FITS file written HDU by HDU (bypassing ``write_lab``'s checks):
    ``hdus`` is ``[(EXTNAME, EXTVER, data), ...]``, each optionally with a
    fourth item, ``{keyword: value}`` for its header; ``header`` the PRIMARY
    keywords."""
    out = [fits.PrimaryHDU()]
    for key, value in header.items():
        out[0].header[key] = value
    for name, ver, data, *keywords in hdus:
        h = fits.ImageHDU(data, name=name)
        h.header["EXTVER"] = ver
        for key, value in (keywords[0] if keywords else {}).items():
            h.header[key] = value
        out.append(h)
    fits.HDUList(out).writeto(path)
    return str(path)


@functools.cache
def _sensor_sigma(silicon_items):
    import galsim
    from scipy.optimize import minimize_scalar
    from scipy.special import ndtr

    n, c = 15, 7
    sensor = galsim.SiliconSensor(rng=galsim.BaseDeviate(3), **dict(silicon_items))
    img = galsim.ImageD(n, n, xmin=0, ymin=0, scale=1.0)
    total = np.zeros((n, n))
    for k in range(8):
        img.setZero()
        galsim.DeltaFunction(flux=250000).drawImage(
            img, center=galsim.PositionD(c, c), method="phot", sensor=sensor,
            poisson_flux=False, rng=galsim.BaseDeviate(11 + k))
        total += img.array
    share = total / total.sum()
    k = np.arange(n) - c

    def cost(s):
        w = ndtr((k + 0.5) / s) - ndtr((k - 0.5) / s)
        return float(np.sum((np.outer(w, w) - share) ** 2))

    return minimize_scalar(cost, bounds=(0.01, 1.0), method="bounded").x


def sensor_sigma(silicon):
    """The truth: the RMS of GalSim's silicon diffusion, from photons shot at
    a pixel centre (a point source) and the pixel-integrated Gaussian;
    computed once per session."""
    return _sensor_sigma(tuple(sorted(silicon.items())))

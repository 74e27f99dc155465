"""How long ``calibrate`` takes on a full-frame ramp (a benchmark row, not a test)."""

import os
import tempfile
import time

import numpy as np

from ..coupling import couple

__all__ = ["measure_calibrate"]


def _ramp(size, groups, seed=0, n_hot=4000, read_noise=12.0, alpha=0.006):
    """A dark ramp [e-]: hot pixels coupled by a constant nearest-neighbour kernel."""
    rng = np.random.default_rng(seed)
    rate = np.full((size, size), 0.5)
    y = rng.integers(8, size - 8, n_hot)
    x = rng.integers(8, size - 8, n_hot)
    rate[y, x] = np.exp(rng.uniform(np.log(2000.0), np.log(60000.0), n_hot)) / groups
    ramp = np.empty((1, groups, size, size), np.float32)
    charge = np.zeros((size, size))
    for g in range(groups):
        charge += rng.poisson(rate)
        ramp[0, g] = couple(charge, law=alpha) + rng.normal(0.0, read_noise, charge.shape)
    return ramp


def measure_calibrate(size=2048, groups=10):
    """Wall time of :func:`ipc_taichi.calibrate.calibrate` on a ``size`` x
    ``size`` x ``groups`` dark ramp in electrons (FITS read, hot-pixel search,
    group-by-group measurement, law fit, model written).

    Returns
    -------
    dict
        ``size``, ``groups``, ``seconds`` (calibrate only), ``hot_pixels_found``,
        ``alpha_x`` (the measured law at 10 ke-, 0.006 made the ramp).
    """
    from astropy.io import fits

    from .workflow import calibrate

    ramp = _ramp(int(size), int(groups))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "dark.fits")
        hdu = fits.ImageHDU(ramp, name="SCI")
        hdu.header["BUNIT"] = "electron"
        fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(path)
        del ramp, hdu
        start = time.perf_counter()
        result = calibrate([path], output=os.path.join(tmp, "model.json"))
        seconds = time.perf_counter() - start
    model = result["model"]
    return {"size": int(size), "groups": int(groups), "seconds": seconds,
            "hot_pixels_found": int(result["report"]["hot_pixels"]["found"]),
            "alpha_x": float(model.geometry.weight(0, 1) * model.law.alpha(1e4, 0.0))}

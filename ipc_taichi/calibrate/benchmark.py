"""How long ``calibrate`` takes on a full-frame dark ramp and flat ramps (a benchmark
row, not a test)."""

import os
import tempfile
import time

import numpy as np

from ..coupling import couple
from .workflow import calibrate

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


def _flat_ramps(size, nints, groups, seed=1, per_group=2100.0, read_noise=12.0, alpha=0.006):
    """Flat ramps [e-] (nints, groups, size, size): Poisson collection, a 1 %
    response map, a constant nearest-neighbour coupling at each read."""
    rng = np.random.default_rng(seed)
    response = 1.0 + 0.01 * rng.standard_normal((size, size))
    ramps = np.empty((nints, groups, size, size), np.float32)
    for i in range(nints):
        charge = np.zeros((size, size))
        for g in range(groups):
            if g:
                charge += rng.poisson(per_group * response)
            ramps[i, g] = couple(charge, law=alpha) + rng.normal(0.0, read_noise, charge.shape)
    return ramps


def _write(path, sci):
    from astropy.io import fits

    hdu = fits.ImageHDU(sci, name="SCI")
    hdu.header["BUNIT"] = "electron"
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(path)


def measure_calibrate(size=2048, groups=10, flat_size=512, flat_ints=8, flat_groups=20):
    """Wall time of :func:`ipc_taichi.calibrate.calibrate` on a ``size`` x
    ``size`` x ``groups`` dark ramp and ``flat_ints`` flat ramps of
    ``flat_size`` x ``flat_size`` x ``flat_groups`` reads to ~40 ke-, in
    electrons (FITS read, hot-pixel search, group-by-group measurement, flat
    ramps separated, the law chosen on held-out folds, the transfer check,
    the model written).

    Returns
    -------
    dict
        ``size``, ``groups``, ``flats`` (shape text), ``seconds`` (calibrate
        only), ``hot_pixels_found``, ``alpha_x`` (the measured law at 10 ke-,
        0.006 made both), ``chosen`` (the law form), ``brighter_fatter`` and
        ``nonlinear_ipc`` (detected: both False for these data).
    """
    with tempfile.TemporaryDirectory() as tmp:
        dark = os.path.join(tmp, "dark.fits")
        _write(dark, _ramp(int(size), int(groups)))
        flats = []
        if flat_ints:
            flats.append(os.path.join(tmp, "flats.fits"))
            _write(flats[0], _flat_ramps(int(flat_size), int(flat_ints), int(flat_groups)))
        start = time.perf_counter()
        result = calibrate([dark], flats, output=os.path.join(tmp, "model.json"))
        seconds = time.perf_counter() - start
    model, report = result["model"], result["report"]
    return {"size": int(size), "groups": int(groups),
            "flats": f"{flat_ints} x {flat_groups} x {flat_size}x{flat_size}" if flat_ints
            else "none",
            "seconds": seconds, "hot_pixels_found": int(report["hot_pixels"]["found"]),
            "alpha_x": float(model.geometry.weight(0, 1) * model.law.alpha(1e4, 0.0)),
            "chosen": report["fit"]["chosen"],
            "brighter_fatter": bool(report["brighter_fatter"]["detected"]),
            "nonlinear_ipc": bool(report["nonlinear_ipc"]["detected"])}

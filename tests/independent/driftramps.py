"""An independent generator of ramp lab files (``docs/discovery_format.md``,
"Ramps") with the readout's bias drifting from read to read.

Imports nothing from ``ipc_taichi`` (NumPy and astropy only). Written from
the physics, read by read:

- Scene: a uniform background rate, a few Gaussian spots and scattered hot
  pixels, e- per second (SCENE is this rate).
- Collection: between reads each pixel gains a Poisson number of electrons
  of mean ``rate x TFRAME`` (read 0 at ``TFRAME``), summed.
- IPC: ``alpha`` to each of the four nearest neighbours (zero beyond the
  frame), on the charge present at each read.
- Read noise: Gaussian per read and pixel, ``readnoise`` e-.
- Bias drift (``drift_rms``, e-): at each read one Gaussian offset added to
  every pixel of the frame (what reference pixels track).
- Column offsets (``column_rms``, e-): at each read one Gaussian offset per
  column (the 1/f noise of a column-parallel readout); ``column_lag``: a
  column's offset correlated with the previous column's by that much (a
  Gaussian AR(1) sequence along x, stationary: 1/f noise smooth across columns).
"""

import numpy as np
from astropy.io import fits

ALPHA = 0.01


def spot_scene(n, rng, background=30.0, spots=5, peak=1500.0, hot=12):
    """Background plus ``spots`` Gaussian spots (sigma 1.5 px) and ``hot``
    hot pixels at random places, e-/s."""
    y, x = np.mgrid[0:n, 0:n]
    rate = np.full((n, n), background)
    for _ in range(spots):
        cy, cx = rng.uniform(3, n - 3, 2)
        rate += peak * rng.uniform(0.3, 1.0) * np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / 4.5)
    rate[rng.integers(0, n, hot), rng.integers(0, n, hot)] += rng.uniform(500, 4000, hot)
    return rate


def _couple(q, alpha):
    out = (1.0 - 4.0 * alpha) * q
    out[:, 1:, :] += alpha * q[:, :-1, :]
    out[:, :-1, :] += alpha * q[:, 1:, :]
    out[:, :, 1:] += alpha * q[:, :, :-1]
    out[:, :, :-1] += alpha * q[:, :, 1:]
    return out


def drift_ramp(n, nreads, tframe, readnoise, rng, drift_rms=0.0, column_rms=0.0,
               column_lag=0.0):
    """``(rate, reads)`` of one ramp (module docstring)."""
    rate = spot_scene(n, rng)
    charge = np.cumsum(rng.poisson(np.broadcast_to(rate * tframe, (nreads, n, n)))
                       .astype(np.float64), axis=0)
    reads = _couple(charge, ALPHA) + rng.normal(0.0, readnoise, (nreads, n, n))
    reads += rng.normal(0.0, drift_rms, (nreads, 1, 1)) if drift_rms else 0.0
    if column_rms:
        shocks = rng.normal(0.0, 1.0, (nreads, n))
        columns = np.empty_like(shocks)
        columns[:, 0] = shocks[:, 0]
        for x in range(1, n):
            columns[:, x] = column_lag * columns[:, x - 1] + np.sqrt(
                1.0 - column_lag ** 2) * shocks[:, x]
        reads += column_rms * columns[:, None, :]
    return rate, reads


def make_drift_file(path, n=32, nreads=8, tframe=2.0, pairs=3, seed=0, readnoise=10.0,
                    **hidden):
    """Write a ramp lab file of ``pairs`` ramps and return what was hidden."""
    rng = np.random.default_rng(seed)
    hdus = [fits.PrimaryHDU()]
    hdus[0].header["READNOIS"] = readnoise
    hdus[0].header["SHOTNOIS"] = True
    hdus[0].header["IPCLAW"] = f"constant:{ALPHA}"
    for k in range(pairs):
        rate, reads = drift_ramp(n, nreads, tframe, readnoise, rng, **hidden)
        s = fits.ImageHDU(rate.astype(">f4"), name="SCENE")
        s.header["EXTVER"] = k + 1
        m = fits.ImageHDU(reads.astype(">f4"), name="MEASURED")
        m.header["EXTVER"] = k + 1
        m.header["TFRAME"] = tframe
        hdus += [s, m]
    fits.HDUList(hdus).writeto(path, overwrite=True)
    return hidden

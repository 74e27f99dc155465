"""Read noise of integer DN darks, and the gain it gives the flat ramps' fit.

A detector writes integers: DN. ``calibrate`` measures the read noise on the
darks (consecutive differences) and holds it fixed in the flat ramps' fit,
where the increments' variance is ``I / r + 2 sigma^2``: a read-noise
variance ``delta`` too small moves ``2 delta`` into the shot noise and the
gain ratio ``r`` low by ``2 delta / I``. The median absolute deviation of
integer differences is itself an integer number of DN, so at 12 e- of read
noise and 1.8 e-/DN (the bench's set, ``ipc_taichi/bench/calfull.py``) it
gave 11.32 e- (6 DN x 1.4826 x 1.8 / sqrt 2), and the gain came out 1.771 for
1.8 e-/DN at every size.

The data here come from a generator written in this file (no project code:
Poisson charge from a dark first read, a 4-neighbour coupling of numpy
shifts, Gaussian read noise, rounding to uint16 DN, FITS written by astropy).
"""

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.calibrate import calibrate, hotpixels

GAIN = 1.8  # e-/DN
READ_NOISE = 12.0  # e- per read, before the DN rounding
ALPHA = 0.006
PER_GROUP = 500.0  # e- a group in the flats


def _dn_reads(rng, charges, bias):
    """Each charge frame [e-] coupled to its 4 neighbours (``ALPHA``), with read
    noise, as uint16 DN over ``bias``."""
    for q in charges:
        p = np.pad(q, 1)
        coupled = (1 - 4 * ALPHA) * q + ALPHA * (p[:-2, 1:-1] + p[2:, 1:-1]
                                                 + p[1:-1, :-2] + p[1:-1, 2:])
        e = coupled + READ_NOISE * rng.standard_normal(q.shape)
        yield np.clip(np.rint(e / GAIN + bias), 0, 65535).astype(np.uint16)


def _ramp(rng, size, groups, per_group):
    """Reads [uint16 DN] of a ramp from reset: read 0 holds no charge."""
    bias = 10000.0 + rng.uniform(-300.0, 300.0, (size, size))
    rate = per_group * (1.0 + 0.01 * np.random.default_rng(5).standard_normal((size, size)))
    charge = np.cumsum([np.zeros((size, size))] + [rng.poisson(rate).astype(float)
                                                   for _ in range(groups - 1)], axis=0)
    return np.array(list(_dn_reads(rng, charge, bias)))


def _write(path, ramps):
    """(nints, ngroups, ny, nx) uint16 DN as an integer raw ramp (BZERO 32768)."""
    sci = fits.ImageHDU(ramps, name="SCI")  # astropy stores uint16 as int16 + BZERO
    sci.header["BUNIT"] = "DN"
    sci.header["GAIN"] = (GAIN, "e-/DN")
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(path)


def test_read_noise_of_integer_darks_is_not_stepped():
    """At 1.8 and 1.5 e-/DN the darks' read noise is sqrt(sigma^2 + g^2 / 12) to
    1.5 % (the old median absolute deviation: 5.7 % low at both)."""
    rng = np.random.default_rng(2)
    for gain in (1.8, 1.5):
        dn = np.rint(10000.0 + READ_NOISE / gain * rng.standard_normal((10, 256, 256)))
        measured = hotpixels.read_noise_from_darks(dn * gain)
        truth = np.sqrt(READ_NOISE ** 2 + gain ** 2 / 12.0)
        assert abs(measured / truth - 1.0) < 0.015, (gain, measured, truth)


def test_continuous_darks_keep_the_robust_value():
    """Without quantisation the value is the ordinary robust one: sigma to 1.5 %,
    a few hot pixels left out."""
    rng = np.random.default_rng(3)
    reads = 5.0 * rng.standard_normal((6, 256, 256))
    reads[:, rng.integers(0, 256, 20), rng.integers(0, 256, 20)] += \
        np.arange(6)[:, None] * 3000.0
    assert abs(hotpixels.read_noise_from_darks(reads) / 5.0 - 1.0) < 0.015


@pytest.mark.slow
def test_gain_of_integer_ramps_with_darks(cpu, tmp_path):
    """Flats of 500 e- a group with the darks' read noise held fixed: the gain
    within 2.5 % of 1.8 e-/DN (a read noise of 11.32 e- puts it ~6 % low here:
    ``2 delta / I`` with ``delta`` = 16 e-^2)."""
    rng = np.random.default_rng(11)
    size = 256
    dark, flats = tmp_path / "dark.fits", tmp_path / "flats.fits"
    _write(dark, _ramp(rng, size, 10, 0.5)[None])
    _write(flats, np.array([_ramp(rng, size, 12, PER_GROUP) for _ in range(6)]))
    report = calibrate([str(dark)], [str(flats)], measure_map=False)["report"]
    rn = report["provenance"]["read_noise_e"]
    assert abs(rn / np.sqrt(READ_NOISE ** 2 + GAIN ** 2 / 12.0) - 1.0) < 0.015, rn
    gain = report["gain"]
    assert gain["error"] < 0.01 * GAIN, gain
    assert abs(gain["measured"] / GAIN - 1.0) < 0.025, gain

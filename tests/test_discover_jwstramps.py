"""JWST ramps as discovery ramp files (``ipc_taichi.discover.jwstramps``,
``ipc-taichi ramp-file``): the reads, times and rate of a tiny JWST-like
ramp made here with NumPy (bias, Poisson charge, read noise, integers with
BZERO as in an ``_uncal``); the gap of a complete model at its floor once
the first read's noise (``FIRSTSUB``) and the left-out rate's variance
(``SCENEVAR``) are whitened, and not without them; the real FGS ACQ1 file;
the ramp figure."""

import os

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.discover.jwstramps import (
    expected_gap_factor,
    jwst_ramps,
    symmetric_model,
    write_jwst_ramps,
)
from ipc_taichi.discover.rampfigures import RAMP_FIGURE, write_ramp_figure
from ipc_taichi.discover.ramps import RampData, ramp_gap, read_ramps
from ipc_taichi.errors import IPCInputError

DATA = os.path.join(os.path.dirname(__file__), "data")
FGS = os.path.join(DATA, "jwst_fgs_guider2_acq1.fits")
GAIN, TGROUP, READNOISE = 1.6, 0.5, 9.0


def _uncal(path, rate_dn, nints=6, ngroups=2, seed=1, tgroup=TGROUP, keyword=True,
           shared_e=0.0):
    """A raw JWST-like ramp: bias (per pixel, and a reset level per
    integration), Poisson electrons collected from ``rate_dn`` DN/s x GAIN
    since the reset (group g at (g + 1) tgroup), read noise per group,
    ``shared_e`` e- RMS offsets per group shared by each row; DN, int16 with
    BZERO 32768."""
    rng = np.random.default_rng(seed)
    ny, nx = rate_dn.shape
    bias = 12000.0 + rng.normal(0.0, 300.0, (ny, nx))
    sci = np.empty((nints, ngroups, ny, nx))
    for k in range(nints):
        reset = rng.normal(0.0, 20.0)
        steps = rng.poisson(rate_dn * GAIN * tgroup, (ngroups, ny, nx))
        charge = np.cumsum(steps, axis=0) + rng.poisson(rate_dn * GAIN * tgroup, (ny, nx))
        read = charge + rng.normal(0.0, READNOISE, charge.shape)
        read += rng.normal(0.0, shared_e, (ngroups, ny, 1)) if shared_e else 0.0
        sci[k] = bias + reset + read / GAIN
    primary = fits.PrimaryHDU()
    primary.header["TELESCOP"] = "JWST"
    primary.header["NINTS"], primary.header["NGROUPS"] = nints, ngroups
    if keyword:
        primary.header["TGROUP"] = tgroup
    hdu = fits.ImageHDU(np.round(sci).astype(np.int64) - 32768, name="SCI")
    hdu.data = hdu.data.astype(np.int16)
    hdu.header["BZERO"], hdu.header["BUNIT"] = 32768, "DN"
    fits.HDUList([primary, hdu]).writeto(path)
    return path


def _rates(ny=24, nx=24):
    rate = np.full((ny, nx), 40.0)  # DN/s
    rate[5:9, 5:9] = 900.0
    rate[15, 12] = 3000.0
    return rate


def test_reads_times_and_rate_of_a_noiseless_ramp(tmp_path):
    rate = _rates()
    # noiseless: no Poisson, no read noise; 3 integrations of 4 groups
    sci = np.stack([[1000.0 + 50 * k + rate * (g + 1) * TGROUP for g in range(4)]
                    for k in range(3)])
    path = str(tmp_path / "clean.fits")
    primary = fits.PrimaryHDU()
    primary.header["TGROUP"] = TGROUP
    hdu = fits.ImageHDU(sci, name="SCI")
    hdu.header["BUNIT"] = "DN"
    fits.HDUList([primary, hdu]).writeto(path)
    out = str(tmp_path / "ramps.fits")
    made = write_jwst_ramps(path, out, GAIN, readnoise=5.0)
    data = read_ramps(out)
    assert len(data.ramps) == 3 and data.readnoise == 5.0
    for ramp in data.ramps:
        assert ramp.first_subtracted
        np.testing.assert_allclose(ramp.times, TGROUP * np.arange(1, 4))
        np.testing.assert_allclose(ramp.rate, rate * GAIN, rtol=1e-9)  # e-/s
        np.testing.assert_allclose(ramp.reads, rate[None] * GAIN * ramp.times[:, None, None],
                                   rtol=1e-9)
        # the left-out slope's variance: (rate t_m + 2 r^2) / t_m^2 over 2 other integrations
        t_m = 3 * TGROUP
        np.testing.assert_allclose(ramp.scene_var,
                                   (rate * GAIN * t_m + 2 * 25.0) / t_m ** 2 / 2, rtol=1e-9)
    assert made.gap_factor == 1.0


def test_leave_one_out_factor_is_the_variance_it_adds():
    # one increment, n integrations: the residual of a left-out mean has n / (n - 1)
    assert expected_gap_factor(6, 1) == pytest.approx(1.2)
    assert expected_gap_factor(2, 1) == pytest.approx(2.0)
    rng = np.random.default_rng(3)
    d = rng.normal(0.0, 1.0, (6, 200000))
    resid = d - (d.sum(axis=0) - d) / 5
    assert np.mean(resid ** 2) == pytest.approx(1.2, rel=0.01)
    assert 1.0 < expected_gap_factor(6, 9) < 1.05  # more reads: the rate's share falls


def test_complete_model_reaches_its_floor_only_with_scenevar(tmp_path):
    path = _uncal(str(tmp_path / "u.fits"), _rates(), nints=6, ngroups=2)
    out = str(tmp_path / "r.fits")
    made = write_jwst_ramps(path, out, GAIN, law="constant:0")
    assert made.readnoise == pytest.approx(READNOISE, rel=0.1)  # measured, not given
    data = read_ramps(out)
    stats = ramp_gap(data, n_sim=4, seed=2)
    assert stats["complete"], stats
    assert abs(stats["gap"] - 1.0) < 0.06
    # the same ramps without the rate's variance: the gap rises by about n / (n - 1)
    bare = RampData(data.path, data.readnoise, data.shot_noise, data.law,
                    [type(r)(r.extver, r.rate, r.reads, r.times, r.oversample,
                             r.first_subtracted, None) for r in data.ramps])
    without = ramp_gap(bare, n_sim=4, seed=2)
    assert without["gap"] == pytest.approx(1.2 * stats["gap"], rel=0.05)
    assert not without["complete"]


def test_shared_row_noise_is_seen_between_neighbours(tmp_path):
    path = _uncal(str(tmp_path / "u.fits"), _rates(), nints=6, ngroups=3, shared_e=12.0)
    out = str(tmp_path / "r.fits")
    write_jwst_ramps(path, out, GAIN, law="constant:0")
    stats = ramp_gap(out, n_sim=4, seed=1)
    m, s = stats["neighbour_floor"]["x"]
    assert (stats["neighbour_correlation"]["x"] - m) / s > 10  # rows share it
    m, s = stats["neighbour_floor"]["y"]
    assert abs(stats["neighbour_correlation"]["y"] - m) / s < 5


def test_errors_name_the_file(tmp_path):
    path = _uncal(str(tmp_path / "u.fits"), _rates(), keyword=False)
    with pytest.raises(IPCInputError, match="u.fits: no TGROUP"):
        jwst_ramps(path, GAIN)
    assert jwst_ramps(path, GAIN, tgroup=TGROUP).tgroup == TGROUP
    with pytest.raises(IPCInputError, match=r"u.fits\[SCI\].*exclude box 0:30"):
        jwst_ramps(path, GAIN, tgroup=TGROUP, exclude=[(0, 30, 0, 4)])
    one = _uncal(str(tmp_path / "one.fits"), _rates(), nints=1, ngroups=2)
    with pytest.raises(IPCInputError, match="one integration of 2 groups"):
        jwst_ramps(one, GAIN)


def test_cli_ramp_file(tmp_path, cli):
    path = _uncal(str(tmp_path / "u.fits"), _rates(), nints=3, ngroups=3)
    out = tmp_path / "r.fits"
    res = cli("ramp-file", path, out, "--gain", GAIN, "--exclude", "0:4,0:24")
    assert res.returncode == 0, res.stderr
    assert "3 ramp pairs of 2 reads" in res.stdout and "left out: rows 0:4" in res.stderr
    data = read_ramps(str(out))
    assert np.isnan(data.ramps[0].reads[:, :4]).all() and not data.ramps[0].valid[:4].any()
    res = cli("ramp-file", path, out, "--gain", GAIN)
    assert res.returncode == 2 and "exists" in res.stderr
    res = cli("ramp-file", path, tmp_path / "x.fits", "--gain", GAIN, "--exclude", "a,b")
    assert res.returncode == 2 and "--exclude 'a,b'" in res.stderr


def test_real_fgs_acq1_file(tmp_path):
    made = jwst_ramps(FGS, 1.57, exclude=[(64, 125, 35, 96)])
    assert len(made.rates) == 6 and made.reads[0].shape == (1, 128, 128)
    assert made.tgroup == pytest.approx(0.364)
    assert 6.0 < made.readnoise < 14.0  # e- per read, measured
    with fits.open(FGS) as hdul:
        sci = hdul["SCI"].data.astype(np.float64)
    slope = (sci[:, 1] - sci[:, 0]) * 1.57 / 0.364
    outside = np.ones((128, 128), dtype=bool)
    outside[64:125, 35:96] = False
    # the typical pixel's rate is the typical slope; the box is left out
    assert np.median(made.rates[0][outside]) == pytest.approx(np.median(slope[:, outside]),
                                                              abs=3.0)
    assert np.isnan(made.reads[0][:, 64:125, 35:96]).all()


def test_symmetric_model_and_the_figure(tmp_path):
    import json

    from ipc_taichi.geometry import Geometry
    from ipc_taichi.model import CouplingModel

    src = str(tmp_path / "m.json")  # second neighbours measured along x only, as on the FGS
    CouplingModel.resolve(law="constant:0.004", geometry=Geometry.terms(
        second_horizontal=0.1, second_vertical=0.0)).save(src)
    out = symmetric_model(src, str(tmp_path / "s.json"))
    with open(out) as f:
        geometry = {(dy, dx): w for dy, dx, w in json.load(f)["geometry"]}
    assert geometry[(0, 2)] == geometry[(2, 0)] == geometry[(-2, 0)] == pytest.approx(0.05)
    path = _uncal(str(tmp_path / "u.fits"), _rates(), nints=3, ngroups=3)
    write_jwst_ramps(path, str(tmp_path / "r.fits"), GAIN, law="constant:0")
    stats = ramp_gap(str(tmp_path / "r.fits"), n_sim=3)
    keys = ("gap", "gap_per_read", "neighbour_correlation")
    report = {"input": "r.fits", "baseline": stats, "gap_per_read_floor":
              stats["gap_per_read_floor"], "neighbour_floor": stats["neighbour_floor"],
              "steps": [{"effect": "correlated_read_noise", **{k: stats[k] for k in keys}}],
              "complete": stats["complete"], "missing_effects": ["correlated_read_noise"],
              "final_gap": stats["gap"], "gap_floor": stats["gap_floor"],
              "gap_floor_sigma": stats["gap_floor_sigma"]}
    written = write_ramp_figure(report, str(tmp_path / "figs"))
    assert written == str(tmp_path / "figs" / RAMP_FIGURE)
    with open(written, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    assert os.path.getsize(written) > 10_000

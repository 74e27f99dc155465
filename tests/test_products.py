"""JWST-shaped FITS products through ``ipc-taichi decouple``, as a user runs it.

The input files are built here with astropy and NumPy: the truth is a charge
image in electrons, the measured image is the independent NumPy model
(``couple_reference``) of it, converted to the product's units. Nothing of
the product pipeline is used to make them.
"""

import os

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.reference import couple_reference
from tests.helpers import next_to

DO_NOT_USE, SATURATED, REFERENCE_PIXEL = 1, 2, 2 ** 31
GAIN, EFFINTTM, BORDER = 2.0, 100.0, 4


def _primary():
    h = fits.Header()
    for key, value in (("TELESCOP", "JWST"), ("INSTRUME", "NIRCAM"), ("DETECTOR", "NRCALONG"),
                       ("FILTER", "F444W"), ("SUBARRAY", "SUB64"), ("EFFINTTM", EFFINTTM),
                       ("EFFEXPTM", EFFINTTM), ("NGROUPS", 3), ("DATE-OBS", "2026-01-01")):
        h[key] = value
    return h


def _reference_flags(shape):
    dq = np.zeros(shape, dtype=np.uint32)
    dq[:BORDER] = dq[-BORDER:] = REFERENCE_PIXEL | DO_NOT_USE
    dq[:, :BORDER] = dq[:, -BORDER:] = REFERENCE_PIXEL | DO_NOT_USE
    return dq


def _bad_pixels(rng, shape, n):
    """``n`` DO_NOT_USE positions inside the science region."""
    science = np.zeros(shape, dtype=bool)
    science[BORDER:-BORDER, BORDER:-BORDER] = True
    flat = rng.choice(np.flatnonzero(science), n, replace=False)
    mask = np.zeros(shape, dtype=bool)
    mask.flat[flat] = True
    return mask


# The true charge of a masked pixel is unknown, so the charge it exchanged
# with its neighbours stays in them (ring 1: error up to ~alpha * its
# charge); their error reaches the next ring through the iteration (ring 2:
# ~alpha^2 * charge). Beyond that the result is exact to the stopping rule.
ALPHA_MAX = 0.008  # donlon2018 at zero signal, its largest value


def _rings(bad):
    ring1 = next_to(bad) & ~bad
    ring2 = next_to(next_to(bad)) & ~ring1 & ~bad
    return ring1, ring2, ~next_to(next_to(bad))


def _measured_electrons(truth_e):
    """IPC on the science region; the reference border is zero-signal."""
    out = np.zeros_like(truth_e)
    out[BORDER:-BORDER, BORDER:-BORDER] = couple_reference(
        truth_e[BORDER:-BORDER, BORDER:-BORDER])
    return out


@pytest.fixture
def rate_file(tmp_path, rng):
    """A JWST level-2 ``_rate.fits``-like product: DN/s, float32, a 4-pixel
    reference border, DO_NOT_USE pixels holding junk."""
    shape = (64, 72)
    truth_e = np.zeros(shape)
    truth_e[BORDER:-BORDER, BORDER:-BORDER] = rng.uniform(0, 60000, (56, 64))
    rate = (_measured_electrons(truth_e) / (GAIN * EFFINTTM)).astype(np.float32)
    bad = _bad_pixels(rng, shape, 60)
    rate[bad] = rng.uniform(-1e4, 1e5, bad.sum()).astype(np.float32)  # junk
    refpix = _reference_flags(shape) != 0
    rate[refpix] = rng.normal(0.0, 0.5, refpix.sum()).astype(np.float32)
    dq = _reference_flags(shape)
    dq[bad] |= DO_NOT_USE | 2 ** 10
    sci = fits.ImageHDU(rate, name="SCI")
    sci.header["BUNIT"] = "DN/s"
    asdf = fits.BinTableHDU.from_columns(
        [fits.Column(name="ASDF_METADATA", format="40A", array=np.array([b"#ASDF 1.0.0"]))],
        name="ASDF")
    hdul = fits.HDUList([
        fits.PrimaryHDU(header=_primary()), sci,
        fits.ImageHDU(np.full(shape, 0.1, np.float32), name="ERR"),
        fits.ImageHDU(dq, name="DQ"),
        fits.ImageHDU(rng.uniform(0, 1, shape).astype(np.float32), name="VAR_POISSON"),
        fits.ImageHDU(rng.uniform(0, 1, shape).astype(np.float32), name="VAR_RNOISE"),
        asdf])
    path = tmp_path / "jw01_rate.fits"
    hdul.writeto(path)
    return path, truth_e / (GAIN * EFFINTTM), bad, refpix


def test_rate_product_kept_whole(cli, tmp_path, rate_file):
    src, truth, bad, refpix = rate_file
    out = tmp_path / "out" / "jw01_ipc.fits"
    out.parent.mkdir()
    r = cli("decouple", "--law", "donlon2018", src, out, "--gain", GAIN)
    assert r.returncode == 0, r.stderr
    with fits.open(src) as a, fits.open(out) as b:
        assert [h.name for h in b] == [h.name for h in a]
        for key in a[0].header:  # every primary keyword carried through
            if key not in ("COMMENT", "HISTORY", ""):
                assert b[0].header[key] == a[0].header[key], key
        assert b[0].header["S_IPC"] == "COMPLETE" and b[0].header["IPCCONV"] is True
        assert b["SCI"].header["BUNIT"] == "DN/s"
        for name in ("ERR", "DQ", "VAR_POISSON", "VAR_RNOISE"):
            assert b[name].data.dtype == a[name].data.dtype
        np.testing.assert_array_equal(b["DQ"].data, a["DQ"].data)
        for name in ("ERR", "VAR_POISSON", "VAR_RNOISE"):  # propagated: test_products_noise
            kept = refpix | bad  # never corrected: their noise as it came
            np.testing.assert_array_equal(b[name].data[kept], a[name].data[kept])
            assert not np.array_equal(b[name].data, a[name].data)
        assert b["ASDF"].data.tobytes() == a["ASDF"].data.tobytes()
        got, measured = b["SCI"].data, a["SCI"].data
        assert got.dtype.kind == "f" and got.dtype.itemsize == 4
        # reference pixels and DO_NOT_USE pixels: bit-identical
        assert got[refpix].tobytes() == measured[refpix].tobytes()
        assert got[bad].tobytes() == measured[bad].tobytes()
    ring1, ring2, far = _rings(bad)
    err = np.abs(got.astype(float) - truth)
    top = truth.max()
    assert err[far & ~refpix].max() <= 2e-5 * top
    assert err[ring2 & ~refpix].max() <= 4 * ALPHA_MAX ** 2 * top
    # the junk (up to 1e5 DN/s) did not leak into the ring
    assert err[ring1 & ~refpix].max() <= 4 * ALPHA_MAX * top
    # and the measured frame was far from the truth (the test can fail)
    assert np.abs(measured.astype(float) - truth)[far & ~refpix].max() > 100 * 2e-5 * top


def test_masked_pixels_do_not_couple(cli, tmp_path, rng):
    """Pixels that truly do not couple (the NumPy model's NaN pixels), flagged
    DO_NOT_USE and holding junk: every other pixel, next to them or not, comes
    out within 2e-5 of the truth; the convention is exact where it holds."""
    truth = rng.uniform(0, 60000, (40, 44))
    bad = np.zeros(truth.shape, dtype=bool)
    bad.flat[rng.choice(truth.size, 40, replace=False)] = True
    measured = couple_reference(np.where(bad, np.nan, truth))
    measured[bad] = rng.uniform(-1e6, 1e6, bad.sum())
    src, out = tmp_path / "in.fits", tmp_path / "out.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(measured, name="SCI"),
                  fits.ImageHDU(np.where(bad, DO_NOT_USE, 0).astype(np.uint32),
                                name="DQ")]).writeto(src)
    r = cli("decouple", "--law", "donlon2018", src, out)
    assert r.returncode == 0, r.stderr
    got = fits.getdata(out, "SCI")
    assert (got[bad] == measured[bad]).all()
    assert np.abs(got - truth)[~bad].max() <= 2e-5 * truth.max()
    # junk decoupled as data
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "nodq.fits", "--dq-bits", "0")
    assert r.returncode == 0, r.stderr
    wrong = fits.getdata(tmp_path / "nodq.fits", "SCI")
    assert np.abs(wrong - truth)[next_to(bad) & ~bad].max() > 1000


def test_rate_product_tiled_equals_whole(cli, tmp_path, rate_file):
    src, truth, bad, refpix = rate_file
    whole, tiled = tmp_path / "whole.fits", tmp_path / "tiled.fits"
    assert cli("decouple", "--law", "donlon2018", src, whole, "--gain", GAIN).returncode == 0
    r = cli("decouple", "--law", "donlon2018", src, tiled, "--gain", GAIN, "--tile", 16)
    assert r.returncode == 0, r.stderr
    with fits.open(whole) as a, fits.open(tiled) as b:
        assert [h.name for h in b] == [h.name for h in a]
        np.testing.assert_allclose(b["SCI"].data, a["SCI"].data, rtol=0,
                                   atol=1e-6 * truth.max())
        assert b["SCI"].data[refpix].tobytes() == a["SCI"].data[refpix].tobytes()
        assert b[0].header["IPCITER"] == a[0].header["IPCITER"]
        np.testing.assert_array_equal(b["DQ"].data, a["DQ"].data)


def test_ramp_product_group_by_group(cli, tmp_path, rng):
    """A bias-subtracted 4-D ramp (1 integration x 3 groups, DN) with PIXELDQ
    and GROUPDQ: decoupled group by group; IPC acts on the charge at each read."""
    shape = (48, 40)
    rate_e = np.zeros(shape)
    rate_e[BORDER:-BORDER, BORDER:-BORDER] = rng.uniform(0, 20000, (40, 32))
    truth = np.stack([rate_e * (g + 1) / GAIN for g in range(3)])[np.newaxis]  # DN
    sci = np.stack([_measured_electrons(rate_e * (g + 1)) / GAIN
                    for g in range(3)])[np.newaxis].astype(np.float32)
    pixeldq = _reference_flags(shape)
    bad = _bad_pixels(rng, shape, 20)
    pixeldq[bad] |= DO_NOT_USE
    sci[0, :, bad] = 65535.0
    groupdq = np.zeros(sci.shape, dtype=np.uint8)
    late = _bad_pixels(rng, shape, 5) & ~bad
    groupdq[0, 2][late] = DO_NOT_USE  # flagged in the last group only
    sci[0, 2][late] = -999.0
    saturated = _bad_pixels(rng, shape, 5)
    groupdq[0, 1][saturated] = SATURATED  # a default bit: its charge is unknown, left out
    ramp = fits.ImageHDU(sci, name="SCI")
    ramp.header["BUNIT"] = "DN"
    src, out = tmp_path / "jw01_ramp.fits", tmp_path / "jw01_ramp_ipc.fits"
    fits.HDUList([fits.PrimaryHDU(header=_primary()), ramp,
                  fits.ImageHDU(pixeldq, name="PIXELDQ"), fits.ImageHDU(groupdq, name="GROUPDQ"),
                  fits.ImageHDU(np.ones(sci.shape, np.float32), name="ERR")]).writeto(src)
    r = cli("decouple", "--law", "donlon2018", src, out, "--gain", GAIN)
    assert r.returncode == 0, r.stderr
    refpix = pixeldq & REFERENCE_PIXEL != 0
    with fits.open(src) as a, fits.open(out) as b:
        assert [h.name for h in b] == ["PRIMARY", "SCI", "PIXELDQ", "GROUPDQ", "ERR"]
        for name in ("PIXELDQ", "GROUPDQ"):
            np.testing.assert_array_equal(b[name].data, a[name].data)
        assert not np.array_equal(b["ERR"].data, a["ERR"].data)  # test_products_noise
        got = b["SCI"].data
        assert got.dtype.itemsize == 4 and got.shape == (1, 3) + shape
        assert "frame     2" in str(b[0].header["HISTORY"])
        for g in range(3):
            masked = bad | (late if g == 2 else False) | (saturated if g == 1 else False)
            keep = masked | refpix  # bit-identical (the file is big-endian, sci native)
            assert got[0, g][keep].astype("<f4").tobytes() == sci[0, g][keep].tobytes()
            np.testing.assert_array_equal(b["ERR"].data[0, g][keep], 1.0)  # as it came
            ring1, ring2, far = _rings(masked)
            err = np.abs(got[0, g].astype(float) - truth[0, g])
            top = truth[0, g].max()
            assert err[far & ~refpix].max() <= 2e-5 * top, g
            assert err[ring2 & ~refpix].max() <= 4 * ALPHA_MAX ** 2 * top, g
            assert err[ring1 & ~refpix].max() <= 4 * ALPHA_MAX * top, g


def test_units_are_converted(cli, tmp_path, rng):
    """The law sees electrons: a DN/s frame decoupled with its gain and
    integration time equals the electron frame decoupled, divided back."""
    truth_e = rng.uniform(0, 60000, (24, 28))
    measured_e = couple_reference(truth_e)
    e_file, rate_file = tmp_path / "e.fits", tmp_path / "rate.fits"
    fits.writeto(e_file, measured_e)
    h = fits.Header()
    h["BUNIT"], h["EFFINTTM"], h["GAIN"] = "DN/s", 50.0, 1.8
    fits.writeto(rate_file, measured_e / (1.8 * 50.0), header=h)
    assert cli("decouple", "--law", "donlon2018", e_file, tmp_path / "e_out.fits").returncode == 0
    # GAIN and EFFINTTM keywords
    r = cli("decouple", "--law", "donlon2018", rate_file, tmp_path / "rate_out.fits")
    assert r.returncode == 0, r.stderr
    e_out = fits.getdata(tmp_path / "e_out.fits")
    rate_out = fits.getdata(tmp_path / "rate_out.fits")
    np.testing.assert_allclose(rate_out * 1.8 * 50.0, e_out, rtol=1e-10)
    assert np.abs(e_out - truth_e).max() < 0.05
    # the same numbers read as electrons would be decoupled with alpha at ~0 e-
    r = cli("decouple", "--law", "donlon2018", rate_file, tmp_path / "wrong.fits",
            "--bunit", "electron")
    assert r.returncode == 0
    wrong = fits.getdata(tmp_path / "wrong.fits") * 1.8 * 50.0
    assert np.abs(wrong - truth_e).max() > 100 * np.abs(e_out - truth_e).max()


@pytest.mark.parametrize("header, args, message", [
    ({"BUNIT": "MJy/sr"}, [], "flux-calibrated"),
    ({"BUNIT": "DN/s"}, [], "need a gain"),
    ({"BUNIT": "DN/s"}, ["--gain", "2"], "integration time"),
    ({"BUNIT": "furlongs"}, [], "not understood"),
])
def test_units_refused(cli, tmp_path, rng, header, args, message):
    src = tmp_path / "in.fits"
    h = fits.Header()
    h.update(header)
    fits.HDUList([fits.PrimaryHDU(header=h), fits.ImageHDU(rng.uniform(0, 1, (8, 8)),
                                                           name="SCI", header=h)]).writeto(src)
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits", *args)
    assert r.returncode == 2
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and message in line and "in.fits[SCI]" in line
    assert sorted(os.listdir(tmp_path)) == ["in.fits"]


def test_refpix_option_and_gain_image(cli, tmp_path, rng):
    """``--refpix N`` without flags; a per-pixel gain image."""
    shape = (30, 34)
    gain = rng.uniform(1.5, 2.5, shape)
    truth_e = np.zeros(shape)
    truth_e[BORDER:-BORDER, BORDER:-BORDER] = rng.uniform(0, 60000, (22, 26))
    dn = _measured_electrons(truth_e) / gain
    dn[:BORDER] = 7.0  # reference border holds anything
    src, gfile, out = tmp_path / "in.fits", tmp_path / "gain.fits", tmp_path / "out.fits"
    h = fits.Header()
    h["BUNIT"] = "DN"
    fits.writeto(src, dn, header=h)
    unknown = gain.copy()
    unknown[15, 15] = 0.0  # no usable gain there: the pixel is left out, like a DQ flag
    fits.writeto(gfile, unknown)
    r = cli("decouple", "--law", "donlon2018", src, out, "--gain", gfile, "--refpix", BORDER)
    assert r.returncode == 0, r.stderr
    got = fits.getdata(out)
    assert got[15, 15] == dn[15, 15]
    far = np.zeros(shape, dtype=bool)
    far[BORDER:-BORDER, BORDER:-BORDER] = True
    far[13:18, 13:18] = False
    assert np.abs(got * gain - truth_e)[far].max() < 2e-5 * truth_e.max()
    assert (got[:BORDER] == 7.0).all()
    # a 1-based FITS section [x1:x2,y1:y2], in the science HDU's header
    assert fits.getheader(out)["IPCSCIRG"] == f"[5:{shape[1] - 4},5:{shape[0] - 4}]"


def test_dq_hdu_is_refused_as_data(cli, tmp_path, rate_file):
    src, *_ = rate_file
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "o.fits", "--gain", GAIN,
            "--hdu", "DQ")
    assert r.returncode == 2 and "bit flags" in r.stderr and "[DQ]" in r.stderr
    assert not (tmp_path / "o.fits").exists()


def test_cube_tiled_keeps_header(cli, tmp_path, rng):
    """A 3-D stack in the primary HDU through --tile: frame by frame, each
    frame equal to the whole-frame decoupler, the header kept."""
    import ipc_taichi

    cube = np.stack([couple_reference(rng.uniform(0, 60000, (50, 42))) for _ in range(2)])
    src, out = tmp_path / "cube.fits", tmp_path / "out.fits"
    hdr = fits.Header()
    hdr["OBSERVER"] = "tiles"
    fits.writeto(src, cube.astype(">f8"), header=hdr)
    r = cli("decouple", "--law", "donlon2018", src, out, "--tile", 16)
    assert r.returncode == 0, r.stderr
    with fits.open(out) as hdul:
        data, h = hdul[0].data, hdul[0].header
    assert h["OBSERVER"] == "tiles" and data.shape == cube.shape
    for k in range(2):
        whole, info = ipc_taichi.decouple(cube[k], full_output=True)
        assert f"frame     {k}: {info.iterations:3d} iterations, converged" in str(h["HISTORY"])
        assert np.abs(data[k] - whole).max() <= 1e-12 * whole.max()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tmp-")]


def test_rateints_integration_by_integration(cli, tmp_path, rng):
    """A ``_rateints``-like stack (nints, ny, nx) in DN/s with a 3-D DQ: each
    integration with its own flags."""
    shape = (20, 24)
    truth_e = rng.uniform(0, 60000, (2,) + shape)
    sci = np.stack([couple_reference(t) for t in truth_e]) / (GAIN * EFFINTTM)
    dq = np.zeros(sci.shape, dtype=np.uint32)
    dq[1, 10, 12] = DO_NOT_USE  # flagged in the second integration only
    sci[1, 10, 12] = 9e9
    hdu = fits.ImageHDU(sci.astype(np.float32), name="SCI")
    hdu.header["BUNIT"] = "DN/s"
    src, out = tmp_path / "jw_rateints.fits", tmp_path / "out.fits"
    fits.HDUList([fits.PrimaryHDU(header=_primary()), hdu,
                  fits.ImageHDU(dq, name="DQ")]).writeto(src)
    r = cli("decouple", "--law", "donlon2018", "--edge", "zero", src, out, "--gain", GAIN,
            "--refpix", 0)
    assert r.returncode == 0, r.stderr
    got = fits.getdata(out, "SCI").astype(float)
    truth = truth_e / (GAIN * EFFINTTM)
    assert got[1, 10, 12] == np.float32(9e9)
    assert np.abs(got[0] - truth[0]).max() <= 2e-5 * truth[0].max()
    far = ~next_to(next_to(dq[1] != 0))
    assert np.abs(got[1] - truth[1])[far].max() <= 2e-5 * truth[1].max()
    assert np.abs(got[1] - truth[1])[~far].max() > 2e-5 * truth[1].max()  # the ring


@pytest.mark.parametrize("bunit, kind", [
    (None, "charge"), ("electrons", "charge"), ("e-", "charge"), ("DN", "dn"),
    ("counts", "dn"), ("ADU", "dn"), ("DN/s", "dn_rate"), ("DN / s", "dn_rate"),
    ("DN s-1", "dn_rate"), ("DN s**-1", "dn_rate"), ("dn/sec", "dn_rate"),
    ("electron/s", "charge_rate"), ("e-/s", "charge_rate")])
def test_units_read_from_bunit(bunit, kind):
    from ipc_taichi.products import parse_units

    assert parse_units(bunit, "f.fits[SCI]").kind == kind


@pytest.mark.parametrize("bunit", ["MJy/sr", "MJy", "erg/s/cm2/A", "furlongs", "DN/s/pixel"])
def test_units_refused_by_name(bunit):
    from ipc_taichi import IPCInputError
    from ipc_taichi.products import parse_units

    with pytest.raises(IPCInputError, match=r"f\.fits\[SCI\]: BUNIT"):
        parse_units(bunit, "f.fits[SCI]")


def test_tiled_with_nan_block_equals_whole(cli, tmp_path, rng):
    """A block of NaN covering whole tiles: --tile gives the whole-frame result,
    NaN kept."""
    measured = couple_reference(rng.uniform(0, 60000, (48, 48)))
    measured[:20, :20] = np.nan
    measured[30, 40] = np.nan
    src = tmp_path / "in.fits"
    fits.writeto(src, measured)
    assert cli("decouple", "--law", "donlon2018", src, tmp_path / "whole.fits").returncode == 0
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "tiled.fits", "--tile", 8)
    assert r.returncode == 0, r.stderr
    whole, tiled = fits.getdata(tmp_path / "whole.fits"), fits.getdata(tmp_path / "tiled.fits")
    assert np.array_equal(np.isnan(tiled), np.isnan(measured))
    assert np.nanmax(np.abs(tiled - whole)) <= 1e-12 * np.nanmax(whole)
    assert np.nanmax(np.abs(whole - measured)) > 100  # it was decoupled


def test_tiled_reads_scaled_float_data_as_astropy_does(cli, tmp_path, rng):
    """Float data with BSCALE/BZERO: the tiled path's memory-mapped windows are
    scaled as astropy scales them (they were read unscaled: 15,491 e- off), so
    --tile gives the whole-frame result."""
    measured = couple_reference(rng.uniform(0, 60000, (40, 36)))
    src = tmp_path / "in.fits"
    fits.writeto(src, ((measured - 10.0) / 2.0).astype(np.float32))
    with fits.open(src, mode="update") as hdul:
        hdul[0].header["BSCALE"], hdul[0].header["BZERO"] = 2.0, 10.0
    for name, extra in (("whole.fits", ()), ("tiled.fits", ("--tile", 16))):
        r = cli("decouple", "--law", "donlon2018", src, tmp_path / name, *extra)
        assert r.returncode == 0, r.stderr
    whole, tiled = fits.getdata(tmp_path / "whole.fits"), fits.getdata(tmp_path / "tiled.fits")
    assert np.abs(tiled - whole).max() <= 1e-6 * np.abs(whole).max()
    assert np.abs(whole - measured).max() > 100  # it was decoupled

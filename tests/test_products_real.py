"""Files shaped like the real instrument products of issue 18, generated here.

Each file copies the structure of a real product (HDUs, keywords, units, DQ
conventions) at a small size: a WFC3/IR MULTIACCUM ``_ima`` subarray (four
reads and a zeroth read, 5-pixel reference border, ELECTRONS/S, SAMPTIME per
read, HST DQ bits), a JWST superbias, a tile-compressed product, a LUCI2-like
cut-out in electrons (with NDIT coadds), a JWST dark with its own DQ_DEF. The
truth is built with the independent NumPy model (``couple_reference``); the
product pipeline makes none of it.
"""

import errno
import os

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.reference import couple_reference
from tests.helpers import LAW, optional

HST_BAD, HST_SATURATED = 4, 256


def _no_temporaries(folder):
    return not [p for p in os.listdir(folder) if p.startswith(".tmp-")]


# --- HST WFC3/IR _ima: every read, its own SAMPTIME, the zeroth read's charge


SAMPTIMES = (0.0, 2.9, 12.9, 22.9, 32.9)  # zeroth read first in time
N_SCI = 64  # science pixels per side; the 74x74 frame has a 5-pixel border


def _inner(a):
    return a[5:-5, 5:-5]


@pytest.fixture
def ima(tmp_path, rng):
    """A WFC3/IR ``_ima``-like file: imsets SCI/ERR/DQ/SAMP/TIME, EXTVER 1 =
    the last read ... EXTVER 5 = the zeroth read. The node holds the pedestal
    ``P`` at the zeroth read and ``P + R t`` at a read ``t`` seconds later;
    each read stores (coupled charge - coupled zeroth read) / t, the zeroth
    read stores its coupled charge (electrons)."""
    shape = (N_SCI + 10, N_SCI + 10)
    rate = np.zeros(shape)
    _inner(rate)[...] = rng.uniform(0, 800, (N_SCI, N_SCI))  # e-/s
    pedestal = np.zeros(shape)
    _inner(pedestal)[...] = 2.5 * _inner(rate) * 2.9 + 300  # bright stars: 2-3x the first read
    coupled = {}
    for t in SAMPTIMES:
        charge = np.zeros(shape)
        _inner(charge)[...] = couple_reference(_inner(pedestal + rate * t))
        coupled[t] = charge
    primary = fits.Header()
    for key, value in (("TELESCOP", "HST"), ("INSTRUME", "WFC3"), ("DETECTOR", "IR"),
                       ("FILETYPE", "SCI"), ("SUBARRAY", True), ("EXPTIME", SAMPTIMES[-1]),
                       ("NSAMP", len(SAMPTIMES))):
        primary[key] = value
    hdus = [fits.PrimaryHDU(header=primary)]
    dq_extra = np.zeros(shape, dtype=np.int16)
    sat = (20, 30)
    dq_extra[sat] = HST_SATURATED
    for ver, t in enumerate(reversed(SAMPTIMES), start=1):
        if t == 0:
            sci = coupled[0.0]
        else:
            sci = (coupled[t] - coupled[0.0]) / t
        sci = sci.copy()
        sci[:5] = sci[-5:] = 1.0 + ver  # reference pixels: anything, never changed
        sci[:, :5] = sci[:, -5:] = 1.0 + ver
        h = fits.Header()
        h["BUNIT"] = "ELECTRONS/S"
        h["SAMPTIME"] = t
        dq = dq_extra if ver == 1 else np.zeros(shape, dtype=np.int16)
        hdus += [fits.ImageHDU(sci.astype(np.float32), header=h, name="SCI", ver=ver),
                 fits.ImageHDU(rng.uniform(0, 1, shape).astype(np.float32), name="ERR",
                               ver=ver),
                 fits.ImageHDU(dq, name="DQ", ver=ver),
                 fits.ImageHDU(np.full(shape, 1 + ver, np.int16), name="SAMP", ver=ver),
                 fits.ImageHDU(np.full(shape, t, np.float32), name="TIME", ver=ver)]
    path = tmp_path / "ib1_ima.fits"
    fits.HDUList(hdus).writeto(path)
    return path, rate, pedestal, sat


def test_ima_every_read_with_its_samptime_and_the_zeroth_read(cli, tmp_path, ima):
    src, rate, pedestal, sat = ima
    out = tmp_path / "ib1_ipc.fits"
    r = cli("decouple", src, out, *LAW)
    assert r.returncode == 0, r.stderr
    with fits.open(src) as a, fits.open(out) as b:
        assert [h.name for h in b] == [h.name for h in a]
        assert b[0].header["S_IPC"] == "COMPLETE" and b[0].header["IPCNHDU"] == 5
        assert "zeroth read" in b[0].header["IPCPED"]
        for k in range(1, len(a)):
            name, ver = a[k].name, a[k].ver
            if name == "ERR":  # propagated (tests/test_products_noise.py); the border kept
                assert b[k].data.dtype == a[k].data.dtype and b[0].header["IPCNOISE"]
                assert not np.array_equal(b[k].data, a[k].data)
                assert a[k].data[:5].tobytes() == b[k].data[:5].tobytes()
                continue
            if name != "SCI":  # DQ, SAMP, TIME: bit-identical
                assert a[k].data.tobytes() == b[k].data.tobytes(), (name, ver)
                continue
            t = a[k].header["SAMPTIME"]
            got, before = b[k].data.astype(float), a[k].data.astype(float)
            border = np.ones(got.shape, dtype=bool)
            border[5:-5, 5:-5] = False
            assert got[border].tobytes() == before[border].tobytes()  # the 5-pixel border
            assert b[k].header["IPCTIME"] == t and b[k].header["IPCCONV"] is True
            assert b[k].header["IPCSCIRG"] == f"[6:{N_SCI + 5},6:{N_SCI + 5}]"
            truth = pedestal if t == 0 else rate
            err = np.abs(got - truth)[~border]
            if ver == 1:  # the saturated pixel keeps its value; ring 1 keeps ~alpha of it
                assert got[sat] == before[sat]
                near = np.zeros(got.shape, dtype=bool)
                near[sat[0] - 2:sat[0] + 3, sat[1] - 2:sat[1] + 3] = True
                err = np.abs(got - truth)[~border & ~near]
            assert err.max() <= 1e-4 * truth.max(), (ver, err.max())
            # the correction mattered: the file's values were off by far more
            assert np.abs(before - truth)[~border].max() > 30 * 1e-4 * truth.max()


def test_ima_without_the_pedestal_is_wrong_for_bright_pixels(cli, tmp_path, ima):
    """The law at the charge since the zeroth read misses the charge already
    on the node: the rule (and the option to turn it off) is what makes the
    first test pass."""
    src, rate, pedestal, _ = ima
    out = tmp_path / "nopedestal.fits"
    r = cli("decouple", src, out, *LAW, "--pedestal", "none")
    assert r.returncode == 0, r.stderr
    got = fits.getdata(out, ("SCI", 4)).astype(float)  # the first read, 2.9 s
    assert np.abs(_inner(got) - _inner(rate)).max() > 10 * 1e-4 * rate.max()
    assert fits.getheader(out, 0)["IPCPED"] == "none"


def test_ima_one_read_is_partial_and_the_default_law_is_refused(cli, tmp_path, ima):
    src, *_ = ima
    r = cli("decouple", src, tmp_path / "o.fits")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "HST WFC3" in r.stderr and "calibrate" in r.stderr and "--model" in r.stderr
    out = tmp_path / "one.fits"
    r = cli("decouple", src, out, *LAW, "--hdu", "SCI,2")
    assert r.returncode == 0, r.stderr
    with fits.open(out) as b:
        assert b[0].header["S_IPC"] == "PARTIAL" and b[0].header["IPCNHDU"] == 1
        assert b[("SCI", 2)].header["IPCOP"] == "decouple" and "IPCOP" not in b[("SCI", 3)].header
    # correcting SCI,3 next is not "already corrected"; SCI,2 again is
    r = cli("decouple", out, tmp_path / "two.fits", *LAW, "--hdu", "SCI,3")
    assert r.returncode == 0 and "already corrected" not in r.stderr
    r = cli("decouple", out, tmp_path / "three.fits", *LAW, "--hdu", "SCI,2")
    assert "already corrected" in r.stderr


def test_hst_dq_names(tmp_path):
    from ipc_taichi.products.conventions import parse_dq_bits
    from ipc_taichi.products.missions import recognise

    hst = recognise(fits.Header({"TELESCOP": "HST", "INSTRUME": "WFC3"}))
    assert parse_dq_bits("SATURATED", hst.dq_flags) == 256
    assert parse_dq_bits("HOT", hst.dq_flags) == 16
    assert parse_dq_bits("DO_NOT_USE", hst.dq_flags) == 1 | 2 | 4
    jwst = recognise(fits.Header({"TELESCOP": "JWST", "INSTRUME": "NIRCAM"}))
    assert parse_dq_bits("SATURATED", jwst.dq_flags) == 2


# --- a JWST dark with its own DQ_DEF, a superbias


def _jwst_primary(**extra):
    h = fits.Header()
    for key, value in dict(TELESCOP="JWST", INSTRUME="NIRSPEC", DETECTOR="NRS1",
                           SUBARRAY="SUB32", **extra).items():
        h[key] = value
    return h


def test_dq_def_of_the_file_comes_first(cli, tmp_path, rng):
    """A NIRSpec-dark-like file whose DQ_DEF says HOT = 4: ``--dq-bits HOT``
    leaves out the pixel with bit 4, not the one with JWST's 2048."""
    shape = (24, 26)
    data = couple_reference(rng.uniform(100, 3000, shape))
    dq = np.zeros(shape, dtype=np.uint32)
    dq[8, 9] = 4
    dq[15, 17] = 2048
    data[8, 9] = data[15, 17] = 5e4
    table = fits.BinTableHDU.from_columns(
        [fits.Column(name="BIT", format="J", array=[0, 1, 2]),
         fits.Column(name="VALUE", format="J", array=[1, 2, 4]),
         fits.Column(name="NAME", format="20A", array=["DO_NOT_USE", "SATURATED", "HOT"]),
         fits.Column(name="DESCRIPTION", format="20A", array=["bad", "sat", "hot"])],
        name="DQ_DEF")
    src, out = tmp_path / "dark.fits", tmp_path / "out.fits"
    fits.HDUList([fits.PrimaryHDU(header=_jwst_primary()), fits.ImageHDU(data, name="SCI"),
                  fits.ImageHDU(dq, name="DQ"), table]).writeto(src)
    r = cli("decouple", src, out, *LAW, "--dq-bits", "HOT")
    assert r.returncode == 0, r.stderr
    got = fits.getdata(out, "SCI")
    assert got[8, 9] == data[8, 9]  # left out: the file's HOT
    assert got[15, 17] != data[15, 17]  # 2048 means nothing in this file
    assert fits.getheader(out, 0)["IPCDQBIT"] == 4


def test_superbias_is_refused(cli, tmp_path, rng):
    src = tmp_path / "jwst_nirspec_superbias.fits"
    fits.HDUList([fits.PrimaryHDU(header=_jwst_primary(REFTYPE="SUPERBIAS")),
                  fits.ImageHDU(rng.uniform(1e4, 1.2e4, (16, 16)).astype(np.float32),
                                name="SCI")]).writeto(src)
    r = cli("decouple", src, tmp_path / "o.fits", *LAW)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "superbias" in r.stderr and "bias" in r.stderr
    assert not (tmp_path / "o.fits").exists()


# --- a LUCI2-like cut-out: the edge rule from the product, coadds


def _luci2(tmp_path, data, **extra):
    h = fits.Header()
    for key, value in dict(TELESCOP="LBT-DXU", INSTRUME="LUCI2", BUNIT="electrons",
                           **extra).items():
        h[key] = value
    path = tmp_path / "luci2_cutout.fits"
    fits.writeto(path, data, header=h, overwrite=True)
    return path


def test_cutout_border_is_not_raised(cli, tmp_path):
    """A cut-out of a uniform field is uniform after IPC (each pixel gives and
    takes the same): decoupled, it must stay uniform. The paper's zero edge
    raises its border by alpha (~1.2 % at 10 ke- with donlon2018) and its
    corners by about twice that."""
    path = _luci2(tmp_path, np.full((20, 24), 10000.0))
    out = tmp_path / "out.fits"
    r = cli("decouple", path, out, *LAW)
    assert r.returncode == 0, r.stderr
    got = fits.getdata(out)
    assert np.abs(got / 10000.0 - 1).max() < 1e-9
    h = fits.getheader(out)
    assert h["IPCEDGE"] == "isolated" and "cut-out" in h["IPCEDGER"]
    r = cli("decouple", path, tmp_path / "zero.fits", *LAW, "--edge", "zero")
    zero = fits.getdata(tmp_path / "zero.fits")
    edge, corner = zero[0, 10] / 10000.0 - 1, zero[0, 0] / 10000.0 - 1
    assert 0.008 < edge < 0.015 and 1.8 * edge < corner < 2.2 * edge


def test_coadds_divide_the_charge(cli, tmp_path, rng):
    """A sum of NDIT = 10 exposures: the law sees the charge of one."""
    truth = rng.uniform(0, 6000, (20, 22))
    path = _luci2(tmp_path, 10 * couple_reference(truth), NDIT=10)
    out, wrong = tmp_path / "out.fits", tmp_path / "wrong.fits"
    assert cli("decouple", path, out, *LAW, "--edge", "zero").returncode == 0
    got = fits.getdata(out)
    assert np.abs(got - 10 * truth).max() <= 2e-5 * 10 * truth.max()
    assert fits.getheader(out)["IPCCOADD"] == 10
    assert cli("decouple", path, wrong, *LAW, "--edge", "zero", "--coadds", "1").returncode == 0
    assert np.abs(fits.getdata(wrong) - 10 * truth).max() > 100 * 2e-5 * 10 * truth.max()


# --- saturation and unphysical values


def test_unflagged_garbage_is_named_and_saturation_leaves_out(cli, tmp_path, rng):
    data = couple_reference(rng.uniform(0, 5000, (20, 20)))
    data[7, 8] = 1e30
    src = tmp_path / "img.fits"
    fits.writeto(src, data)
    r = cli("decouple", src, tmp_path / "a.fits", *LAW)
    assert "unflagged" in r.stderr and "y=7, x=8" in r.stderr
    r = cli("decouple", src, tmp_path / "b.fits", *LAW, "--saturation", 60000)
    assert r.returncode == 0 and "unflagged pixel" not in r.stderr
    got = fits.getdata(tmp_path / "b.fits")
    assert got[7, 8] == 1e30 and np.isfinite(got).all()
    assert np.abs(got[7, 8 + 3:]).max() < 1e4  # no garbage beyond the first rings


# --- tile-compressed products


def _compressed(tmp_path, rng, dq_compressed=False):
    truth = rng.integers(0, 60000, (40, 48)).astype(np.float64)
    data = np.rint(couple_reference(truth)).astype(np.int32)
    dq = np.zeros(data.shape, dtype=np.int32)
    dq[10, 10] = 1
    sci = fits.CompImageHDU(data, name="SCI", compression_type="RICE_1")
    flags = fits.CompImageHDU(dq, name="DQ") if dq_compressed else fits.ImageHDU(dq, name="DQ")
    src = tmp_path / "comp.fits"
    fits.HDUList([fits.PrimaryHDU(), sci, flags]).writeto(src)
    plain = tmp_path / "plain.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(data, name="SCI"),
                  fits.ImageHDU(dq, name="DQ")]).writeto(plain)
    return src, plain


@pytest.mark.parametrize("dq_compressed", [False, True])
def test_compressed_product_right_or_refused(cli, tmp_path, rng, dq_compressed):
    src, plain = _compressed(tmp_path, rng, dq_compressed)
    a, b, c = tmp_path / "a.fits", tmp_path / "b.fits", tmp_path / "c.fits"
    assert cli("decouple", src, a, *LAW).returncode == 0
    assert cli("decouple", plain, b, *LAW).returncode == 0
    np.testing.assert_array_equal(fits.getdata(a, "SCI"), fits.getdata(b, "SCI"))
    assert fits.getdata(a, "SCI")[10, 10] == fits.getdata(plain, "SCI")[10, 10]
    r = cli("decouple", src, c, *LAW, "--tile", 16)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "tile-compressed" in r.stderr
    assert not c.exists() and _no_temporaries(tmp_path)


# --- disk full, truncated files, directories as outputs


def test_full_disk_one_line_nothing_left(cli, tmp_path, rng, monkeypatch):
    src = tmp_path / "in.fits"
    fits.writeto(src, couple_reference(rng.uniform(0, 5000, (20, 20))))
    before = src.read_bytes()
    out_dir = tmp_path / "out"
    out_dir.mkdir()

    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "posix_fallocate", full)
    r = cli("decouple", src, out_dir / "o.fits", *LAW)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert str(out_dir / "o.fits") in r.stderr and "No space left" in r.stderr
    assert ".tmp-" not in r.stderr
    assert os.listdir(out_dir) == [] and src.read_bytes() == before


def test_truncated_fits_header_refused(cli, tmp_path, rng):
    src = tmp_path / "cut.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(rng.uniform(0, 5000, (16, 16)), name="SCI"),
                  fits.ImageHDU(np.zeros((16, 16), np.int32), name="DQ")]).writeto(src)
    raw = src.read_bytes()
    dq_header = raw.rfind(b"XTENSION")
    src.write_bytes(raw[:dq_header + 400])  # cut inside the last header
    r = cli("decouple", src, tmp_path / "o.fits", *LAW)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert str(src) in r.stderr and not (tmp_path / "o.fits").exists()


def test_truncated_roman_file_refused(cli, tmp_path, rng):
    rdm = pytest.importorskip("roman_datamodels.datamodels", reason=optional("roman_datamodels"))
    model = rdm.ImageModel.create_fake_data(shape=(32, 32))
    model.data = rng.uniform(0, 10, (32, 32)).astype(np.float32)
    model.meta.exposure.effective_exposure_time = 100.0
    src = tmp_path / "r_cal.asdf"
    model.save(src)
    raw = src.read_bytes()
    cut = tmp_path / "cut.asdf"
    cut.write_bytes(raw[:len(raw) * 2 // 3])
    r = cli("decouple", cut, tmp_path / "o.asdf", *LAW, "--gain", 2)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert str(cut) in r.stderr and _no_temporaries(tmp_path)


def test_directory_as_output_refused_before_work(cli, tmp_path, rng):
    src = tmp_path / "in.fits"
    fits.writeto(src, rng.uniform(0, 5000, (12, 12)))
    target = tmp_path / "adir"
    target.mkdir()
    r = cli("decouple", src, "--output", target, "--overwrite", *LAW)
    assert r.returncode == 2 and "is a directory" in r.stderr
    assert os.listdir(target) == [] and _no_temporaries(tmp_path)


# --- S_IPC: written last, with convergence


def test_unconverged_is_not_complete(cli, tmp_path, rng):
    src, out = tmp_path / "in.fits", tmp_path / "out.fits"
    fits.writeto(src, couple_reference(rng.uniform(0, 60000, (20, 20))))
    r = cli("decouple", src, out, *LAW, "--max-iter", 1)
    assert r.returncode == 3
    h = fits.getheader(out)
    assert h["S_IPC"] == "FAILED" and h["IPCCONV"] is False


def test_a_killed_run_claims_nothing():
    """The header written before the work says PENDING (what a run killed by
    SIGKILL leaves in its temporary file); COMPLETE only after the work."""
    from ipc_taichi.model import CouplingModel
    from ipc_taichi.products import RunSettings
    from ipc_taichi.products.provenance import Provenance
    from tests.helpers import one_array_plan

    plan = one_array_plan(CouplingModel.resolve("donlon2018"))
    prov = Provenance(plan, RunSettings("decouple", 20, 1e-5))
    assert prov.primary(fits.Header())["S_IPC"] == "PENDING"

    class Info:
        iterations, converged, max_delta = 4, True, [0.0]

    prov.infos[1] = [Info()]
    assert prov.primary(fits.Header())["S_IPC"] == "COMPLETE"


def test_model_file_for_an_instrument_product(cli, tmp_path, rng):
    from ipc_taichi.model import CouplingModel

    model = tmp_path / "nrs1.json"
    CouplingModel.resolve("constant:0.006").save(model, provenance={"test": True})
    truth = rng.uniform(0, 20000, (20, 22))
    src = tmp_path / "rate.fits"
    sci = fits.ImageHDU(couple_reference(truth, law="constant:0.006", edge="isolated"),
                        name="SCI")
    sci.header["BUNIT"] = "electrons"
    fits.HDUList([fits.PrimaryHDU(header=_jwst_primary()), sci]).writeto(src)
    out = tmp_path / "out.fits"
    r = cli("decouple", src, out, "--model", model, "--edge", "zero")
    assert r.returncode == 2 and "--model" in r.stderr  # the file holds the edge too
    r = cli("decouple", src, out, "--model", model)
    assert r.returncode == 0, r.stderr
    # a cut-out (no reference border): the frame decides the edge, not the model file
    # (a measured coupling says nothing of where a cut-out ends)
    assert fits.getheader(out)["IPCEDGE"] == "isolated"
    assert np.abs(fits.getdata(out, "SCI") - truth).max() <= 2e-5 * truth.max()


def test_ima_tiled_equals_whole_without_pedestal(cli, tmp_path, ima):
    """Every read through --tile (the pedestal cannot be added tile by tile:
    refused in one line; with --pedestal none, tiled equals whole)."""
    src, *_ = ima
    r = cli("decouple", src, tmp_path / "t.fits", *LAW, "--tile", 16)
    assert r.returncode == 2 and "--pedestal none" in r.stderr
    whole, tiled = tmp_path / "whole.fits", tmp_path / "tiled.fits"
    assert cli("decouple", src, whole, *LAW, "--pedestal", "none").returncode == 0
    r = cli("decouple", src, tiled, *LAW, "--pedestal", "none", "--tile", 16)
    assert r.returncode == 0, r.stderr
    with fits.open(whole) as a, fits.open(tiled) as b:
        for ver in range(1, 6):
            np.testing.assert_allclose(b[("SCI", ver)].data, a[("SCI", ver)].data, rtol=1e-6,
                                       atol=1e-6)
        assert b[0].header["S_IPC"] == "COMPLETE"


def test_cutout_rate_uses_exptime(cli, tmp_path, rng):
    """A NIRISS-like rate cut-out (DN/s) that carries EXPTIME but no EFFINTTM:
    no --exptime needed; the time used is recorded in its HDU."""
    truth = rng.uniform(0, 20000, (18, 20))
    sci = fits.ImageHDU((couple_reference(truth) / (2.0 * 50.0)).astype(np.float32), name="SCI")
    sci.header["BUNIT"] = "DN/s"
    primary = fits.Header({"TELESCOP": "JWST", "INSTRUME": "NIRISS", "EXPTIME": 50.0})
    src, out = tmp_path / "cutout.fits", tmp_path / "out.fits"
    fits.HDUList([fits.PrimaryHDU(header=primary), sci]).writeto(src)
    r = cli("decouple", src, out, *LAW, "--edge", "zero", "--gain", 2.0)
    assert r.returncode == 0, r.stderr
    assert fits.getheader(out, "SCI")["IPCTIME"] == 50.0
    got = fits.getdata(out, "SCI").astype(float) * 100.0
    assert np.abs(got - truth).max() <= 2e-5 * truth.max() + 1e-3 * 100

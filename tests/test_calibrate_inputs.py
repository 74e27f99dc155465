"""calibrate's inputs: what a file is (ramp or frames), its units and gain, its refusals."""

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.calibrate import calibrate
from ipc_taichi.calibrate.inputs import cube_rises, read_frames
from ipc_taichi.errors import IPCInputError
from ipc_taichi.products import process_fits
from tests.helpers import optional

NY = NX = 48


def _write(path, sci, bunit=None, primary=None, sci_keys=None, **extra):
    """A JWST-like file: PRIMARY (keywords ``primary``), SCI, then ``extra`` HDUs."""
    head = fits.PrimaryHDU()
    for k, v in (primary or {}).items():
        head.header[k] = v
    data = np.asarray(sci)
    sci_hdu = fits.ImageHDU(data if data.dtype.kind in "ui" else data.astype(np.float32),
                            name="SCI")
    if bunit is not None:
        sci_hdu.header["BUNIT"] = bunit
    for k, v in (sci_keys or {}).items():
        sci_hdu.header[k] = v
    hdus = [head, sci_hdu] + [fits.ImageHDU(d, name=n) for n, d in extra.items()]
    fits.HDUList(hdus).writeto(path)
    return str(path)


def _ramp(rng, nreads, flux, gradient=0.3, prnu=0.03, read_noise=10.0):
    """Reads of one flat ramp [e-]: Poisson increments of a non-uniform flux."""
    pattern = (1 + prnu * rng.standard_normal((NY, NX))) * np.linspace(
        1 - gradient, 1 + gradient, NX)[None, :]
    reads = np.cumsum(rng.poisson(flux * pattern, (nreads, NY, NX)), axis=0)
    return reads + rng.normal(0, read_noise, reads.shape)


def _frames(rng, nframes, level, drift=0.0, gradient=0.3, prnu=0.03):
    """Independent frames at one level [e-] (a lamp drifting by ``drift`` per frame)."""
    pattern = (1 + prnu * rng.standard_normal((NY, NX))) * np.linspace(
        1 - gradient, 1 + gradient, NX)[None, :]
    return np.array([rng.poisson(level * (1 + drift * k) * pattern) for k in range(nframes)],
                    dtype=float)


# ---- ramp or frames ------------------------------------------------------------------

def test_4d_sci_is_ramps(tmp_path, rng):
    data = np.array([_ramp(rng, 5, 800.0) for _ in range(3)])
    f = read_frames(_write(tmp_path / "r4.fits", data, bunit="electron"), role="flat")
    assert f.data.shape == f.mask.shape == (3, 5, NY, NX) and f.data.dtype == np.float64
    assert f.meta["stack"] == "ramp"
    assert (f.meta["nints"], f.meta["ngroups"], f.meta["nframes"]) == (3, 5, 5)
    assert "4-D SCI (3 integrations x 5 groups" in f.meta["stack_reason"]
    np.testing.assert_allclose(f.data, data.astype(np.float32))


def test_rising_cube_is_one_ramp(tmp_path, rng):
    data = _ramp(rng, 8, 2000.0)
    f = read_frames(_write(tmp_path / "r3.fits", data), role="flat")
    assert f.data.shape == (1, 8, NY, NX)
    assert f.meta["stack"] == "ramp" and (f.meta["nints"], f.meta["ngroups"]) == (1, 8)
    reason = f.meta["stack_reason"]
    assert reason.startswith("3-D cube of 8 reads whose mean rises") and "(a ramp)" in reason
    first, last = (float(x) for x in reason.split("rises ")[1].split(" e-")[0].split(" -> "))
    assert first == pytest.approx(2000, rel=0.1) and last == pytest.approx(16000, rel=0.1)


def test_frames_at_one_level_stay_frames_even_with_lamp_drift(tmp_path, rng):
    # 0.3 % drift per frame, all upward (monotonic): +1.5 % over 6 frames, i.e. 300 e- at
    # 20 ke-, inside 5 x the 200 e- noise of a frame difference: not a ramp
    data = _frames(rng, 6, 20000.0, drift=0.003)
    f = read_frames(_write(tmp_path / "f.fits", data, bunit="electron"), role="flat")
    assert f.data.shape == (1, 6, NY, NX)
    assert f.meta["stack"] == "frames" and f.meta["ngroups"] is None
    assert f.meta["nframes"] == 6 and f.meta["nints"] == 1
    assert f.meta["stack_reason"].startswith("3-D stack of 6 frames at one level")
    steady = read_frames(_write(tmp_path / "g.fits", _frames(rng, 2, 5000.0)))
    assert steady.meta["stack"] == "frames"


def test_ramp_test_margins():
    """The ramp test itself: a two-read ramp rises; a cube that falls does not; a rise
    inside the noise does not."""
    rng = np.random.default_rng(3)
    base = rng.normal(0.0, 10.0, (2, 64, 64))
    two = base + np.array([0.0, 300.0])[:, None, None]  # 300 e- >> 5 x 14 e-
    assert cube_rises(two)["rises"]
    small = base + np.array([0.0, 40.0])[:, None, None]  # 40 e- < 5 x 14 e-
    r = cube_rises(small)
    assert not r["rises"] and r["rise"] == pytest.approx(40, abs=3)
    assert r["noise"] == pytest.approx(10 * np.sqrt(2), rel=0.1)
    falling = rng.normal(0.0, 10.0, (3, 64, 64)) + np.array([0, 500, 400])[:, None, None]
    r = cube_rises(falling)
    assert not r["rises"] and r["falls"] == 1


def test_dark_cube_is_a_ramp_by_its_jwst_keywords(tmp_path, rng):
    dark = rng.normal(0.0, 5.0, (6, NY, NX))
    keys = {"NGROUPS": 6, "NINTS": 1, "READPATT": "NRSRAPID", "TELESCOP": "JWST"}
    f = read_frames(_write(tmp_path / "d.fits", dark, bunit="electron", primary=keys),
                    role="dark")
    assert f.meta["stack"] == "ramp" and f.meta["ngroups"] == 6
    assert "NGROUPS = 6, READPATT NRSRAPID" in f.meta["stack_reason"]
    assert "within 5 x its noise" in f.meta["stack_reason"]
    plain = read_frames(_write(tmp_path / "d2.fits", dark, bunit="electron"), role="dark")
    assert plain.meta["stack"] == "frames"


def test_2d_is_one_frame(tmp_path, rng):
    f = read_frames(_write(tmp_path / "one.fits", rng.normal(100, 3, (NY, NX))))
    assert f.data.shape == (1, 1, NY, NX) and f.meta["stack"] == "frames"
    assert f.meta["stack_reason"] == "2-D SCI: one frame" and f.meta["nframes"] == 1
    g = read_frames(_write(tmp_path / "one3.fits", rng.normal(100, 3, (1, NY, NX))))
    assert g.meta["stack"] == "frames" and g.meta["stack_reason"] == "3-D SCI: one frame"


# ---- units and gain ------------------------------------------------------------------

def test_no_bunit_with_a_gain_given_is_dn(tmp_path, rng):
    data = _ramp(rng, 4, 500.0)
    path = _write(tmp_path / "dn.fits", data)
    f = read_frames(path, gain=1.5)
    assert f.meta["units_note"] == "no BUNIT: taken as DN, gain 1.5 e-/DN given"
    assert f.meta["gain"] == 1.5 and f.meta["gain_source"] == "given"
    np.testing.assert_allclose(f.data[0], 1.5 * data.astype(np.float32))
    # the CLI's string form of the gain reads the same
    assert read_frames(path, gain="1.5").meta["gain"] == 1.5


def test_no_bunit_with_a_gain_keyword_is_dn(tmp_path, rng):
    data = rng.normal(1000, 10, (2, NY, NX))
    f = read_frames(_write(tmp_path / "k.fits", data, sci_keys={"GAIN": 2.0}))
    assert f.meta["units_note"] == "no BUNIT: taken as DN, gain 2 e-/DN from the GAIN keyword"
    assert f.meta["gain"] == 2.0 and f.meta["gain_source"] == "GAIN keyword"
    np.testing.assert_allclose(f.data[0], 2.0 * data.astype(np.float32))
    # a gain given wins over the keyword
    g = read_frames(_write(tmp_path / "k2.fits", data, primary={"GAIN": 2.0}), gain=3.0)
    assert g.meta["gain"] == 3.0 and g.meta["gain_source"] == "given"


def test_no_bunit_and_no_gain_is_electrons_said(tmp_path, rng):
    data = rng.normal(1000, 10, (2, NY, NX))
    f = read_frames(_write(tmp_path / "e.fits", data))
    assert f.meta["units_note"] == "no BUNIT and no gain: taken as electrons"
    assert f.meta["gain"] is None and f.meta["gain_source"] is None
    np.testing.assert_allclose(f.data[0], data.astype(np.float32))


def _refusals(path, tmp_path, **options):
    """The one-line refusals of calibrate's reader, of calibrate and of decouple
    for the same file and options."""
    said = []
    for run in (lambda: read_frames(path, **options),
                lambda: calibrate(darks=[path], **options),
                lambda: process_fits(path, str(tmp_path / "out.fits"), **options)):
        with pytest.raises(IPCInputError) as refused:
            run()
        said.append(str(refused.value))
    return said


def test_gain_given_for_electrons_is_refused_as_decouple_refuses_it(tmp_path, rng):
    """One rule, the product plan's: a gain given for data in electrons (the
    file's BUNIT, or --bunit) is refused by calibrate and decouple alike."""
    data = rng.normal(1000, 10, (2, NY, NX))
    path = _write(tmp_path / "el.fits", data, bunit="electron")
    said = _refusals(path, tmp_path, gain=1.5)
    assert said[0] == said[1] == said[2]
    assert said[0] == (f"{path}[SCI]: a gain was given but the data are in electron; give "
                       "--bunit DN or DN/s if they are not")
    dn = _write(tmp_path / "dn.fits", data, bunit="DN")
    said = _refusals(dn, tmp_path, gain=2.0, bunit="electron")
    assert said[0] == said[1] == said[2] and "a gain was given" in said[0]
    assert not (tmp_path / "out.fits").exists()
    # without a gain the same file is read, in electrons
    f = read_frames(path)
    assert f.meta["units_note"] == "BUNIT 'electron': electrons" and f.meta["gain"] is None
    np.testing.assert_allclose(f.data[0], data.astype(np.float32))


def test_gain_image_and_keyword_read_as_decouple_reads_them(tmp_path, rng):
    """A gain image's unusable pixels are left out (decouple's masked-pixel
    rule), and a GAIN keyword that is not a number is blamed on the keyword."""
    data = rng.normal(1000, 10, (2, NY, NX))
    gain = np.full((NY, NX), 2.0)
    gain[5, 7] = 0.0
    image = tmp_path / "gain.fits"
    fits.writeto(image, gain)
    f = read_frames(_write(tmp_path / "g.fits", data, bunit="DN"), gain=str(image))
    assert f.mask[0, :, 5, 7].all() and np.isnan(f.data[0, :, 5, 7]).all()
    assert f.mask[0, :, 5, 8].sum() == 0 and f.meta["gain"] == 2.0
    bad = _write(tmp_path / "k.fits", data, bunit="DN", sci_keys={"GAIN": "abc"})
    with pytest.raises(IPCInputError, match=r"k\.fits\[SCI\]: header GAIN = 'abc' is not a "
                                            "number"):
        read_frames(bad)


def test_dn_without_any_gain_and_rates_are_refused(tmp_path, rng):
    data = rng.normal(1000, 10, (2, NY, NX))
    with pytest.raises(IPCInputError, match=r"dn\.fits\[SCI\]: data in DN need a gain"):
        read_frames(_write(tmp_path / "dn.fits", data, bunit="DN"))
    with pytest.raises(IPCInputError, match=r"rate\.fits\[SCI\]: a rate \(DN/s\)"):
        read_frames(_write(tmp_path / "rate.fits", data, bunit="DN/s"), gain=2.0, role="flat")
    with pytest.raises(IPCInputError, match="a rate"):
        read_frames(_write(tmp_path / "r2.fits", data), gain=2.0, bunit="DN/s")


# ---- refusals ------------------------------------------------------------------------

def _superbias(tmp_path, rng):
    keys = {"REFTYPE": "SUPERBIAS", "TELESCOP": "JWST", "INSTRUME": "NIRCAM"}
    return _write(tmp_path / "jwst_nircam_superbias.fits", rng.normal(12000, 30, (NY, NX)),
                  bunit="DN", primary=keys)


def test_superbias_refused_as_decouple_refuses_it(tmp_path, rng):
    path = _superbias(tmp_path, rng)
    with pytest.raises(IPCInputError) as ours:
        read_frames(path, gain=2.0, role="dark")
    with pytest.raises(IPCInputError) as theirs:
        process_fits(path, str(tmp_path / "out.fits"), gain=2.0)
    assert str(ours.value) == str(theirs.value)
    assert str(ours.value).startswith(f"{path}[SCI]: a superbias (REFTYPE = SUPERBIAS)")
    assert len(str(ours.value).splitlines()) == 1
    with pytest.raises(IPCInputError, match=r"superbias\.fits\[SCI\]: a superbias"):
        calibrate(darks=[path], gain=2.0)
    with pytest.raises(IPCInputError, match=r"superbias\.fits\[SCI\]: a superbias"):
        calibrate(flats=[path], gain=2.0)


def test_other_reference_files_refused_but_darks_read(tmp_path, rng):
    flat_ref = _write(tmp_path / "jwst_flat.fits", np.ones((NY, NX)),
                      primary={"REFTYPE": "FLAT", "TELESCOP": "JWST"})
    with pytest.raises(IPCInputError, match=r"jwst_flat\.fits\[SCI\]: a flat reference file "
                                            r"\(REFTYPE = FLAT\)"):
        read_frames(flat_ref, role="flat")
    ipc_ref = _write(tmp_path / "jwst_ipc.fits", np.ones((3, 3)), primary={"REFTYPE": "IPC"})
    with pytest.raises(IPCInputError, match="--reference"):
        read_frames(ipc_ref, role="dark")
    dark_ref = _write(tmp_path / "jwst_dark.fits", rng.normal(0, 3, (4, NY, NX)), bunit="DN",
                      primary={"REFTYPE": "DARK", "NGROUPS": 4})
    assert read_frames(dark_ref, gain=1.0, role="dark").meta["stack"] == "ramp"


def test_uncal_ramp_read_as_charge_since_its_first_read(tmp_path, rng):
    bias = rng.normal(12000, 40, (NY, NX))
    ramp = np.array([_ramp(rng, 5, 600.0) for _ in range(2)]) / 2.0 + bias  # DN
    raw = np.clip(np.rint(ramp), 0, 65535).astype(np.uint16)
    path = _write(tmp_path / "jw_uncal.fits", raw, bunit="DN",
                  primary={"TELESCOP": "JWST", "NGROUPS": 5, "NINTS": 2})
    f = read_frames(path, gain=2.0, role="flat")
    assert f.meta["stack"] == "ramp" and f.meta["first_read_subtracted"]
    assert (f.meta["nints"], f.meta["ngroups"]) == (2, 5)
    assert "raw (_uncal) ramp, its first read subtracted" in f.meta["stack_reason"]
    expected = 2.0 * (raw.astype(float) - raw[:, :1].astype(float))
    np.testing.assert_allclose(f.data, expected)
    assert np.nanmedian(f.data[:, -1]) == pytest.approx(4 * 600.0, rel=0.05)


@pytest.mark.parametrize("shape", [(NY, NX), (3, NY, NX), (2, 1, NY, NX)])
def test_raw_reads_that_are_no_ramp_are_named_as_holding_bias(tmp_path, rng, shape):
    """A raw bias read (integer, 12 kDN, no ramp to subtract its first read from)
    is refused as bias, not read as 24 ke- of charge."""
    raw = np.clip(rng.normal(12000, 40, shape), 0, 65535).astype(np.uint16)
    path = _write(tmp_path / "raw.fits", raw, bunit="DN")
    with pytest.raises(IPCInputError,
                       match=r"raw\.fits\[SCI\].*raw reads hold the detector's bias"):
        read_frames(path, gain=2.0, role="dark")


def test_flat_ramp_saturated_in_every_read_is_said(tmp_path, rng):
    ramp = np.full((4, NY, NX), 60000.0)
    groupdq = np.full((1, 4, NY, NX), 2, np.uint32)  # SATURATED
    groupdq[0, 0, :, :5] = 0  # one unsaturated read is not a difference
    path = _write(tmp_path / "sat.fits", ramp[None], bunit="electron", GROUPDQ=groupdq)
    with pytest.raises(IPCInputError, match=r"sat\.fits\[SCI\]: every read of this flat ramp "
                                            r"is saturated \(DQ SATURATED\)"):
        read_frames(path, role="flat")
    keyed = _write(tmp_path / "satk.fits", np.full((1, 3, NY, NX), 30000.0), bunit="DN",
                   sci_keys={"SATURATE": 30000})
    with pytest.raises(IPCInputError, match=r"saturated \(>= SATURATE \(60000 e-\)\)"):
        read_frames(keyed, gain=2.0, role="flat")


def test_partly_saturated_flat_is_read(tmp_path, rng):
    data = _frames(rng, 4, 5000.0)
    dq = np.full((NY, NX), 2, np.uint32)
    dq[:, :20] = 0  # SATURATED on most pixels, not all
    f = read_frames(_write(tmp_path / "half.fits", data, bunit="electron", DQ=dq), role="flat")
    assert f.mask[0, :, :, 20:].all() and not f.mask[0, :, :, :20].any()


def test_everything_masked_is_said(tmp_path, rng):
    dq = np.ones((NY, NX), np.uint32)  # DO_NOT_USE
    path = _write(tmp_path / "dead.fits", rng.normal(5, 1, (3, NY, NX)), bunit="electron",
                  DQ=dq)
    with pytest.raises(IPCInputError, match=r"dead\.fits\[SCI\]: every pixel of this dark "
                                            r"frames is masked"):
        read_frames(path, role="dark")
    with pytest.raises(IPCInputError, match="role 'bias'"):
        read_frames(path, role="bias")


def test_roman_ramp_read_and_said(tmp_path, rng):
    rdm = pytest.importorskip("roman_datamodels.datamodels", reason=optional("roman_datamodels"))
    model = rdm.RampModel.create_fake_data(shape=(4, NY, NX))
    model.data = (_ramp(rng, 4, 1000.0) / 2.0).astype(np.float32)  # DN
    model.pixeldq = np.zeros((NY, NX), dtype=np.uint32)
    model.groupdq = np.zeros((4, NY, NX), dtype=np.uint8)
    path = str(tmp_path / "ramp.asdf")
    model.save(path)
    f = read_frames(path, gain=2.0, refpix=0, role="flat")
    assert f.meta["stack"] == "ramp" and f.meta["ngroups"] == 4
    assert f.meta["units_note"] == "Roman schema 'DN': DN converted with gain 2 e-/DN given"
    np.testing.assert_allclose(f.data[0], 2.0 * np.asarray(model.data, dtype=float))

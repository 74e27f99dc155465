"""One rule for data without BUNIT, the product plan's
(``products.plan.units_of``), asked by decouple and calibrate alike: DN when a
gain is known (``--gain`` or a ``GAIN`` keyword), electrons otherwise.

Before, decouple read such a file as electrons whatever its GAIN keyword said
and refused ``--gain``, while calibrate read it as DN: the same file was two
different charges."""

import numpy as np
from astropy.io import fits

from ipc_taichi.calibrate.inputs import read_frames

NY, NX = 24, 24


def _file(path, data, **keys):
    sci = fits.ImageHDU(data.astype(np.float32), name="SCI")
    for key, value in keys.items():
        sci.header[key] = value
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(path)
    return path


def _decoupled(cli, src, out, *args):
    r = cli("decouple", "--law", "donlon2018", src, out, *args)
    assert r.returncode == 0, r.stderr
    with fits.open(out) as h:
        return np.asarray(h["SCI"].data), " ".join(" ".join(h[0].header["HISTORY"]).split())


def test_no_bunit_with_a_gain_is_dn_for_decouple_and_calibrate(cli, tmp_path):
    rng = np.random.default_rng(21)
    data = rng.uniform(2000, 30000, (NY, NX))  # DN: x 2 e-/DN reaches 60 ke-
    keyword = _file(tmp_path / "keyword.fits", data, GAIN=2.0)
    plain = _file(tmp_path / "plain.fits", data)
    dn = _file(tmp_path / "dn.fits", data, BUNIT="DN", GAIN=2.0)
    as_dn, _ = _decoupled(cli, dn, tmp_path / "dn_out.fits")
    by_keyword, history = _decoupled(cli, keyword, tmp_path / "k_out.fits")
    by_option, _ = _decoupled(cli, plain, tmp_path / "o_out.fits", "--gain", "2")
    as_electrons, _ = _decoupled(cli, plain, tmp_path / "e_out.fits")
    np.testing.assert_array_equal(by_keyword, as_dn)
    np.testing.assert_array_equal(by_option, as_dn)
    assert "DN (no BUNIT, a gain known) -> electrons (gain 2 e-/DN)" in history
    # electrons (no gain known) see a law at half the charge: a different result
    assert np.abs(as_electrons - as_dn).max() > 1.0
    # calibrate reads the same charge from each file
    charge = read_frames(dn).data[0, 0]
    for path, gain in ((keyword, None), (plain, 2.0)):
        f = read_frames(path, gain=gain)
        np.testing.assert_array_equal(f.data[0, 0], charge)
        assert f.meta["units_note"].startswith("no BUNIT: taken as DN")
    np.testing.assert_allclose(charge, 2.0 * data.astype(np.float32))

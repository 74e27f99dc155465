"""The tiled path (``--tile``) with a frame of a stack that has nothing to
decouple: left as it came and said once, the other frames decoupled, as the
whole path does (``products.checks.LostFrames``); every frame lost: refused
in one line naming the file and HDU, nothing written."""

import numpy as np
from astropy.io import fits


def _stack(tmp_path, cube):
    src = tmp_path / "stack.fits"
    hdus = [fits.PrimaryHDU(), fits.ImageHDU(cube, name="SCI")]
    hdus[1].header["BUNIT"] = "electron"
    fits.HDUList(hdus).writeto(src)
    return src


def test_tiled_leaves_the_lost_frame_and_corrects_the_rest_as_whole(cli, tmp_path):
    rng = np.random.default_rng(12)
    cube = rng.uniform(1000, 30000, (3, 40, 40)).astype(np.float32)
    cube[1] = np.nan
    src = _stack(tmp_path, cube)
    whole, tiled = tmp_path / "whole.fits", tmp_path / "tiled.fits"
    r = cli("decouple", "--law", "donlon2018", src, whole)
    assert r.returncode == 0, r.stderr
    r = cli("decouple", "--law", "donlon2018", src, tiled, "--tile", "16")
    assert r.returncode == 0, r.stderr
    said = [line for line in r.stderr.splitlines() if "left as it was" in line]
    assert len(said) == 1 and "stack.fits[SCI] frame 1: no finite, unmasked pixel" in said[0]
    assert "the other 2 frame(s) are decoupled" in said[0]
    with fits.open(whole) as w, fits.open(tiled) as t:
        got, ref = t["SCI"].data, w["SCI"].data
        np.testing.assert_array_equal(got[1], cube[1])  # as it came (NaN == NaN)
        for k in (0, 2):
            assert np.abs(got[k] - cube[k]).max() > 1.0  # decoupled, not copied
            np.testing.assert_allclose(got[k], ref[k], rtol=1e-6, atol=1e-3)
        assert t[0].header["S_IPC"] == "COMPLETE"
        assert "frame     1: left as it was" in "\n".join(t[0].header["HISTORY"])


def test_tiled_refuses_when_every_frame_is_lost(cli, tmp_path):
    src = _stack(tmp_path, np.full((2, 24, 24), np.nan, np.float32))
    out = tmp_path / "out.fits"
    r = cli("decouple", "--law", "donlon2018", src, out, "--tile", "16")
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and "stack.fits[SCI]" in line
    assert "no finite, unmasked pixel" in line
    assert not out.exists()

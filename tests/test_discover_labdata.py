"""The lab file format of ``ipc-taichi discover``: reading, writing, the
generator (``simulate-lab``) and one-line errors naming the HDU."""

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.cli import main
from ipc_taichi.discover import make_scene, read_lab, write_lab
from ipc_taichi.discover.labdata import FLAT_LEVELS
from ipc_taichi.errors import IPCInputError
from tests.discover_helpers import write_hdus


def test_round_trip_float32_big_endian(tmp_path, rng):
    scene = rng.uniform(0, 1000, (20, 30)).astype(np.float32)
    measured = scene + 1
    measured[3, 4] = np.nan
    path = str(tmp_path / "lab.fits")
    write_lab(path, [(scene, measured), (scene * 2, measured * 2)], 11.5, law="constant:0.01",
              shot_noise=False, dtype=np.float32)
    lab = read_lab(path)
    assert (lab.readnoise, lab.shot_noise, lab.law) == (11.5, False, "constant:0.01")
    assert [p.extver for p in lab.pairs] == [1, 2]
    s, m = lab.pairs[1].scene, lab.pairs[1].measured
    assert s.dtype == np.float64 and s.dtype.isnative
    np.testing.assert_array_equal(s, scene.astype(np.float64) * 2)
    assert np.isnan(m[3, 4]) and np.isfinite(m).sum() == m.size - 1
    with fits.open(path) as h:  # FITS stores big-endian; the reader made it native
        assert h["SCENE", 1].data.dtype.byteorder == ">"


def test_defaults_shotnois_and_ipclaw(tmp_path):
    a = np.ones((8, 8))
    lab = read_lab(write_hdus(tmp_path / "d.fits", [("SCENE", 1, a), ("MEASURED", 1, a)],
                          READNOIS=10.0))
    assert lab.shot_noise is True and lab.law == "donlon2018"


@pytest.mark.parametrize("case, match", [
    ("no_readnois", r"\[PRIMARY\]: keyword READNOIS"),
    ("bad_law", r"\[PRIMARY\]: IPCLAW 'quadratic:3'"),
    ("shape", r"\[MEASURED,2\]: shape \(8, 9\) differs from .*\[SCENE,2\]"),
    ("unpaired", r"\[SCENE,3\]: unpaired: no MEASURED HDU with EXTVER=3"),
    ("all_nan", r"\[MEASURED,1\]: no finite pixel"),
    ("cube", r"\[SCENE,1\]: expected a 2-D image"),
])
def test_bad_input_names_the_hdu(tmp_path, case, match, capsys):
    a = np.ones((8, 8))
    header = {"READNOIS": 10.0, "IPCLAW": "donlon2018"}
    pairs = [("SCENE", 1, a), ("MEASURED", 1, a), ("SCENE", 2, a), ("MEASURED", 2, a)]
    if case == "no_readnois":
        del header["READNOIS"]
    elif case == "bad_law":
        header["IPCLAW"] = "quadratic:3"
    elif case == "shape":
        pairs[3] = ("MEASURED", 2, np.ones((8, 9)))
    elif case == "unpaired":
        pairs.append(("SCENE", 3, a))
    elif case == "all_nan":
        pairs[1] = ("MEASURED", 1, np.full((8, 8), np.nan))
    elif case == "cube":
        pairs[0] = ("SCENE", 1, np.ones((2, 8, 8)))
    path = write_hdus(tmp_path / "bad.fits", pairs, **header)
    with pytest.raises(IPCInputError, match=match):
        read_lab(path)
    # the command line: exit status 2, one line naming the HDU, no report written
    report = tmp_path / "r.json"
    assert main(["discover", path, "--report", str(report), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("ipc-taichi: error: ")
    assert path in err and not report.exists()


def test_make_scene_has_every_probe(rng):
    scene = make_scene((128, 128), rng)
    background = 60.0 + 90.0 + 50.0  # the background never exceeds this
    for level in FLAT_LEVELS:  # a 10x10 patch at each level
        patch = (scene > level) & (scene < level + background)
        assert patch.sum() >= 100
    from scipy import ndimage

    peaks = (scene == ndimage.maximum_filter(scene, size=3)) & (scene > 1500 + background)
    single = peaks & (ndimage.uniform_filter(scene, 3) * 9 - scene < 8 * background + 1)
    assert single.sum() >= 40  # hot pixels: single-pixel events
    assert (peaks & ~single).sum() >= 20  # point sources (and patches)


def test_simulate_lab_cli_hides_the_truth(tmp_path):
    out = tmp_path / "lab.fits"
    assert main(["simulate-lab", str(out), "--effect", "diagonal_ipc=0.002", "--seed", "3",
                 "--size", "64x80", "--pairs", "3", "--readnoise", "15", "--float32",
                 "--nan-fraction", "0.01"]) == 0
    lab = read_lab(str(out))
    assert len(lab.pairs) == 3 and lab.pairs[0].scene.shape == (64, 80)
    assert lab.readnoise == 15.0 and lab.law == "donlon2018"
    frac = np.mean([np.isnan(p.measured).mean() for p in lab.pairs])
    assert 0.005 < frac < 0.015
    with fits.open(out) as h:
        text = repr(h[0].header) + "".join(repr(x.header) for x in h[1:])
        assert h[1].data.dtype == np.dtype(">f4")
    assert "diagonal" not in text.lower() and "0.002" not in text
    # refuses to overwrite, and rejects an unknown effect
    assert main(["simulate-lab", str(out)]) == 2
    assert main(["simulate-lab", str(tmp_path / "x.fits"), "--effect", "cosmic=1"]) == 2
    assert not (tmp_path / "x.fits").exists()


def test_nan_pixels_are_masked_not_propagated():
    from ipc_taichi.discover.diagnostics import fill_scene, valid_mask

    scene = np.full((20, 20), 100.0)
    scene[8, 9] = np.nan
    measured = np.full((20, 20), 100.0)
    measured[15, 4] = np.nan
    filled = fill_scene(scene)
    assert np.isfinite(filled).all() and filled[8, 9] == 100.0
    valid = valid_mask(scene, measured)
    assert not valid[6:11, 7:12].any() and valid[5, 9] and valid[8, 12]  # 2-px guard
    assert not valid[15, 4] and valid[15, 5] and valid[14, 4]
    assert not valid[:3].any() and not valid[:, -3:].any() and valid[3, 3]

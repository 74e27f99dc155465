"""Flats of frames at one level cannot tell brighter-fatter from non-linear IPC; where
they rise while the hot pixels stay flat, ``calibrate`` names brighter-fatter as the
likely cause and writes the hot pixels' constant, not a rising law (issue 26).

The data are the issue's case in small: charge collected with a brighter-fatter kernel
(tests/independent/rampgen.collect) and coupled at each read by a CONSTANT law
(tests/independent/ipcgen.couple, 0.55 %, anisotropic), each level written as "read k
minus read 0" of several integrations; hot pixels from ipcgen's dark ramp, same law.
"""

import numpy as np
import pytest

from ipc_taichi.calibrate import calibrate
from tests.helpers import write_sci
from tests.independent import ipcgen, rampgen

GAIN = 2.0


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bf_frames")
    rng = np.random.default_rng(61)
    shape, nints, ngroups, level = (192, 192), 6, 6, 50000.0
    rate = np.full(shape, level / ngroups)
    reads = np.empty((nints, ngroups) + shape)
    for i in range(nints):
        charge = np.zeros(shape)
        for g in range(ngroups):
            charge = rampgen.collect(charge, rate, rampgen.BF_KERNEL, 4, rng)
            reads[i, g] = ipcgen.couple(charge, "constant") + rng.normal(0.0, 12.0, shape)
    flats = [write_sci(folder / f"flat_{g}.fits", (reads[:, g] - reads[:, 0]) / GAIN,
                       bunit="DN")
             for g in range(1, ngroups)]
    dark = ipcgen.dark_ramp("constant", shape=(256, 256), ngroups=4, n_hot=300, gain=GAIN,
                            n_junk=0, n_pairs=0, seed=62)
    dark_path = write_sci(folder / "dark.fits", dark["sci"], bunit="DN")
    return dark_path, flats


@pytest.mark.slow  # a 256 x 256 calibration: 10 s
def test_rising_one_level_flats_beside_flat_hot_pixels_name_brighter_fatter(cpu, files):
    dark, flats = files
    result = calibrate([dark], flats, gain=GAIN, read_noise=12.0 * np.sqrt(2.0))
    report, model = result["report"], result["model"]
    bf = report["brighter_fatter"]
    assert bf["measured"] is False and bf.get("likely") is True
    assert "brighter-fatter" in bf["note"] and "flat ramps" in bf["note"]
    assert any("cannot tell brighter-fatter" in n for n in report["notes"])
    # the flats really rise (what a one-level fit would have written as IPC)...
    levels = [r for r in report["flats"]["levels"] if r.get("terms")]
    first, last = levels[0]["terms"]["x"]["value"], levels[-1]["terms"]["x"]["value"]
    assert last > 1.3 * first
    # ...but the law is the hot pixels' constant, flat along the diagonal
    truth = ipcgen.truth_per_axis("constant", 1e4, 0.0)["x"]
    for s in (5000.0, 20000.0, 40000.0):
        got = model.geometry.weight(0, 1) * model.law.alpha(s, s)
        assert got == pytest.approx(truth, rel=0.05), s
    assert report["nonlinear_ipc"]["detected"] is False

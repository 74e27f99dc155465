"""Roman ASDF products through ``ipc-taichi decouple``.

Files are made with roman_datamodels' own fake-data helpers (offline) and
filled with a truth in electrons coupled by the independent NumPy model.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

from ipc_taichi.reference import couple_reference
from tests.helpers import next_to, optional

# the whole file: Roman ASDF products
rdm = pytest.importorskip("roman_datamodels.datamodels", reason=optional("roman_datamodels"))

DO_NOT_USE = 1
GAIN, EXPTIME = 2.0, 139.8


def test_level2_image(cli, tmp_path, rng):
    shape = (40, 36)
    truth_e = rng.uniform(0, 60000, shape)
    rate = (couple_reference(truth_e) / (GAIN * EXPTIME)).astype(np.float32)
    bad = np.zeros(shape, dtype=bool)
    bad.flat[rng.choice(rate.size, 25, replace=False)] = True
    rate[bad] = 1e5  # junk
    model = rdm.ImageModel.create_fake_data(shape=shape)
    model.data = rate
    model.dq = np.where(bad, DO_NOT_USE, 0).astype(np.uint32)
    model.err = rng.uniform(0, 1, shape).astype(model.err.dtype)
    model.var_poisson = rng.uniform(0, 1, shape).astype(model.var_poisson.dtype)
    model.meta.exposure.effective_exposure_time = EXPTIME
    model.meta.instrument.detector = "WFI07"
    src, out = tmp_path / "r0001_cal.asdf", tmp_path / "r0001_ipc.asdf"
    model.save(src)
    # the truth was coupled with the zero edge; a 40x36 cut-out would get
    # 'isolated' by default (no reference border)
    r = cli("decouple", "--law", "donlon2018", "--edge", "zero", src, out, "--gain", GAIN)
    assert r.returncode == 0, r.stderr
    truth = truth_e / (GAIN * EXPTIME)
    with rdm.open(src) as a, rdm.open(out) as b:
        assert type(b).__name__ == "ImageModel"
        assert b.meta.instrument.detector == "WFI07"
        assert b.meta.ipc_taichi["S_IPC"] == "COMPLETE" and b.meta.ipc_taichi["converged"]
        arrays = [k for k in a.keys() if k not in ("meta", "data")]
        assert {"dq", "err", "var_poisson", "amp33", "border_ref_pix_left"} <= set(arrays)
        assert set(b.keys()) == set(a.keys())
        for name in arrays:  # every other array carried through unchanged
            if name in ("err", "var_poisson", "var_rnoise", "var_flat"):  # propagated
                assert np.asarray(b[name]).dtype == np.asarray(a[name]).dtype
                np.testing.assert_array_equal(np.asarray(b[name])[bad], np.asarray(a[name])[bad])
                continue
            np.testing.assert_array_equal(np.asarray(b[name]), np.asarray(a[name]))
        assert b.meta.ipc_taichi["noise"].startswith("linearised decoupler")
        assert not np.array_equal(np.asarray(b.err), np.asarray(a.err))
        got = np.asarray(b.data)
        assert got.dtype == np.float32
        assert (got[bad] == rate[bad]).all()
    far = ~next_to(next_to(bad))  # see tests/test_products.py for the rings
    assert np.abs(got.astype(float) - truth)[far].max() <= 2e-5 * truth.max()
    assert np.abs(rate.astype(float) - truth)[far].max() > 100 * 2e-5 * truth.max()
    # the positional-overwrite rule knows ASDF outputs too
    r = cli("decouple", "--law", "donlon2018", "--edge", "zero", src, out, "--gain", GAIN,
            "--overwrite")
    assert r.returncode == 0, r.stderr


def test_flux_calibrated_refused(cli, tmp_path, rng):
    import asdf.schema

    model = rdm.ImageModel.create_fake_data(shape=(16, 16))
    steps = asdf.schema.load_schema(
        "asdf://stsci.edu/datamodels/roman/schemas/meta/l2_cal_step-2.0.0")["required"]
    model.meta["cal_step"] = dict.fromkeys(steps, "COMPLETE")  # through the flux step
    src = tmp_path / "r0001_cal.asdf"
    model.save(src)
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.asdf", "--gain", GAIN)
    assert r.returncode == 2 and "flux-calibrated" in r.stderr and "r0001_cal.asdf" in r.stderr


def test_raw_resultants_refused(cli, tmp_path):
    raw = rdm.ScienceRawModel.create_fake_data(shape=(3, 16, 16))
    src = tmp_path / "r0001_uncal.asdf"
    raw.save(src)
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.asdf", "--gain", GAIN)
    assert r.returncode == 2 and "subtract it first" in r.stderr and "uncal.asdf" in r.stderr
    assert sorted(os.listdir(tmp_path)) == ["r0001_uncal.asdf"]


def test_ramp_resultants(cli, tmp_path, rng):
    """A RampModel (resultants in DN, bias removed): resultant by resultant,
    pixeldq/groupdq honoured, a reference border given with --refpix."""
    shape = (24, 20)
    rate_e = np.zeros(shape)
    rate_e[4:-4, 4:-4] = rng.uniform(0, 20000, (16, 12))
    truth = np.stack([rate_e * (k + 1) / GAIN for k in range(3)])
    groups = np.zeros((3,) + shape)
    for k in range(3):
        groups[k, 4:-4, 4:-4] = couple_reference(rate_e[4:-4, 4:-4] * (k + 1)) / GAIN
    groups[:, :4] = 3.0  # reference rows hold anything
    model = rdm.RampModel.create_fake_data(shape=(3,) + shape)
    model.data = groups.astype(np.float32)
    model.pixeldq = np.zeros(shape, dtype=np.uint32)
    model.groupdq = np.zeros((3,) + shape, dtype=np.uint8)
    bad = (1, 10, 9)
    model.groupdq[bad] = DO_NOT_USE  # one read of one pixel not trusted
    model.data[bad] = -50.0
    src, out = tmp_path / "ramp.asdf", tmp_path / "ramp_ipc.asdf"
    model.save(src)
    r = cli("decouple", "--law", "donlon2018", src, out, "--gain", GAIN, "--refpix", 4)
    assert r.returncode == 0, r.stderr
    with rdm.open(out) as b:
        got = np.asarray(b.data, dtype=float)
        assert b.meta.cal_step["ipc"] == "COMPLETE"
        assert (got[:, :4] == 3.0).all()
    assert got[bad] == -50.0
    far = np.ones(shape, dtype=bool)
    far[8:13, 7:12] = False  # within two pixels of the flagged one
    for k in range(3):
        err = np.abs(got[k] - truth[k])[4:-4, 4:-4]
        ok = far[4:-4, 4:-4] if k == 1 else slice(None)
        assert err[ok].max() <= 2e-5 * truth[k].max(), k


def test_roman_dq_flags_read_without_importing_the_package():
    """The Roman DQ bits the FITS path uses are roman_datamodels' own, read from
    its dqflags.py alone (the package import takes 2 s of a command line)."""
    dqflags = pytest.importorskip("roman_datamodels.dqflags")
    from ipc_taichi.products import missions

    want = {str(k): int(v) for k, v in dqflags.pixel.__members__.items()}
    assert missions._flag_table("Roman") == want and want["SATURATED"] == 2
    code = ("import sys; from astropy.io import fits; from ipc_taichi.products import missions; "
            "m = missions.recognise(fits.Header({'TELESCOP': 'ROMAN', 'INSTRUME': 'WFI'})); "
            "print(m.name, m.dq_flags['DO_NOT_USE'], 'roman_datamodels' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert run.stdout.split() == ["Roman", str(want["DO_NOT_USE"]), "False"]

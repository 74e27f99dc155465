"""``ipc-taichi decouple IN1 IN2 ... -o OUTDIR`` (Dask local cluster) and ``--tile``."""

import os

import numpy as np
from astropy.io import fits

from ipc_taichi.reference import couple_reference, decouple_reference
from tests.helpers import run_cli


def test_many_files_one_corrupt(tmp_path, rng):
    inputs, truths = [], []
    for k in range(2):
        truth = rng.uniform(0, 60000, (24, 30))
        path = tmp_path / f"frame{k}.fits"
        fits.writeto(path, couple_reference(truth))
        inputs.append(path)
        truths.append(truth)
    bad = tmp_path / "broken.fits"
    bad.write_text("not a fits file")
    out = tmp_path / "out"
    out.mkdir()
    r = run_cli("decouple", inputs[0], bad, inputs[1], "-o", out, "--workers", "2", "--quiet")
    assert r.returncode == 1
    errors = [line for line in r.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "broken.fits" in errors[0]
    assert "1 of 3 files failed" in r.stderr
    assert sorted(os.listdir(out)) == ["frame0_decoupled.fits", "frame1_decoupled.fits"]
    for k, _truth in enumerate(truths):
        got = fits.getdata(out / f"frame{k}_decoupled.fits")
        ref, iterations, _, _ = decouple_reference(fits.getdata(inputs[k]))
        np.testing.assert_allclose(got, ref, rtol=1e-9)
        assert fits.getheader(out / f"frame{k}_decoupled.fits")["IPCITER"] == iterations
    # outputs exist now: without --overwrite every file fails, nothing is replaced
    before = (out / "frame0_decoupled.fits").read_bytes()
    r = run_cli("decouple", inputs[0], inputs[1], "-o", out, "--workers", "2", "--quiet")
    assert r.returncode == 1 and r.stderr.count("exists") == 2
    assert (out / "frame0_decoupled.fits").read_bytes() == before


def test_usage_errors(cli, tmp_path):
    a, b, c = (tmp_path / f"{n}.fits" for n in "abc")
    r = cli("decouple", a, b, c)
    assert r.returncode == 2 and "-o OUTDIR" in r.stderr
    r = cli("decouple", a, "-o", tmp_path / "missing")  # -o makes its directory
    assert r.returncode == 1 and "no such file" in r.stderr and (tmp_path / "missing").is_dir()
    (tmp_path / "afile").write_bytes(b"x")
    r = cli("decouple", a, b, "-o", tmp_path / "afile")
    assert r.returncode == 2 and "not a directory" in r.stderr
    (tmp_path / "d1").mkdir()
    (tmp_path / "d2").mkdir()
    r = cli("decouple", tmp_path / "d1" / "x.fits", tmp_path / "d2" / "x.fits", "-o", tmp_path)
    assert r.returncode == 2 and "both be written" in r.stderr
    r = cli("decouple", a, "-o", tmp_path, "--law", "constant:0.3")
    assert r.returncode == 2 and "too strong" in r.stderr


def test_single_file_tiled(cli, tmp_path, rng):
    truth = rng.uniform(0, 60000, (50, 45))
    src, out = tmp_path / "in.fits", tmp_path / "out.fits"
    fits.writeto(src, couple_reference(truth))
    r = cli("decouple", src, out, "--tile", "16")
    assert r.returncode == 0, r.stderr
    ref, iterations, _, _ = decouple_reference(fits.getdata(src))
    with fits.open(out) as hdul:
        np.testing.assert_allclose(hdul[0].data, ref, rtol=1e-9)
        assert hdul[0].header["IPCITER"] == iterations and hdul[0].header["IPCOP"] == "decouple"


def test_one_worker_per_gpu(tmp_path, rng):
    """``--gpus ID,ID`` runs one worker per GPU id, each with its own
    CUDA_VISIBLE_DEVICES (checked here with fake ids and ``--arch cpu``, which
    the workers take over the CUDA default their environment sets)."""
    inputs = []
    for k in range(2):
        path = tmp_path / f"f{k}.fits"
        fits.writeto(path, couple_reference(rng.uniform(0, 60000, (16, 20))))
        inputs.append(path)
    out = tmp_path / "out"
    out.mkdir()
    r = run_cli("decouple", *inputs, "-o", out, "--gpus", "7,9", "--arch", "cpu", "--quiet")
    assert r.returncode == 0, r.stderr
    for k in range(2):
        ref, _, _, _ = decouple_reference(fits.getdata(inputs[k]))
        np.testing.assert_allclose(fits.getdata(out / f"f{k}_decoupled.fits"), ref, rtol=1e-9)


def test_model_file_many_files_and_tiles(cli, tmp_path, rng):
    """``--model FILE`` reaches every path: many files on Dask, and --tile."""
    from ipc_taichi.model import CouplingModel

    model = tmp_path / "det.json"
    CouplingModel.resolve("constant:0.006", edge="zero").save(model)
    truths = [rng.uniform(0, 30000, (24, 20)) for _ in range(2)]
    inputs = []
    for k, t in enumerate(truths):
        inputs.append(tmp_path / f"in{k}.fits")
        fits.writeto(inputs[-1], couple_reference(t, law="constant:0.006"))
    out = tmp_path / "out"
    r = cli("decouple", *inputs, "-o", out, "--model", model, "--workers", "2", "--quiet")
    assert r.returncode == 0, r.stderr
    for k, t in enumerate(truths):
        got = fits.getdata(out / f"in{k}_decoupled.fits")
        assert np.abs(got - t).max() <= 2e-5 * t.max()
        assert fits.getheader(out / f"in{k}_decoupled.fits")["IPCLAW"] == "constant:0.006"
    tiled = tmp_path / "tiled.fits"
    r = cli("decouple", inputs[0], tiled, "--model", model, "--tile", 8)
    assert r.returncode == 0, r.stderr
    assert np.abs(fits.getdata(tiled) - truths[0]).max() <= 2e-5 * truths[0].max()

"""Noise carried through the products (issue 27 item 4): ERR and VAR_* propagated
through the linearised decoupler by the FITS path (``process_product``, the command
line) and the Step, the method recorded (``IPCNOISE``, HISTORY); checked against a
Monte Carlo of the product's own decoupled SCI on noisy draws (a rate cube, a ramp);
the Step's ERR bit for bit the command line's; ``--keep-noise``, ``couple`` and
``--tile`` leave the arrays as they came and say so. Also warm starts for the groups
of a ramp (issue 28): within the stopping rule's tolerance of solving each group
from scratch, in fewer iterations.
"""

import re
import time

import numpy as np
import pytest
from astropy.io import fits
from stdatamodels.jwst.datamodels import CubeModel, ImageModel, RampModel

import ipc_taichi
from ipc_taichi import iteration, noise
from ipc_taichi.model import CouplingModel
from ipc_taichi.products import process_product
from ipc_taichi.products.jwst_step import IPCTaichiStep
from ipc_taichi.products.noise_arrays import noise_of
from tests.test_noise import SHAPE, _pooled, _scene

MODEL = CouplingModel.resolve("donlon2018", None, "zero")
GAIN, EXPTIME, READ = 2.0, 50.0, 6.0  # e-/DN, s, e- rms
RUN = dict(model=MODEL, gain=GAIN, edge="zero", refpix=0)
STEP = dict(gain=GAIN, law="donlon2018", edge="zero", refpix=0)


def _jwst(model, filename):
    model.meta.filename = filename
    model.meta.telescope = "JWST"
    model.meta.instrument.name, model.meta.instrument.detector = "NIRCAM", "NRCA1"
    model.meta.cal_step.superbias = "COMPLETE"
    return model


def _rate_cube(rng, draws):
    """``draws`` noisy rates (DN/s) of one scene as integrations of a rateints
    product, with ERR, VAR_POISSON, VAR_RNOISE as the pipeline estimates them."""
    s, mask = _scene(rng)
    scale = GAIN * EXPTIME
    shot = rng.poisson(s, size=(draws,) + SHAPE).astype(float)
    y = (np.asarray(ipc_taichi.couple(shot, model=MODEL, mask=mask))
         + rng.normal(0.0, READ, shot.shape)) / scale
    var_poisson = np.asarray(ipc_taichi.couple(s, model=MODEL, mask=mask)) / scale ** 2
    var_rnoise = np.full(SHAPE, READ ** 2 / scale ** 2)
    cube = _jwst(CubeModel(y.shape), "jw_nrca1_rateints.fits")
    cube.data = y.astype(np.float32)
    cube.dq = np.broadcast_to(np.where(mask, 1, 0).astype(np.uint32), y.shape).copy()
    cube.var_poisson = np.broadcast_to(var_poisson, y.shape).astype(np.float32)
    cube.var_rnoise = np.broadcast_to(var_rnoise, y.shape).astype(np.float32)
    cube.err = np.sqrt(cube.var_poisson + cube.var_rnoise).astype(np.float32)
    cube.meta.exposure.integration_time = EXPTIME
    cube.meta.bunit_data = "DN/s"
    return cube, mask


def test_rate_err_within_two_percent_of_monte_carlo(cpu, tmp_path):
    """1000 rate draws, one integration each, through process_product: the
    propagated ERR against the spread of the product's own decoupled SCI."""
    cube, mask = _rate_cube(np.random.default_rng(8), 1000)
    src, dst = tmp_path / "jw_nrca1_rateints.fits", tmp_path / "out.fits"
    cube.save(src)
    process_product(src, dst, "decouple", **RUN)
    with fits.open(dst) as hdul:
        sci, err = hdul["SCI"].data.astype(float), hdul["ERR"].data.astype(float)
        var = {k: hdul[k].data.astype(float) for k in ("VAR_POISSON", "VAR_RNOISE")}
        assert hdul["ERR"].data.dtype == np.dtype(">f4")  # its own dtype and HDU
        assert hdul[0].header["IPCNOISE"] == noise.METHOD
        history = [str(line) for line in hdul[0].header["HISTORY"]]
    assert "noise arrays: " + noise.METHOD in re.sub(r"\s+", " ", " ".join(history))
    mc = sci.var(axis=0, ddof=1)
    predicted = (err ** 2).mean(axis=0)  # one ERR per draw, nearly the same
    ratio, zmax = _pooled(mc, predicted, size=60, draws=sci.shape[0])
    assert np.abs(ratio - 1).max() < 0.02
    assert zmax < 5.5
    np.testing.assert_allclose(err ** 2, var["VAR_POISSON"] + var["VAR_RNOISE"], rtol=2e-6)
    assert np.array_equal(err[:, 24, 24], cube.err[:, 24, 24])  # flagged: as it came
    unchanged, _ = _pooled(mc, (cube.err.astype(float) ** 2).mean(axis=0), size=60,
                           draws=sci.shape[0])
    assert np.abs(unchanged - 1).max() > 0.04  # the ERR that came in is not the answer
    _report("rate", ratio)


def _ramp_file(rng, nints, groups=4):
    """A ramp (DN) of ``nints`` integrations of ``groups`` groups each: cumulative
    shot noise, read noise in every group; ERR, VAR_POISSON and VAR_RNOISE per group."""
    s, mask = _scene(rng)
    per_group = s / groups
    q = np.cumsum(rng.poisson(per_group, size=(nints, groups) + SHAPE), axis=1)
    y = np.asarray(ipc_taichi.couple(q.reshape((-1,) + SHAPE).astype(float), model=MODEL,
                                     mask=mask)).reshape(q.shape)
    y = (y + rng.normal(0.0, READ * 1.3, y.shape)) / GAIN
    means = np.cumsum(np.broadcast_to(per_group, (groups,) + SHAPE), axis=0)
    var_poisson = np.asarray(ipc_taichi.couple(means, model=MODEL, mask=mask)) / GAIN ** 2
    var_rnoise = np.full(var_poisson.shape, (READ * 1.3 / GAIN) ** 2)
    ramp = _jwst(RampModel(data=y.astype(np.float32),
                           pixeldq=np.where(mask, 1, 0).astype(np.uint32),
                           groupdq=np.zeros(y.shape, np.uint8)), "jw_nrca1_ramp.fits")
    ramp.meta.bunit_data = "DN"
    variances = {"VAR_POISSON": np.broadcast_to(var_poisson, y.shape).astype(np.float32),
                 "VAR_RNOISE": np.broadcast_to(var_rnoise, y.shape).astype(np.float32)}
    ramp.err = np.sqrt(variances["VAR_POISSON"] + variances["VAR_RNOISE"])
    return ramp, variances


def _save_with(ramp, variances, path):
    """The ramp's file with ERR and VAR_* HDUs (a RampModel carries none)."""
    ramp.save(path)
    with fits.open(path, mode="append") as hdul:
        for name, value in dict(ERR=np.asarray(ramp.err), **variances).items():
            hdul.append(fits.ImageHDU(value, name=name))


def test_ramp_err_within_two_percent_of_monte_carlo(cpu, tmp_path):
    """250 integrations of 4 groups through process_product (warm starts on): each
    group's propagated ERR against the spread of its decoupled SCI."""
    ramp, variances = _ramp_file(np.random.default_rng(9), 250)
    src, dst = tmp_path / "jw_nrca1_ramp.fits", tmp_path / "out.fits"
    _save_with(ramp, variances, src)
    process_product(src, dst, "decouple", warm_start=True, **RUN)
    with fits.open(dst) as hdul:
        sci, err = hdul["SCI"].data.astype(float), hdul["ERR"].data.astype(float)
        assert hdul[0].header["IPCNOISE"] == noise.METHOD
    ratios = []
    for k in range(sci.shape[1]):
        ratio, zmax = _pooled(sci[:, k].var(axis=0, ddof=1), (err[:, k] ** 2).mean(axis=0),
                              size=60, draws=sci.shape[0])
        assert np.abs(ratio - 1).max() < 0.02, k
        assert zmax < 5.5
        ratios.append(ratio)
    _report("ramp", np.concatenate(ratios))


def _report(what, ratio):
    print(f"\n{what}: pooled sigma_MC / ERR in [{ratio.min():.4f}, {ratio.max():.4f}]")


def _step_and_cli(cli, model, src, tmp_path):
    model.save(src)
    out = tmp_path / "cli.fits"
    r = cli("decouple", src, out, "--law", "donlon2018", "--gain", GAIN, "--edge", "zero",
            "--refpix", 0)
    assert r.returncode == 0, r.stderr
    result = IPCTaichiStep.call(str(src), **STEP)
    with fits.open(out) as hdul:
        return result, {h.name: (h.data.copy() if h.data is not None else None, h.header.copy())
                        for h in hdul if h.name in ("PRIMARY", "SCI", "ERR", "VAR_POISSON",
                                                    "VAR_RNOISE")}


@pytest.mark.parametrize("kind", ["rate", "rateints"])
def test_step_err_is_the_clis_bit_for_bit(cpu, cli, tmp_path, kind):
    """(A RampModel carries no err: the Step has none to propagate on a ramp.)"""
    model, _ = _rate_cube(np.random.default_rng(11), 3)
    if kind == "rate":
        cube, model = model, _jwst(ImageModel(SHAPE), "jw_nrca1_rate.fits")
        for name in ("data", "dq", "err", "var_poisson", "var_rnoise"):
            setattr(model, name, getattr(cube, name)[0])
        model.meta.exposure.integration_time = EXPTIME
        model.meta.bunit_data = "DN/s"
    names = ("ERR", "VAR_POISSON", "VAR_RNOISE")
    result, hdul = _step_and_cli(cli, model, tmp_path / f"jw_nrca1_{kind}.fits", tmp_path)
    assert np.array_equal(np.asarray(result.data), hdul["SCI"][0])
    for name in names:
        got, came = np.asarray(getattr(result, name.lower())), hdul[name][0]
        assert got.dtype.kind == "f" and got.dtype.itemsize == 4, name  # float32
        assert np.array_equal(got, came), name
        assert not np.array_equal(got, getattr(model, name.lower()))  # changed
    assert hdul["PRIMARY"][1]["IPCNOISE"] == noise.METHOD
    assert result.extra_fits.PRIMARY.header  # the keywords travel with the model
    cards = {c[0]: c[1] for c in result.extra_fits.PRIMARY.header}
    assert cards["IPCNOISE"] == noise.METHOD


def _small_rate(tmp_path):
    cube, _ = _rate_cube(np.random.default_rng(12), 2)
    src = tmp_path / "jw_nrca1_rateints.fits"
    cube.save(src)
    return cube, src


def _left_as_they_came(src, dst):
    with fits.open(src) as a, fits.open(dst) as b:
        for name in ("ERR", "VAR_POISSON", "VAR_RNOISE"):
            assert np.array_equal(a[name].data, b[name].data), name
        return b[0].header["IPCNOISE"], [str(h) for h in b[0].header["HISTORY"]]


def test_keep_noise_leaves_the_arrays(cpu, cli, tmp_path):
    _, src = _small_rate(tmp_path)
    dst = tmp_path / "kept.fits"
    r = cli("decouple", src, dst, "--law", "donlon2018", "--gain", GAIN, "--keep-noise")
    assert r.returncode == 0, r.stderr
    text, history = _left_as_they_came(src, dst)
    assert text == "unchanged (--keep-noise): ERR, VAR_POISSON, VAR_RNOISE"
    assert "noise arrays: unchanged (--keep-noise): ERR, VAR_POISSON, VAR_RNOISE" in \
        re.sub(r"\s+", " ", " ".join(history))


def test_couple_leaves_the_arrays_and_says_so(cpu, tmp_path):
    _, src = _small_rate(tmp_path)
    dst = tmp_path / "coupled.fits"
    process_product(src, dst, "couple", **RUN)
    text, _ = _left_as_they_came(src, dst)
    assert text == "unchanged (couple): ERR, VAR_POISSON, VAR_RNOISE"


def test_tile_leaves_the_arrays_and_says_so_in_one_line(cpu, tmp_path):
    _, src = _small_rate(tmp_path)
    dst = tmp_path / "tiled.fits"
    with pytest.warns(UserWarning) as said:
        process_product(src, dst, "decouple", tile=32, **RUN)
    lines = [str(w.message) for w in said if "left unchanged" in str(w.message)]
    assert lines == [f"{src}[ERR]: ERR, VAR_POISSON, VAR_RNOISE left unchanged with --tile "
                     "(the noise is propagated on whole frames); run without --tile to "
                     "propagate it"]
    text, _ = _left_as_they_came(src, dst)
    assert text == "unchanged (--tile): ERR, VAR_POISSON, VAR_RNOISE"


def test_noise_of_without_arrays():
    from ipc_taichi.products.options import ProductOptions

    assert noise_of("decouple", ProductOptions(), [], "x.fits") == (
        False, "none: no ERR or VAR_* array")


def test_warm_starts_on_a_ramp_within_the_tolerance(cpu, tmp_path):
    """A ramp (10 integrations of 8 groups, 48x48) through process_product with and
    without warm starts: the largest difference within the stopping rule's tolerance
    (``tol * max|S|``), in fewer iterations."""
    rng = np.random.default_rng(13)
    s, _ = _scene(rng)
    s = s * 1.5
    q = np.cumsum(rng.poisson(s / 8, size=(10, 8) + SHAPE), axis=1).astype(float)
    y = np.asarray(ipc_taichi.couple(q.reshape((-1,) + SHAPE), model=MODEL)).reshape(q.shape)
    ramp = _jwst(RampModel(data=(y / GAIN).astype(np.float64)), "jw_nrca1_ramp.fits")
    ramp.meta.bunit_data = "DN"
    src = tmp_path / "jw_nrca1_ramp.fits"
    ramp.save(src)
    out, seconds, iterations = {}, {}, {}
    for warm in (False, True, False, True):  # twice each: the second timing counts
        dst = tmp_path / f"warm{warm}.fits"
        t0 = time.perf_counter()
        summary = process_product(src, dst, "decouple", warm_start=warm, overwrite=True,
                                  **RUN)
        seconds[warm] = time.perf_counter() - t0
        iterations[warm] = sum(i.iterations for i in summary["infos"])
        assert summary["converged"]
        out[warm] = fits.getdata(dst, "SCI").astype(float) * GAIN  # electrons
    tol = iteration.TOL  # the default stopping rule, used by both runs
    worst = max(np.abs(out[True][i, g] - out[False][i, g]).max()
                / np.abs(out[False][i, g]).max() for i in range(10) for g in range(8))
    assert worst <= tol
    assert iterations[True] < 0.8 * iterations[False]
    print(f"\nwarm starts: {iterations[False]} -> {iterations[True]} iterations, "
          f"{seconds[False]:.2f} s -> {seconds[True]:.2f} s, max |warm - cold| / max|S| = "
          f"{worst:.2e} (tol {tol:g})")

"""Calibrate measures the IPC map across the detector (issue 35, items 3 and 6).

The data come from tests/independent/mapgen.py (written without the project's
code): a constant 0.60 % law times a hidden map (a +-12 % gradient across x
and a disc where IPC is 40 % weaker)."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.calibrate import calibrate, hotpixels, maps
from ipc_taichi.geometry import Geometry
from ipc_taichi.laws import get_law
from ipc_taichi.model import CouplingModel
from ipc_taichi.reference import decouple_reference
from tests.independent import mapgen


def test_generator_moves_alpha_times_the_map_and_conserves_charge():
    shape = (40, 60)
    s = np.zeros(shape)
    s[20, 10] = s[10, 45] = 1.0e4
    out = mapgen.couple(s)
    assert out.sum() == pytest.approx(s.sum(), rel=1e-12)  # far from the edge
    for y, x in ((20, 10), (10, 45)):
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            g = mapgen.map_factor(y + dy / 2, x + dx / 2, shape)
            assert out[y + dy, x + dx] == pytest.approx(1e4 * mapgen.ALPHA * g, rel=1e-12)
    k = mapgen.truth_kernels(shape)
    assert k[1, 2, 20, 10] == pytest.approx(out[20, 11] / 1e4, rel=1e-12)
    assert mapgen.in_disc(20, 20, shape) and not mapgen.in_disc(5, 55, shape)


def test_noise_sums_give_the_covariance_of_each_block():
    rng = np.random.default_rng(3)
    img = rng.normal(size=(32, 32))
    img[:, 1:] += 0.3 * img[:, :-1]
    sums = maps.NoiseSums(img.shape)
    sums.add(img, 0)
    cov = sums.covariance(16)
    block = img[:16, 16:32]
    right = img[:16, 17:33] if img.shape[1] > 32 else img[:16, 17:32]
    direct = np.mean(block[:, :right.shape[1]] * right)
    # the block sum holds the products whose left pixel is in the block (16 x 16, the
    # last column pairing with nothing at the frame's edge)
    assert cov[(0, 1)][0][0, 1] == pytest.approx(direct, rel=1e-12)
    assert cov[(0, 0)][0][1, 0] == pytest.approx(np.mean(img[16:, :16] ** 2), rel=1e-12)


def _factors(truth, rng, n=2000, error=0.05, shape=(128, 128)):
    y = rng.integers(0, shape[0], n)
    x = rng.integers(0, shape[1], n)
    value = truth(y, x) + rng.normal(0.0, error, n)
    e = np.full(n, error)
    return {"y": y, "x": x, "pixel": y * shape[1] + x, (0, 1): (value, e), (1, 0): (value, e)}


def test_superpixel_map_recovers_a_map_and_keeps_noise_near_one():
    rng = np.random.default_rng(4)
    shape = (128, 128)
    gradient = lambda y, x: 1.0 + 0.2 * (x / 127.0 - 0.5)  # noqa: E731
    got = maps.superpixel_map(16, shape, factors=_factors(gradient, rng))
    centres = (np.arange(8) + 0.5) * 16 - 0.5
    value, error = got[(0, 1)]
    pull = (value - gradient(0, centres[None, :])) / error
    assert np.abs(pull).max() < 4.5 and np.median(error) < 0.03
    flat = maps.superpixel_map(16, shape, factors=_factors(lambda y, x: np.ones(y.shape), rng))
    assert np.abs(flat[(0, 1)][0] - 1).max() < 0.02  # shrunk: noise is not a map


def test_hot_pixel_factors_see_the_local_map():
    shape = (128, 128)
    ramp = mapgen.dark_ramp(shape, ngroups=3, n_hot=150, read_noise=3.0, seed=5)
    frames = ramp["sci"][0].astype(float) * 2.0
    pos = hotpixels.find_hot_pixels(frames[-1])
    ev = hotpixels.measure_events(frames, pos)
    law, geometry = get_law(f"constant:{mapgen.ALPHA}"), Geometry.terms()
    f = maps.hot_pixel_factors(ev, shape[1], law, geometry, 3.0)
    truth = mapgen.map_factor(f["y"], f["x"], shape)
    value, error = f[(0, 1)]
    bright = error < 0.05
    assert bright.sum() > 30
    assert np.median(np.abs(value - truth)[bright] / error[bright]) < 1.5
    assert np.mean(value[bright] - truth[bright]) == pytest.approx(0.0, abs=0.02)


def _regions(frame, shape):
    """Hot-pixel nearest-neighbour residual per region: the disc, and the thirds
    of x outside it (value, error, n)."""
    pos = hotpixels.find_hot_pixels(frame)
    ev = hotpixels.measure_events(frame, pos)
    r = hotpixels.nn_fraction(ev)
    y, x = pos[ev["event"]].T
    ok = ev["signal"] > 3000
    disc = mapgen.in_disc(y, x, shape)
    third = np.minimum(3 * x // shape[1], 2)
    out = {"disc": disc & ok}
    out.update({f"third{k}": ~disc & (third == k) & ok for k in range(3)})
    return {k: (r[s].mean(), r[s].std() / np.sqrt(s.sum()), int(s.sum())) for k, s in out.items()}


@pytest.fixture(scope="module")
def hidden_map(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hidden_map")
    files = mapgen.write_map_set(str(folder), mapped=True)
    out = calibrate([files["dark"]], [files["flats"]], output=str(folder / "model.json"))
    return files, out


@pytest.mark.slow
def test_calibrate_measures_the_hidden_map_and_a_held_out_dark_is_corrected(hidden_map):
    files, out = hidden_map
    from astropy.io import fits

    section = out["report"]["bond_map"]
    assert section["written"] and out["model"].bonds is not None
    assert section["test"]["z"] >= maps.MAP_MARGIN
    loaded = CouplingModel.load(out["output"])
    assert loaded.bonds == out["model"].bonds
    shape = files["shape"]
    frame = fits.getdata(files["held_out"], "SCI")[0, -1].astype(float) * files["gain"]
    before = _regions(frame, shape)
    assert before["disc"][0] > 0.002  # the disc's coupling is there to be corrected
    uniform = CouplingModel.resolve(out["model"].law, out["model"].geometry, "zero")
    flat_law = _regions(decouple_reference(frame, model=uniform)[0], shape)
    assert flat_law["disc"][0] < -0.0015  # the uniform law over-corrects the weak disc
    reference = decouple_reference(frame, model=loaded)[0]
    engine = np.asarray(ipc_taichi.decouple(frame, model=loaded))
    assert np.max(np.abs(engine - reference)) < 1e-6 * np.max(np.abs(reference))
    after = _regions(engine, shape)
    assert after["disc"][2] > 50
    assert abs(after["disc"][0]) < 0.0007
    for k in ("third0", "third1", "third2"):
        assert abs(after[k][0]) < 0.00035, (k, after[k])


@pytest.mark.slow
def test_calibrate_writes_no_map_where_there_is_none(tmp_path):
    files = mapgen.write_map_set(str(tmp_path), mapped=False, seed=7)
    out = calibrate([files["dark"]], [files["flats"]])
    section = out["report"]["bond_map"]
    assert not section["written"] and out["model"].bonds is None
    assert section["test"]["z"] < maps.MAP_MARGIN
    m = out["model"]
    assert m == CouplingModel.resolve(m.law, m.geometry, "zero")  # the uniform model

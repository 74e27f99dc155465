"""The Taichi engine with a bond map (issue 35): every layout (``lanes``,
``sweep``, ``pixel``: the CUDA layout, run on the CPU arch) against the NumPy
reference (1e-10 in f64, to rounding in f32), both edges, bad pixels and a
mask, a reach-2 anisotropic geometry, a parametric, a table and a constant
law; charge conserved with ``isolated``; stacks; tiles; awkward lanes widths.
Without a map the kernels are the map-less ones, bit for bit
(``tests/test_kernel_identity.py``, ``tests/test_lanes_layout.py``)."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.bondmap import BondMap
from ipc_taichi.errors import IPCInputError
from ipc_taichi.model import CouplingModel
from ipc_taichi.reference import couple_reference, decouple_reference
from ipc_taichi.tiling import decouple_tiled
from tests import kernel_reference

LAYOUTS = ("lanes", "sweep", "pixel")
FULL = ipc_taichi.Geometry.terms(horizontal=1.0, vertical=0.7, diagonal=0.2, second=0.05)
TABLE = dict(kernel_reference.cases())["table_nearest"]["law"]


def mapped(law, geometry, edge, shape, seed=0, lo=0.4, hi=1.6):
    """A model whose bonds vary from ``lo`` to ``hi`` times the law, at random."""
    rng = np.random.default_rng(seed)
    uniform = CouplingModel.resolve(law, geometry, edge)
    n = len(uniform.geometry.half_stencil())
    bonds = BondMap.full(uniform.geometry, rng.uniform(lo, hi, (n,) + tuple(shape)))
    return CouplingModel.resolve(law, geometry, edge, bonds=bonds)


def frame(shape, seed=1, bad=True):
    """Signals over the full range, one NaN pixel, and a mask of two pixels."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0, 60000, shape)
    mask = np.zeros(shape, bool)
    if bad:
        s[shape[0] // 2, 0] = np.nan
        mask[1, shape[1] - 1] = mask[shape[0] - 1, shape[1] // 2] = True
    return s, mask


def reference(s, mask, model):
    """The reference's couple and decouple of ``s`` with ``mask`` (masked pixels
    as the engine treats them: no coupling, their input value kept)."""
    held = np.where(mask, np.nan, s)
    m = couple_reference(held, model=model)
    m = np.where(mask, s, m)
    d = decouple_reference(np.where(mask, np.nan, m), model=model)
    return m, np.where(mask, m, d[0]), d[1]


def check(model, s, mask, layout, precision="f64"):
    try:
        ipc_taichi.init("cpu", precision)
        m = np.asarray(ipc_taichi.couple(s, model=model, layout=layout, mask=mask))
        want_m, want_d, iterations = reference(s, mask, model)
        d, info = ipc_taichi.decouple(want_m, model=model, layout=layout, mask=mask,
                                      full_output=True)
    finally:
        ipc_taichi.init("cpu", "f64")
    d = np.asarray(d)
    scale = np.nanmax(np.abs(s))
    tol = 1e-10 if precision == "f64" else 5e-6
    assert np.array_equal(np.isnan(m), np.isnan(want_m))
    assert np.nanmax(np.abs(m - want_m)) <= tol * scale
    assert np.nanmax(np.abs(d - want_d)) <= (tol if precision == "f64" else 2e-5) * scale
    if precision == "f64":
        assert info.iterations == iterations
    # the map matters: uniform coupling is far from it
    uniform = couple_reference(np.where(mask, np.nan, s), model=model.uniform())
    assert np.nanmax(np.abs(np.where(mask, s, uniform) - want_m)) > 100 * tol * scale


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_every_layout_nearest_parametric(cpu, layout, precision):
    shape = (23, 19)
    s, mask = frame(shape)
    for edge, bad in (("zero", True), ("isolated", False)):
        model = mapped("donlon2018", None, edge, shape)
        check(model, s, mask if bad else np.zeros(shape, bool), layout, precision)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_every_layout_reach_two_table_law(cpu, layout):
    shape = (17, 21)
    s, mask = frame(shape, seed=2)
    check(mapped(TABLE, FULL, "zero", shape, seed=3), s, mask, layout)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_every_layout_constant_law(cpu, layout):
    """A constant law has no carried alpha (and, uniform, pre-combined
    coefficients): with a map each pair's own factor is read."""
    shape = (14, 18)
    s, mask = frame(shape, seed=4, bad=False)
    check(mapped("constant:0.012", None, "zero", shape, seed=5), s, mask, layout)
    check(mapped("constant:0.012", None, "isolated", shape, seed=5), s, mask, layout)


def test_isolated_conserves_charge_and_stacks_use_one_map(cpu):
    shape = (20, 26)
    model = mapped("donlon2018", FULL, "isolated", shape, seed=6, lo=0.0, hi=2.0)
    rng = np.random.default_rng(7)
    stack = rng.uniform(0, 60000, (3,) + shape)
    for layout in LAYOUTS:
        m = np.asarray(ipc_taichi.couple(stack, model=model, layout=layout))
        assert np.allclose(m.sum(axis=(1, 2)), stack.sum(axis=(1, 2)), rtol=1e-13, atol=0)
        for k in range(3):
            np.testing.assert_array_equal(
                m[k], np.asarray(ipc_taichi.couple(stack[k], model=model, layout=layout)))
            assert np.abs(m[k] - couple_reference(stack[k], model=model)).max() <= 1e-10 * 6e4


@pytest.mark.slow  # a lanes kernel compiled per width (minutes in all on 2 cores)
@pytest.mark.parametrize("width", [1, 5, 17, 33])
def test_lanes_at_awkward_widths(cpu, width):
    """Rows narrower than, ending inside and crossing one vector: ``lanes``
    is ``sweep`` bit for bit with a map too, and the reference to 1e-10."""
    shape = (9, width)
    s, _ = frame(shape, seed=width, bad=False)
    s[4, width // 2] = np.nan
    for model in (mapped("donlon2018", None, "zero", shape, seed=width),
                  mapped(TABLE, FULL, "isolated", shape, seed=width)):
        got = {layout: np.asarray(ipc_taichi.couple(s, model=model, layout=layout))
               for layout in ("lanes", "sweep")}
        assert np.array_equal(got["lanes"], got["sweep"], equal_nan=True)
        want = couple_reference(s, model=model)
        assert np.nanmax(np.abs(got["lanes"] - want)) <= 1e-10 * 6e4
        dec = {layout: np.asarray(ipc_taichi.decouple(want, model=model, layout=layout))
               for layout in ("lanes", "sweep")}
        assert np.array_equal(dec["lanes"], dec["sweep"], equal_nan=True)
        assert np.nanmax(np.abs(dec["lanes"] - decouple_reference(want, model=model)[0])) \
            <= 1e-10 * 6e4


def test_tiled_equals_whole_frame_with_a_map(cpu):
    from ipc_taichi.datasets import star_field

    truth = star_field(90, seed=3, n_per_mpix=20000)
    truth[30:33, 40:46] = np.nan
    model = mapped("donlon2018", None, "zero", truth.shape, seed=8)
    measured = couple_reference(truth, model=model)
    whole, info = ipc_taichi.decouple(measured, model=model, full_output=True)
    for tile in (13, (40, 64)):
        tiled, tinfo = decouple_tiled(measured, tile, model=model, full_output=True)
        assert tinfo.iterations == info.iterations
        assert np.array_equal(np.isnan(tiled), np.isnan(whole))
        assert np.nanmax(np.abs(tiled - whole)) <= 1e-12 * np.nanmax(whole)
    # the decoupled frame is the truth, and the map matters here
    assert np.nanmax(np.abs(whole - truth)) < 0.05
    assert np.nanmax(np.abs(whole - ipc_taichi.decouple(measured))) > 1.0


def test_map_of_another_shape_is_refused_in_one_line(cpu):
    model = mapped("donlon2018", None, "zero", (10, 12))
    for call in (lambda: ipc_taichi.couple(np.ones((12, 10)), model=model),
                 lambda: ipc_taichi.decouple(np.ones((3, 10, 13)), model=model),
                 lambda: decouple_tiled(np.ones((11, 12)), 4, model=model)):
        with pytest.raises(IPCInputError, match="bond map is 10x12") as err:
            call()
        assert "\n" not in str(err.value)


def test_without_a_map_the_map_less_kernel_runs(cpu):
    """A map of ones is dropped (the uniform model), so the step is the
    map-less one; a model with a map builds the ``mapped`` variant."""
    from ipc_taichi import engine

    shape = (8, 9)
    s, _ = frame(shape, bad=False)
    ones = CouplingModel.resolve(bonds=BondMap.full(ipc_taichi.Geometry.nearest(),
                                                    np.ones(shape)))
    assert ones.bonds is None
    with engine.step_kernels_built() as built:
        plain = ipc_taichi.couple(s, model=ones)
        ipc_taichi.couple(s, model=mapped("donlon2018", None, "zero", shape))
    assert [c.mapped for c in built] == [False, True]
    np.testing.assert_array_equal(plain, ipc_taichi.couple(s))


def test_product_path_takes_the_map_of_its_science_region(cpu, tmp_path):
    from astropy.io import fits

    from ipc_taichi.products import decouple_file

    shape = (20, 24)
    truth = np.random.default_rng(9).uniform(0, 60000, shape)
    model = mapped("donlon2018", None, "zero", shape, seed=9)
    src, dst = tmp_path / "in.fits", tmp_path / "out.fits"
    fits.writeto(src, couple_reference(truth, model=model), fits.Header({"BUNIT": "electron"}))
    with pytest.raises(IPCInputError, match=r"in\.fits\[0\]: the model's bond map is 10x12 "
                                            r"\(ny x nx\), the science region 20x24"):
        decouple_file(str(src), str(dst), model=mapped("donlon2018", None, "zero", (10, 12)))
    assert not dst.exists()
    decouple_file(str(src), str(dst), model=model)
    got = fits.getdata(dst)
    np.testing.assert_allclose(got, ipc_taichi.decouple(fits.getdata(src), model=model),
                               rtol=0, atol=1e-9)
    assert np.abs(got - truth).max() < 0.05


@pytest.mark.parametrize("layout", ["sweep", "pixel"])
def test_device_buffer_path_with_a_map(cpu, layout):
    """The CUDA engine's code path (Taichi ndarrays, 2-D frames, the map 3-D
    ``[k, y, x]``), run on the CPU arch."""
    from ipc_taichi import engine

    shape = (15, 22)
    s, mask = frame(shape, seed=12)
    with engine.device_buffers():
        check(mapped(TABLE, FULL, "zero", shape, seed=13), s, mask, layout)
        check(mapped("donlon2018", None, "isolated", shape, seed=13), s, np.zeros(shape, bool),
              layout)


@pytest.mark.gpu
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_cuda_with_a_map(precision):
    shape = (300, 257)
    s, mask = frame(shape, seed=14)
    for model in (mapped("donlon2018", None, "zero", shape, seed=15),
                  mapped(TABLE, FULL, "isolated", shape, seed=15)):
        try:
            ipc_taichi.init("cuda", precision)
            m = np.asarray(ipc_taichi.couple(s, model=model, mask=mask))
            want_m, want_d, _ = reference(s, mask, model)
            d = np.asarray(ipc_taichi.decouple(want_m, model=model, mask=mask))
        finally:
            ipc_taichi.init("cpu", "f64")
        tol = 1e-10 if precision == "f64" else 2e-5
        assert np.nanmax(np.abs(m - want_m)) <= tol * 6e4
        assert np.nanmax(np.abs(d - want_d)) <= tol * 6e4

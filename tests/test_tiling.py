"""Exact tiling: tile by tile (with a halo of iterations * reach) == whole frame."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.datasets import star_field
from ipc_taichi.model import CouplingModel
from ipc_taichi.reference import couple_reference, decouple_reference
from ipc_taichi.tiling import decouple_tiled, halo_for, tile_maxima, tiles


@pytest.fixture(scope="module")
def star_frame():
    # dense stars: many cross the seams of every tile size below; a NaN block too
    truth = star_field(150, seed=3, n_per_mpix=20000)
    truth[30:34, 60:70] = np.nan
    return truth


@pytest.mark.parametrize("tile", [7, 40, (33, 64), 1000])
def test_tiled_equals_whole_frame_with_stopping_rule(cpu, star_frame, tile):
    measured = ipc_taichi.couple(star_frame)
    whole, info = ipc_taichi.decouple(measured, full_output=True)
    tiled, tinfo = decouple_tiled(measured, tile, full_output=True)
    assert tinfo.iterations == info.iterations and tinfo.converged == info.converged
    np.testing.assert_allclose(tinfo.max_delta, info.max_delta, rtol=1e-12)
    assert np.array_equal(np.isnan(tiled), np.isnan(whole))
    scale = np.nanmax(np.abs(whole))
    assert np.nanmax(np.abs(tiled - whole)) <= 1e-12 * scale
    assert np.nanmax(np.abs(tiled - star_frame)) < 0.05


def test_halo_matters(cpu, star_frame):
    """Without the halo the seams are wrong: the test above can fail."""
    measured = np.nan_to_num(ipc_taichi.couple(star_frame))
    whole = ipc_taichi.decouple(measured, max_iter=4, tol=0)
    model = CouplingModel.resolve("donlon2018")
    core = (slice(40, 80), slice(40, 80))
    exact, _, _ = tile_maxima(lambda w: measured[w], measured.shape, core, 4, 4, model)
    short, _, _ = tile_maxima(lambda w: measured[w], measured.shape, core, 2, 4, model)
    assert np.abs(exact - whole[core]).max() <= 1e-12 * whole.max()
    assert np.abs(short - whole[core]).max() > 1e-3


def test_other_geometry_edge_fixed_count(cpu, rng):
    g = ipc_taichi.Geometry.terms(horizontal=1.0, vertical=0.9, diagonal=0.1, second=0.05)
    truth = rng.uniform(0, 60000, (61, 47))
    measured = ipc_taichi.couple(truth, geometry=g, edge="isolated")
    whole = ipc_taichi.decouple(measured, geometry=g, edge="isolated", max_iter=5, tol=0)
    tiled = decouple_tiled(measured, 16, geometry=g, edge="isolated", max_iter=5, tol=0)
    assert halo_for(5, g) == 10
    assert np.abs(tiled - whole).max() <= 1e-12 * whole.max()


def test_tiles_cover_frame():
    cover = np.zeros((10, 7), int)
    for ys, xs in tiles(cover.shape, (4, 3)):
        cover[ys, xs] += 1
    assert (cover == 1).all()
    with pytest.raises(ipc_taichi.IPCInputError, match="tile size"):
        list(tiles((4, 4), 0))


def test_masked_and_all_nan_tiles_equal_whole_frame(cpu, star_frame):
    """mask= and an all-NaN tile core go through tiling exactly as through the
    whole-frame decoupler, with no warning (warnings are errors here)."""
    measured = np.nan_to_num(ipc_taichi.couple(star_frame))
    measured[:16, :16] = np.nan
    mask = np.zeros(measured.shape, dtype=bool)
    mask[50:53, 70] = True
    measured[50:53, 70] = 1e9  # junk under the mask must not leak
    whole = ipc_taichi.decouple(measured, mask=mask)
    tiled = decouple_tiled(measured, tile=16, mask=mask)
    assert np.array_equal(np.isnan(whole), np.isnan(tiled))
    assert np.nanmax(np.abs(tiled - whole)) <= 1e-12 * np.nanmax(whole)
    assert np.all(tiled[50:53, 70] == 1e9)


@pytest.mark.parametrize("edge", ["zero", "isolated"])
def test_cuda_layout_runs_on_cpu_and_agrees(cpu, star_frame, edge):
    """The per-pixel layout CUDA uses, run on the CPU, agrees with the CPU sweep
    and the NumPy reference (so the GPU path is tested without a GPU)."""
    g = ipc_taichi.Geometry.terms(horizontal=1.0, vertical=0.8, diagonal=0.1, second=0.02)
    truth = star_frame[:70, :90]
    ref = couple_reference(truth, geometry=g, edge=edge)
    for layout in ("pixel", "sweep", "lanes"):
        got = ipc_taichi.couple(truth, geometry=g, edge=edge, layout=layout)
        assert np.nanmax(np.abs(got - ref)) <= 1e-10 * np.nanmax(ref)
        signal = ipc_taichi.decouple(ref, geometry=g, edge=edge, max_iter=5, tol=0,
                                     layout=layout)
        expected = decouple_reference(ref, geometry=g, edge=edge, max_iter=5, tol=0)[0]
        assert np.nanmax(np.abs(signal - expected)) <= 1e-10 * np.nanmax(ref)

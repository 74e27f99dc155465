"""CUDA path: the same kernels, arch chosen at init. Runs only where CUDA exists."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.reference import couple_reference

pytestmark = pytest.mark.gpu


@pytest.mark.parametrize("precision, rtol", [("f64", 1e-10), ("f32", 1e-5)])
def test_cuda_matches_reference(precision, rtol):
    rng = np.random.default_rng(1)
    truth = rng.uniform(0, 60000, (300, 257))
    measured = ipc_taichi.couple(truth, arch="cuda", precision=precision)
    assert ipc_taichi.runtime.current().arch == "cuda"
    np.testing.assert_allclose(measured, couple_reference(truth), rtol=rtol, atol=rtol * 6e4)
    signal, info = ipc_taichi.decouple(measured, arch="cuda", precision=precision,
                                       full_output=True)
    assert info.converged
    assert np.abs(signal - truth).max() < (0.05 if precision == "f64" else 0.05 + 6e4 * 1e-6)


def test_cuda_tiled_and_f32_exp():
    """On CUDA: tiled == whole frame, and the f32 path stays accurate."""
    from ipc_taichi.tiling import decouple_tiled

    rng = np.random.default_rng(2)
    truth = rng.uniform(0, 60000, (257, 300))
    measured = couple_reference(truth)
    whole = ipc_taichi.decouple(measured, arch="cuda", precision="f64")
    tiled = decouple_tiled(measured, 64, arch="cuda", precision="f64")
    assert np.abs(tiled - whole).max() <= 1e-12 * whole.max()
    fast = ipc_taichi.decouple(measured, arch="cuda", precision="f32")
    assert np.abs(fast - truth).max() < 0.05 + 6e4 * 1e-6

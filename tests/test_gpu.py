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

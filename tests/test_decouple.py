import warnings

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import ConvergenceWarning, DivergenceError, IPCInputError, LawError
from ipc_taichi.engine import KernelConfig, get_step_kernel


def test_random_frame_recovered(cpu):
    truth = np.random.default_rng(7).uniform(0, 60000, (256, 256))
    measured = ipc_taichi.couple(truth)
    coupled_error = np.abs(measured - truth)
    assert coupled_error.mean() > 400  # IPC is a big effect on this frame
    signal, info = ipc_taichi.decouple(measured, full_output=True)
    assert info.converged and info.iterations <= 6
    assert np.abs(signal - truth).max() < 0.05


@pytest.mark.parametrize("law", ["donlon2018_printed", "constant:0.08",
                                 "parametric:0.01,5000,0.005,30000,0.02"])
def test_other_laws_and_geometries_round_trip(cpu, law):
    truth = np.random.default_rng(3).uniform(0, 60000, (64, 64))
    g = ipc_taichi.Geometry.terms(horizontal=1.1, vertical=0.9, diagonal=0.1, second=0.03)
    for edge in ("zero", "isolated"):
        measured = ipc_taichi.couple(truth, law=law, geometry=g, edge=edge)
        # the paper's tol stops at ~0.6 e- updates; a strong constant law contracts
        # slowly (factor ~0.6), so ask for a tight tolerance to test the fixed point
        signal = ipc_taichi.decouple(measured, law=law, geometry=g, edge=edge, max_iter=200,
                                     tol=1e-12)
        assert np.abs(signal - truth).max() < 1e-6


def test_not_converged_warns(cpu, worked_truth):
    measured = ipc_taichi.couple(worked_truth)
    with pytest.warns(ConvergenceWarning, match="did not meet the stopping rule in 2"):
        _, info = ipc_taichi.decouple(measured, max_iter=2, full_output=True)
    assert not info.converged and info.iterations == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, info = ipc_taichi.decouple(measured, max_iter=2, tol=0, full_output=True)
    assert info.iterations == 2


def test_divergence_is_an_error(cpu):
    # alpha swings between 0 and 11% every ~6 e-: it passes the linear bound
    # (2 * 0.11 * 4 < 1) but its signal derivative makes the Jacobi map expand
    law = ipc_taichi.TabulatedLaw.from_callable(
        lambda s, n: 0.055 + 0.055 * np.cos(0.5 * (s + n)), (0, 200), n=401)
    truth = np.random.default_rng(0).uniform(50, 150, (32, 32))
    measured = ipc_taichi.couple(truth, law=law)
    with pytest.raises(DivergenceError, match="diverged"):
        ipc_taichi.decouple(measured, law=law, max_iter=200)


def test_too_strong_law_rejected_before_running(cpu):
    with pytest.raises(LawError, match="too strong"):
        ipc_taichi.decouple(np.ones((4, 4)), law="constant:0.2")


def test_argument_validation(cpu):
    with pytest.raises(IPCInputError, match="max_iter"):
        ipc_taichi.decouple(np.ones((4, 4)), max_iter=0)
    with pytest.raises(IPCInputError, match="tol"):
        ipc_taichi.decouple(np.ones((4, 4)), tol=-1)


def test_changing_coefficients_does_not_recompile(cpu, rng):
    signal = rng.uniform(0, 60000, (16, 16))
    ipc_taichi.decouple(ipc_taichi.couple(signal, law="donlon2018"), law="donlon2018")
    kernels_before = get_step_kernel.cache_info().currsize
    compiled = {id(k): len(k._primal.compiled_kernels) for k in _live_kernels()}
    for law in ("donlon2018_printed", "parametric:0.003,1e4,0.002,3e4,0.009",
                ipc_taichi.donlon2018().with_values(floor=0.007)):
        ipc_taichi.decouple(ipc_taichi.couple(signal, law=law), law=law)
    assert get_step_kernel.cache_info().currsize == kernels_before
    assert {id(k): len(k._primal.compiled_kernels) for k in _live_kernels()} == compiled
    # a constant law has its own kernel (no alpha evaluation), built once for all values
    ipc_taichi.decouple(ipc_taichi.couple(signal, law="constant:0.02"), law="constant:0.02")
    with_constant = get_step_kernel.cache_info().currsize
    assert with_constant <= kernels_before + 1
    constant_kernel = get_step_kernel(KernelConfig(((0, 1), (1, 0)), "constant", "zero", False,
                                                   "f64", "lanes"))  # the CPU's layout
    assert len(constant_kernel._primal.compiled_kernels) == 1
    ipc_taichi.decouple(ipc_taichi.couple(signal, law="constant:0.01"), law="constant:0.01")
    assert get_step_kernel.cache_info().currsize == with_constant
    assert len(constant_kernel._primal.compiled_kernels) == 1


def _live_kernels():
    # the lru_cache keeps the kernels it built; reach them through a known config
    return [get_step_kernel(KernelConfig(((0, 1), (1, 0)), "parametric", "zero", False, "f64",
                                         "lanes"))]  # the CPU's layout

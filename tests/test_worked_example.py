"""The paper's worked example, numbers from docs/reference.md section 2."""

import numpy as np
import pytest

import ipc_taichi

COUPLED = np.array([
    [0.00, 27.69, 52.99, 0.00],
    [27.69, 1998.75, 3940.13, 52.99],
    [52.99, 3940.13, 9618.94, 117.35],
    [0.00, 52.99, 117.35, 0.00],
])
MAX_ERRORS = [381.06, 16.69, 0.869, 0.0560, 0.0049]


def test_coupled_window(cpu, worked_truth):
    measured = ipc_taichi.couple(worked_truth)
    np.testing.assert_allclose(measured[23:27, 23:27], COUPLED, atol=0.005)
    # nothing outside the 4x4 window is touched
    outside = measured.copy()
    outside[23:27, 23:27] = 0
    assert np.all(outside == 0)


def test_decoupling_sequence_and_stopping_rule(cpu, worked_truth):
    measured = ipc_taichi.couple(worked_truth)
    peaks, errors = [], [np.abs(measured - worked_truth).max()]

    def record(q, estimate):
        peaks.append(estimate[25, 25])
        errors.append(np.abs(estimate - worked_truth).max())

    signal, info = ipc_taichi.decouple(measured, callback=record, full_output=True)
    assert info.converged and info.iterations == 4
    assert peaks[:3] == pytest.approx([9983.31, 9999.13, 9999.95], abs=0.005)
    assert errors[0] == pytest.approx(MAX_ERRORS[0], abs=0.005)
    assert errors[1] == pytest.approx(MAX_ERRORS[1], abs=0.005)
    assert errors[2] == pytest.approx(MAX_ERRORS[2], abs=0.0005)
    assert errors[3] == pytest.approx(MAX_ERRORS[3], abs=0.00005)
    assert errors[4] == pytest.approx(MAX_ERRORS[4], abs=0.00005)
    # rule: stops at the first q with max|S_q - S_(q-1)| <= 1e-5 max|S_q|
    assert info.max_delta[3] <= 1e-5 * info.max_signal[3] < info.max_delta[2]
    assert np.abs(signal - worked_truth).max() == pytest.approx(0.0049, abs=0.00005)


def test_later_iterations_continue_to_shrink(cpu, worked_truth):
    measured = ipc_taichi.couple(worked_truth)
    errors = []
    ipc_taichi.decouple(measured, max_iter=7, tol=0,
                        callback=lambda q, e: errors.append(np.abs(e - worked_truth).max()))
    # docs/reference.md: 4.8e-4, 4.6e-5, 5e-6 at iterations 5-7
    assert errors[4:] == pytest.approx([4.8e-4, 4.6e-5, 5e-6], rel=0.1)

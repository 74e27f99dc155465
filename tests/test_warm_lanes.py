"""Warm starts on the CPU's ``lanes`` layout: the two vector passes of
:mod:`ipc_taichi._warm` (keep ``c = S - M``, start ``S_0 = M + (c1 + (c1 - c2))``)
against the NumPy passes of the other host layouts."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.datasets import star_field
from ipc_taichi.engine import LaneShift, aligned_zeros, lane_count, lanes_warm_kernels


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_lanes_warm_kernels_match_the_formula(precision, rng):
    dtype = np.float64 if precision == "f64" else np.float32
    ipc_taichi.init("cpu", precision)
    try:
        lanes = lane_count(precision)
        shape = (7, 3 * lanes)
        src, measured, c1, c2 = (aligned_zeros(shape, dtype) for _ in range(4))
        for a in (src, measured, c1, c2):
            a[...] = rng.normal(0.0, 1000.0, shape)
        kernels = lanes_warm_kernels(precision, lanes)
        kept = aligned_zeros(shape, dtype)
        kernels.keep(*(a.reshape(-1, lanes) for a in (src, measured, kept)))
        np.testing.assert_array_equal(kept, src - measured)
        for two, shift in ((1, c1 + (c1 - c2)), (0, c1)):
            dst = aligned_zeros(shape, dtype)
            kernels.start(*(a.reshape(-1, lanes) for a in (dst, measured, c1, c2)), two)
            # one rounding per operation; allow a reassociation's worth (values < 8000)
            np.testing.assert_allclose(dst, measured + shift, rtol=0,
                                       atol=4 * np.finfo(dtype).eps * 8000)
    finally:
        ipc_taichi.init("cpu", "f64")


def test_warm_lanes_path_taken_and_agrees_with_the_sweeps(cpu, monkeypatch):
    rate = star_field(64, seed=5) / 6 + 40.0
    measured = ipc_taichi.couple(np.stack([rate * (g + 1) for g in range(6)]), law="donlon2018")
    starts = []
    add_to = LaneShift.add_to
    monkeypatch.setattr(LaneShift, "add_to",
                        lambda self, ws: (starts.append(self.warm.kept), add_to(self, ws)))
    lanes, lanes_info = ipc_taichi.decouple(measured, law="donlon2018", layout="lanes",
                                            full_output=True, warm_start=True)
    assert starts == [1, 2, 3, 4, 5]  # every frame after the first, from the vector passes
    sweep, sweep_info = ipc_taichi.decouple(measured, law="donlon2018", layout="sweep",
                                            full_output=True, warm_start=True)
    assert len(starts) == 5  # the sweep's warm start is NumPy's
    assert [i.warm_start for i in lanes_info] == [False] + [True] * 5
    assert [i.iterations for i in lanes_info] == [i.iterations for i in sweep_info]
    np.testing.assert_allclose(lanes, sweep, rtol=1e-12, atol=1e-9)


def test_a_carried_lanes_start_survives_another_call_between(cpu, rng):
    """The corrections live in the warm start's own arrays: a cold call of the
    same shape between two carried calls (same workspace) changes nothing."""
    from ipc_taichi.decoupling import WarmCarry

    rate = star_field(48, seed=9) / 4 + 40.0
    ramp = ipc_taichi.couple(np.stack([rate * (g + 1) for g in range(4)]))
    carry = WarmCarry()
    alone = [ipc_taichi.decouple(f, warm_start=carry) for f in ramp]
    carry, mixed = WarmCarry(), []
    for f in ramp:
        mixed.append(ipc_taichi.decouple(f, warm_start=carry))
        ipc_taichi.decouple(rng.uniform(0, 60000, f.shape))  # the same workspace, cold
    np.testing.assert_array_equal(np.stack(mixed), np.stack(alone))

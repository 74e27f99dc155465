"""Warm starts on the CPU's ``lanes`` layout: the two vector passes of
:mod:`ipc_taichi._warm` (keep ``c = S - M``, start ``S_0 = M + (c1 + (c1 - c2))``)
against the NumPy passes of the other host layouts."""

import numpy as np

import ipc_taichi
from ipc_taichi import _warm
from ipc_taichi._lanes import aligned_zeros, lane_count
from ipc_taichi.datasets import star_field


def test_lanes_warm_kernels_match_the_formula(cpu, rng):
    lanes = lane_count("f64")
    shape = (7, 3 * lanes)
    src, measured, c1, c2 = (aligned_zeros(shape, np.float64) for _ in range(4))
    for a in (src, measured, c1, c2):
        a[...] = rng.normal(0.0, 1000.0, shape)
    kernels = _warm.lanes_warm_kernels("f64", lanes)
    kept = aligned_zeros(shape, np.float64)
    kernels.keep(*(a.reshape(-1, lanes) for a in (src, measured, kept)))
    np.testing.assert_array_equal(kept, src - measured)
    for two, shift in ((1, c1 + (c1 - c2)), (0, c1)):
        dst = aligned_zeros(shape, np.float64)
        kernels.start(*(a.reshape(-1, lanes) for a in (dst, measured, c1, c2)), two)
        # one rounding per operation; allow a reassociation's worth
        np.testing.assert_allclose(dst, measured + shift, rtol=0, atol=1e-12 * 4000)


def test_warm_lanes_path_taken_and_agrees_with_the_sweeps(cpu, monkeypatch):
    rate = star_field(64, seed=5) / 6 + 40.0
    measured = ipc_taichi.couple(np.stack([rate * (g + 1) for g in range(6)]), law="donlon2018")
    starts = []
    add_to = _warm.LaneShift.add_to
    monkeypatch.setattr(_warm.LaneShift, "add_to",
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

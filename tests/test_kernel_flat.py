"""The step kernels on host arrays (the CPU default, ``lanes``, since issue 28: flat
``KernelConfig.flat`` arrays before it, 1-D, indexed
``row * width + column``, the table read the same way) against the same kernels
on 2-D Taichi ndarrays (the device path, ``engine.device_buffers``):
bit for bit, on every recorded case of ``tests/kernel_reference.py`` (nearest
and anisotropic + diagonal + second-neighbour geometry, the isolated edge, a
constant and a tabulated law, a NaN pixel, a mask), so that the recorded bytes
of ``tests/data/kernel_reference.json`` (taken on the flat path) hold for both.
Also the table law's lookup at and beyond its grid's ends."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import TabulatedLaw, engine
from ipc_taichi.engine import KernelConfig, StepPlan
from tests import kernel_reference


def _run(case, masked, device_buffers, monkeypatch):
    engine.clear_workspaces()
    truth, mask = kernel_reference.frames()
    kw = dict(mask=mask if masked else None, **case)
    with engine.device_buffers(device_buffers):
        measured = ipc_taichi.couple(truth, **kw)
        signal, infos = ipc_taichi.decouple(measured, full_output=True, **kw)
    return measured, signal, [i.max_delta for i in infos]


@pytest.mark.parametrize("name, case", kernel_reference.cases(),
                         ids=[n for n, _ in kernel_reference.cases()])
def test_flat_host_arrays_bit_identical_to_device_arrays(cpu, monkeypatch, name, case):
    masked = name.startswith("aniso")  # the masked kernels once, the NaN pixel everywhere
    try:
        flat = _run(case, masked, False, monkeypatch)
        nested = _run(case, masked, True, monkeypatch)
    finally:
        engine.clear_workspaces()
    for a, b in zip(flat[:2], nested[:2]):
        assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    assert flat[2] == nested[2]  # the stopping-rule maxima, iteration by iteration


def test_flat_is_the_host_paths_config(cpu):
    """The engine passes host arrays flat and device arrays 2-D; a pixel-layout
    plan carries down columns, a sweep plan along rows and through its ring."""
    assert KernelConfig(((0, 1), (1, 0)), "parametric", "zero", False, "f64").flat
    sweep = StepPlan.of(KernelConfig(((0, 1), (1, 0)), "table", "zero", False, "f32"))
    assert sweep.sources == ("row", "ring") and sweep.carry_size == 1
    pixel = StepPlan.of(KernelConfig(((0, 1), (1, 0)), "table", "zero", False, "f32",
                                     "pixel", flat=False))
    assert pixel.sources == ("fresh", "column") and not pixel.config.flat
    constant = KernelConfig(((0, 1), (1, 0)), "constant", "zero", False, "f32")
    assert StepPlan.of(constant).combined and StepPlan.of(constant).n_coef == 4 + 5 + 5
    for gated in (KernelConfig(((0, 1), (1, 0)), "constant", "zero", True, "f32"),
                  KernelConfig(((0, 1), (1, 0)), "constant", "isolated", False, "f32"),
                  KernelConfig(((0, 1), (1, 0)), "parametric", "zero", False, "f32")):
        assert not StepPlan.of(gated).combined and StepPlan.of(gated).n_coef == 4 + 5
    with pytest.raises(ValueError, match="unknown kernel layout"):
        StepPlan.of(KernelConfig(((0, 1),), "table", "zero", False, "f32", "diagonal"))


def test_table_lookup_clamps_and_interpolates_like_numpy(cpu):
    """Signals below, on and beyond the grid (clamped to its ends), and between
    its nodes: the kernel's coupling with a table law equals the NumPy
    reference's, which evaluates :meth:`TabulatedLaw.alpha` (floor, not
    truncation)."""
    from ipc_taichi.reference import couple_reference

    rng = np.random.default_rng(7)
    table = rng.uniform(0.002, 0.02, (9, 9))
    law = TabulatedLaw(100.0, 250.0, (table + table.T) / 2, name="t9")
    frame = rng.uniform(-500.0, 2600.0, (21, 17))  # grid: 100 .. 2100
    frame[3, 4], frame[5, 6], frame[7, 8] = 100.0, 2100.0, 1350.0  # on nodes and ends
    got = ipc_taichi.couple(frame, law=law)
    want = couple_reference(frame, law=law)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-9)

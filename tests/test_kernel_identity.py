"""The Taichi kernels' outputs, byte for byte, against those recorded before
the kernels were restructured (``tests/kernel_reference.py`` made
``tests/data/kernel_reference.json``): couple and decouple, f64 and f32, both
layouts (``pixel`` runs on the CPU arch here; ``lanes``, added later, is checked against
the ``sweep`` bytes recorded before it existed), a NaN pixel and a mask,
anisotropic + diagonal + second-neighbour geometry, the isolated edge, a
2-frame stack, a constant law and a tabulated law."""

import json
import os

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.reference import decouple_reference
from tests import kernel_reference

RECORDED = os.path.join(kernel_reference.HERE, "kernel_reference.json")
CPU_DEPENDENT = "/table_nearest/"
"""Cases whose decouple bytes depend on the CPU the JIT compiles for: the table law's
decouple outputs differed between an AMD EPYC (where they were first recorded) and an
Intel Xeon with AVX-512 already at commit 40f64e6, before any kernel change (their
couple outputs and every other case agree byte for byte on both). They are checked
against the NumPy reference instead (:func:`test_table_law_decouple_agrees_with_reference`)."""


@pytest.mark.slow
def test_outputs_bit_identical_to_recorded():
    with open(RECORDED) as f:
        recorded = json.load(f)
    try:
        now = kernel_reference.record()
    finally:
        ipc_taichi.init("cpu", "f64")
    assert sorted(now) == sorted(recorded)
    changed = [key for key in sorted(now) if now[key] != recorded[key]
               and not (CPU_DEPENDENT in key and key.endswith("/decouple"))]
    assert changed == [], f"{len(changed)} of {len(now)} outputs changed: {changed[:6]}"


@pytest.mark.parametrize("layout", ["lanes", "sweep", "pixel"])
def test_table_law_decouple_agrees_with_reference(cpu, layout):
    """The table law's decouple (both layouts, f64) against the NumPy reference decoupler
    on the recorded frames: the cases left out of the byte check above."""
    (name, kw), = [c for c in kernel_reference.cases() if c[0] == "table_nearest"]
    truth, _mask = kernel_reference.frames()
    frame = np.nan_to_num(truth[0])
    measured = np.asarray(ipc_taichi.couple(frame, layout=layout, **kw))
    got, info = ipc_taichi.decouple(measured, layout=layout, full_output=True, **kw)
    ref, iterations, converged, _ = decouple_reference(measured, **kw)
    assert converged and info.iterations == iterations
    np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-12, atol=1e-9)

"""The CPU's ``lanes`` layout (the step on vectors of 16 (f32) or 8 (f64)
pixels, ``ipc_taichi/_lanes.py``) against the scalar ``sweep`` it replaced as
the CPU's default: bit for bit, on frames whose widths end inside a vector,
narrower than one vector, of one row, with the geometry's full reach (2),
every law kind, bad pixels and the isolated edge (the recorded cases of
``tests/kernel_reference.py`` are 29 x 23 frames only)."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import engine
from tests import kernel_reference

FULL = ipc_taichi.Geometry.terms(horizontal=1.0, vertical=0.7, diagonal=0.2, second=0.05)
TABLE = dict(kernel_reference.cases())["table_nearest"]["law"]


def _both(frame, **kw):
    out = {}
    for layout in ("sweep", "lanes"):
        measured = ipc_taichi.couple(frame, layout=layout, **kw)
        signal, info = ipc_taichi.decouple(measured, layout=layout, full_output=True, **kw)
        out[layout] = (np.asarray(measured), np.asarray(signal), info.max_delta)
    return out["sweep"], out["lanes"]


# slow: each case compiles its own kernels (about 90 s each in f32 on a 2-core AMD EPYC
# with AVX-512); `make test` runs them, the quick lanes leave them out
@pytest.mark.slow
@pytest.mark.parametrize("shape", [(1, 1), (3, 2), (40, 1), (6, 16), (5, 17), (11, 33)])
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_lanes_bit_identical_to_sweep_at_every_width(cpu, shape, precision):
    rng = np.random.default_rng(sum(shape))
    frame = rng.uniform(0, 60000, shape)
    try:
        for kw in (dict(), dict(geometry=FULL, edge="isolated"), dict(law="constant:0.013"),
                   dict(law=TABLE, geometry=FULL)):
            sweep, lanes = _both(frame, precision=precision, **kw)
            for a, b in zip(sweep[:2], lanes[:2]):
                assert np.array_equal(a, b), (kw, shape)
            assert sweep[2] == lanes[2]
    finally:
        ipc_taichi.init("cpu", "f64")


def test_lanes_with_bad_pixels_and_a_stack(cpu):
    rng = np.random.default_rng(5)
    frames = rng.uniform(0, 60000, (3, 21, 19))
    frames[1, 0, 18] = np.nan  # a corner: its vector holds border lanes too
    mask = np.zeros((21, 19), bool)
    mask[10, 0] = mask[20, 9] = True
    for kw in (dict(mask=mask), dict(mask=mask, geometry=FULL, law=TABLE)):
        sweep, lanes = (ipc_taichi.decouple(ipc_taichi.couple(frames, layout=layout, **kw),
                                            layout=layout, **kw)
                        for layout in ("sweep", "lanes"))
        assert np.array_equal(np.asarray(sweep), np.asarray(lanes), equal_nan=True)


def test_lanes_is_the_cpu_default_and_refused_on_device_buffers(cpu):
    frame = np.random.default_rng(1).uniform(0, 60000, (12, 10))
    with engine.step_kernels_built() as built:
        ipc_taichi.decouple(frame)
    assert {c.layout for c in built} == {"lanes"}
    try:
        with engine.device_buffers(), pytest.raises(ipc_taichi.IPCInputError, match="lanes"):
            ipc_taichi.decouple(frame, layout="lanes")
    finally:
        engine.clear_workspaces()

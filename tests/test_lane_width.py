"""The ``lanes`` step's vector width, chosen from the CPU's vector extensions
(``ipc_taichi/_lanes.py``: AVX-512 and AVX2 16 f32 / 8 f64 pixels, two
256-bit registers; SSE and NEON 8 / 4, two 128-bit ones; none: the scalar
``sweep``) or forced by ``$IPC_TAICHI_LANES``; and the step's outputs bit for
bit the same at every width."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import engine
from ipc_taichi.engine import LANES_ENV, default_layout, host_vector_unit, lane_count, vector_unit
from tests import kernel_reference

ZEN4 = "fpu sse sse2 ssse3 fma sse4_1 sse4_2 avx f16c avx2 avx512f avx512dq avx512vl avx512bw"
HASWELL = "fpu sse sse2 ssse3 fma sse4_1 sse4_2 avx f16c avx2 bmi2"
OLD_X86 = "fpu sse sse2 ssse3 sse4_1 sse4_2 avx"  # AVX but no AVX2
GRAVITON = "fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics fphp asimdhp cpuid"


@pytest.mark.parametrize("flags, machine, unit, f32, f64", [
    (ZEN4, "x86_64", "avx512", 16, 8),
    (HASWELL, "x86_64", "avx2", 16, 8),
    (OLD_X86, "x86_64", "sse", 8, 4),
    (GRAVITON, "aarch64", "neon", 8, 4),
    ("", "arm64", "neon", 8, 4),
])
def test_width_follows_the_vector_extensions(flags, machine, unit, f32, f64):
    assert vector_unit(flags.split(), machine) == unit
    assert (lane_count("f32", unit), lane_count("f64", unit)) == (f32, f64)


@pytest.mark.parametrize("machine", ["ppc64le", "riscv64", "s390x"])
def test_no_known_vector_unit(machine):
    # AVX-512 flags on a machine that is no x86 mean nothing
    assert vector_unit(ZEN4.split(), machine) is None


def test_no_vector_unit_gets_the_sweep(cpu):
    with engine.vector_unit_set("none"):
        assert host_vector_unit() is None
        assert default_layout("cpu") == "sweep"
        assert default_layout("cuda") == "pixel"
        frame = np.random.default_rng(2).uniform(0, 60000, (6, 7))
        with engine.step_kernels_built() as built:
            ipc_taichi.decouple(frame, law="constant:0.01")
        assert {c.layout for c in built} == {"sweep"}
    assert default_layout("cpu") == ("lanes" if host_vector_unit() else "sweep")


def test_width_forced_by_the_environment():
    for name, f32 in (("avx2", 16), ("AVX512", 16), (" sse ", 8), ("neon", 8), ("8", 8),
                      ("4", 4)):
        with engine.vector_unit_set(name):
            assert lane_count("f32") == f32 and lane_count("f64") == f32 // 2
            # rows of whole vectors: 10 + 2 border columns
            assert engine.kernel_layout("lanes").padded_shape((3, 10), 1, "f32") == \
                (5, -(-12 // f32) * f32)
    for bad in ("avx1024", "12"):
        with engine.vector_unit_set(bad), \
                pytest.raises(ipc_taichi.IPCInputError, match=f"{bad}.*{LANES_ENV}"):
            host_vector_unit()


def _outputs(frame, **kw):
    measured = ipc_taichi.couple(frame, **kw)
    signal, info = ipc_taichi.decouple(measured, full_output=True, **kw)
    return np.asarray(measured), np.asarray(signal), info.max_delta, info.iterations


def _at_widths(frame, units, **kw):
    """``{unit: outputs}`` of the ``lanes`` step at each vector unit's width,
    and ``"sweep"``'s."""
    out = {"sweep": _outputs(frame, layout="sweep", **kw)}
    for unit in units:
        with engine.vector_unit_set(unit), engine.step_kernels_built() as built:
            out[unit] = _outputs(frame, layout="lanes", **kw)
        assert {c.layout for c in built} == {"lanes"}
    return out


def _assert_same(out, what):
    sweep = out.pop("sweep")
    for unit, got in out.items():
        for a, b in zip(sweep[:2], got[:2]):
            assert np.array_equal(a, b, equal_nan=True), (unit, what)
        assert sweep[2:] == got[2:], (unit, what)


def test_one_avx2_register_bit_identical_to_the_sweep(cpu):
    """f64 (4 pixels a vector at one AVX2 register's width): a frame whose rows
    end inside a vector, a bad pixel, ``donlon2018``."""
    rng = np.random.default_rng(3)
    frame = rng.uniform(0, 60000, (9, 13))
    frame[4, 12] = np.nan
    _assert_same(_at_widths(frame, ["8"]), "donlon2018, NaN")


TABLE = dict(kernel_reference.cases())["table_nearest"]["law"]
FULL = ipc_taichi.Geometry.terms(horizontal=1.0, vertical=0.7, diagonal=0.2, second=0.05)


# slow: every width compiles its own kernels (about 280 s for both precisions at
# 16, 8 and 4 lanes on a loaded 2-core AMD EPYC); the default width, 16 in f32, is
# tests/test_lanes_layout.py's and the recorded digests'
@pytest.mark.slow
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_every_width_bit_identical_to_the_sweep(cpu, precision):
    rng = np.random.default_rng(11)
    frame = rng.uniform(0, 60000, (7, 19))
    try:
        ipc_taichi.init("cpu", precision)
        for kw in (dict(), dict(law=TABLE, geometry=FULL, edge="isolated"),
                   dict(law="constant:0.013")):
            out = _at_widths(frame, ["8", "4"], precision=precision,
                             **kw)
            _assert_same(out, kw)
    finally:
        ipc_taichi.init("cpu", "f64")

"""Taichi kernels against the plain-NumPy reference on random frames, laws,
geometries and edges (1e-10 relative in f64)."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import DivergenceError, Geometry, ParametricLaw, TabulatedLaw
from ipc_taichi.reference import couple_reference, decouple_reference
from tests.helpers import optional

# the whole file: random cases drawn by hypothesis
pytest.importorskip("hypothesis", reason=optional("hypothesis"))
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

# a few stencils (each is one compiled kernel) with random weights
STENCILS = [
    ((0, 1), (0, -1), (1, 0), (-1, 0)),
    ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)),
    ((0, 1), (1, 0), (0, 2), (-2, 0)),  # asymmetric
]


@st.composite
def geometries(draw):
    stencil = draw(st.sampled_from(STENCILS))
    weights = draw(st.lists(st.floats(0.05, 1.5), min_size=len(stencil), max_size=len(stencil)))
    return Geometry(dict(zip(stencil, weights)))


@st.composite
def laws(draw):
    kind = draw(st.sampled_from(["donlon2018", "printed", "constant", "parametric", "table"]))
    if kind == "donlon2018":
        return ipc_taichi.donlon2018()
    if kind == "printed":
        return ipc_taichi.donlon2018_printed()
    if kind == "constant":
        return ipc_taichi.constant(draw(st.floats(0.0, 0.03)))
    if kind == "parametric":
        return ParametricLaw(draw(st.floats(0, 0.01)), draw(st.floats(100, 1e5)),
                             draw(st.floats(0, 0.01)), draw(st.floats(100, 1e5)),
                             draw(st.floats(0, 0.01)))
    amp = draw(st.floats(0.001, 0.01))
    return TabulatedLaw.from_callable(
        lambda s, n: 0.006 + amp * np.exp(-np.abs(s - n) / 15000.0), (0, 60000),
        n=draw(st.integers(2, 40)))


frames = st.tuples(st.integers(1, 24), st.integers(1, 24), st.integers(0, 2**32 - 1),
                   st.booleans())


def make_frame(spec):
    ny, nx, seed, with_nan = spec
    rng = np.random.default_rng(seed)
    frame = rng.uniform(-500, 65000, (ny, nx))
    if with_nan and frame.size > 2:
        frame.flat[rng.choice(frame.size, size=max(1, frame.size // 10), replace=False)] = np.nan
    return frame


def assert_close(a, b):
    assert np.array_equal(np.isnan(a), np.isnan(b))
    scale = max(np.nanmax(np.abs(b)), 1.0) if np.isfinite(b).any() else 1.0
    assert np.nanmax(np.abs(a - b)) <= 1e-10 * scale if np.isfinite(b).any() else True


SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


@SETTINGS
@given(frame=frames, law=laws(), geometry=geometries(), edge=st.sampled_from(["zero", "isolated"]))
def test_couple_matches_reference(cpu, frame, law, geometry, edge):
    signal = make_frame(frame)
    assert_close(ipc_taichi.couple(signal, law=law, geometry=geometry, edge=edge),
                 couple_reference(signal, law, geometry, edge))


@SETTINGS
@given(frame=frames, law=laws(), geometry=geometries(), edge=st.sampled_from(["zero", "isolated"]))
def test_decouple_matches_reference(cpu, frame, law, geometry, edge):
    truth = make_frame(frame)
    measured = couple_reference(truth, law, geometry, edge)
    ref, iterations, _, deltas = decouple_reference(measured, law, geometry, edge, max_iter=6,
                                                    tol=0)
    if _grows_three_times(deltas):
        # a steep law (e.g. a 100 e- scale) on 65000 e- pixels need not contract:
        # the reference's update grows, and decouple must say so
        with pytest.raises(DivergenceError):
            ipc_taichi.decouple(measured, law=law, geometry=geometry, edge=edge, max_iter=6,
                                tol=0)
        return
    ours, info = ipc_taichi.decouple(measured, law=law, geometry=geometry, edge=edge,
                                     max_iter=6, tol=0, full_output=True)
    assert info.iterations == iterations == 6
    assert_close(ours, ref)
    np.testing.assert_allclose(info.max_delta, deltas, rtol=1e-9, atol=1e-9)


def _grows_three_times(deltas):
    """decouple's divergence rule: max|dS| grew 3 iterations running."""
    rising = 0
    for before, after in zip(deltas, deltas[1:]):
        rising = rising + 1 if after > before else 0
        if rising >= 3:
            return True
    return False


def test_stopping_rule_matches_reference(cpu):
    truth = np.random.default_rng(5).uniform(0, 60000, (48, 40))
    measured = couple_reference(truth)
    ours, info = ipc_taichi.decouple(measured, full_output=True)
    ref, iterations, converged, _ = decouple_reference(measured)
    assert (info.iterations, info.converged) == (iterations, converged) == (4, True)
    np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-9)

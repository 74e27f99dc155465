"""The constant-law kernel: a parametric law with both amplitudes zero runs a
kernel that evaluates no alpha, with the general kernel's results."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import Geometry, ParametricLaw, constant, donlon2018, engine
from ipc_taichi.engine import kernel_law_kind
from ipc_taichi.reference import decouple_reference

ANISO = Geometry.terms(horizontal=1.0, vertical=0.8, diagonal=0.3, second=0.1)


def test_which_laws_are_constant():
    assert kernel_law_kind(constant(0.0125)) == "constant"
    assert kernel_law_kind(ParametricLaw(0.0, 3.0, 0.0, 7.0, 0.01)) == "constant"
    assert kernel_law_kind(donlon2018()) == "parametric"
    assert kernel_law_kind(ParametricLaw(0.0, 3.0, 1e-9, 7.0, 0.01)) == "parametric"
    assert kernel_law_kind(ParametricLaw(1e-9, 3.0, 0.0, 7.0, 0.01)) == "parametric"


@pytest.mark.parametrize("layout", ["lanes", "sweep", "pixel"])
@pytest.mark.parametrize("geometry,edge", [(None, "zero"), (ANISO, "isolated")])
def test_constant_kernel_matches_general_kernel(cpu, rng, layout, geometry, edge):
    """The same law through the general kernel (a parametric law whose
    amplitude is so small that alpha is the floor to the last bit) and through
    the constant kernel: equal to 1e-12, and to the NumPy reference to 1e-10."""
    truth = rng.uniform(0, 60000, (2, 33, 27))
    truth[0, 4, 9] = np.nan
    mask = np.zeros((33, 27), bool)
    mask[20, 3] = True
    const = constant(0.0125)
    with engine.step_kernels_built() as built:
        # amplitude 1e-300: the exponential terms vanish against the floor in f64,
        # but the law is not "constant" to the engine, which takes the general kernel
        general = ParametricLaw(1e-300, 1e4, 0.0, 1e4, 0.0125, name="almost")
        assert kernel_law_kind(general) == "parametric"
        kw = dict(geometry=geometry, edge=edge, layout=layout, mask=mask)
        m_const = ipc_taichi.couple(truth, law=const, **kw)
        m_general = ipc_taichi.couple(truth, law=general, **kw)
        np.testing.assert_allclose(m_const, m_general, rtol=1e-12, atol=0)
        s_const, info_c = ipc_taichi.decouple(m_const, law=const, full_output=True, **kw)
        s_general, info_g = ipc_taichi.decouple(m_const, law=general, full_output=True, **kw)
        np.testing.assert_allclose(s_const, s_general, rtol=1e-12, atol=0)
        assert [i.iterations for i in info_c] == [i.iterations for i in info_g]
        # without the mask, against the NumPy reference (NaN pixel included)
        plain, infos = ipc_taichi.decouple(m_general, law=const, geometry=geometry, edge=edge,
                                           layout=layout, full_output=True)
        for k in range(2):
            ref, iterations, _, _ = decouple_reference(np.asarray(m_general[k]), law=const,
                                                       geometry=geometry, edge=edge)
            assert infos[k].iterations == iterations
            np.testing.assert_allclose(plain[k], ref, rtol=0, atol=1e-10 * 60000)
    # the constant kernel was the one run, with and without bad pixels
    assert {(c.law_kind, c.layout) for c in built} >= {("constant", layout)}
    assert {("parametric", layout)} <= {(c.law_kind, c.layout) for c in built}

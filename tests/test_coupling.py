import numpy as np
import pytest
from scipy import ndimage

import ipc_taichi
from ipc_taichi import Geometry, GeometryError, IPCInputError
from ipc_taichi.reference import couple_reference


@pytest.mark.parametrize("alpha", [0.005, 0.0125, 0.08])
@pytest.mark.parametrize("geometry", [Geometry.nearest(),
                                      Geometry.terms(horizontal=1.2, vertical=0.8, diagonal=0.1,
                                                     second=0.05)])
def test_constant_alpha_is_a_convolution(cpu, rng, alpha, geometry):
    signal = rng.uniform(-100, 60000, (40, 33))
    measured = ipc_taichi.couple(signal, law=alpha, geometry=geometry, edge="zero")
    expected = ndimage.convolve(signal, geometry.kernel(alpha), mode="constant", cval=0.0)
    np.testing.assert_allclose(measured, expected, rtol=1e-12, atol=1e-9)


def test_direction_convolution_not_correlation(cpu):
    # charge moves only to the right: (0, +1) weight 1
    geometry = Geometry({(0, 1): 1.0})
    signal = np.zeros((5, 5))
    signal[2, 2] = 1000.0
    measured = ipc_taichi.couple(signal, law="constant:0.1", geometry=geometry)
    assert measured[2, 3] == pytest.approx(100.0)
    assert measured[2, 1] == 0.0
    assert measured[2, 2] == pytest.approx(900.0)
    k = geometry.kernel(0.1)
    assert k[1, 2] == pytest.approx(0.1) and k[1, 0] == 0.0
    np.testing.assert_allclose(measured, ndimage.convolve(signal, k, mode="constant"), atol=1e-12)
    assert not np.allclose(measured, ndimage.correlate(signal, k, mode="constant"))


def test_vertical_direction_and_anisotropy(cpu):
    signal = np.zeros((7, 7))
    signal[3, 3] = 10000.0
    g = Geometry.terms(horizontal=1.0, vertical=0.5, diagonal=0.1, second=0.02)
    m = ipc_taichi.couple(signal, law="constant:0.01", geometry=g)
    assert m[3, 4] == pytest.approx(100.0) and m[3, 2] == pytest.approx(100.0)
    assert m[2, 3] == pytest.approx(50.0) and m[4, 3] == pytest.approx(50.0)
    assert m[2, 2] == pytest.approx(10.0) and m[4, 4] == pytest.approx(10.0)
    assert m[3, 5] == pytest.approx(2.0) and m[1, 3] == pytest.approx(2.0)
    assert m.sum() == pytest.approx(10000.0, rel=1e-14)


@pytest.mark.parametrize("law", ["donlon2018", "donlon2018_printed", "constant:0.03"])
def test_isolated_edge_conserves_charge(cpu, rng, law):
    signal = rng.uniform(0, 60000, (31, 17))
    g = Geometry.terms(diagonal=0.2, second=0.1)
    measured = ipc_taichi.couple(signal, law=law, geometry=g, edge="isolated")
    assert measured.sum() == pytest.approx(signal.sum(), rel=1e-13)
    leaky = ipc_taichi.couple(signal, law=law, geometry=g, edge="zero")
    assert leaky.sum() < signal.sum() * (1 - 1e-4)


def test_zero_alpha_is_identity(cpu, rng):
    signal = rng.normal(1000, 500, (20, 21))
    for edge in ("zero", "isolated"):
        assert np.array_equal(ipc_taichi.couple(signal, law=0.0, edge=edge), signal)
        assert np.array_equal(ipc_taichi.decouple(signal, law=0.0, edge=edge), signal)


def test_bad_pixels_do_not_spread(cpu, rng):
    signal = rng.uniform(0, 60000, (16, 16))
    signal[5, 7] = np.nan
    signal[0, 0] = np.inf
    measured = ipc_taichi.couple(signal)
    bad = ~np.isfinite(signal)
    assert np.all(np.isnan(measured[bad]))
    assert np.all(np.isfinite(measured[~bad]))
    # bad pixels neither give nor take: same as isolating them
    np.testing.assert_allclose(measured, couple_reference(signal), rtol=1e-12, equal_nan=True)
    decoupled = ipc_taichi.decouple(measured)
    assert np.array_equal(np.isnan(decoupled), bad)
    assert np.nanmax(np.abs(decoupled - signal)) < 0.05


def test_all_nan_frame(cpu):
    out = ipc_taichi.decouple(np.full((4, 4), np.nan))
    assert np.all(np.isnan(out))


def test_stack_is_processed_frame_by_frame(cpu, rng):
    stack = rng.uniform(0, 60000, (3, 12, 14))
    stack[1, 2, 3] = np.nan
    coupled = ipc_taichi.couple(stack)
    assert coupled.shape == stack.shape
    for k in range(3):
        np.testing.assert_array_equal(coupled[k], ipc_taichi.couple(stack[k]))
    decoupled, infos = ipc_taichi.decouple(coupled, full_output=True)
    assert len(infos) == 3 and all(i.converged for i in infos)
    assert np.nanmax(np.abs(decoupled - stack)) < 0.05


def test_integer_and_big_endian_input(cpu, rng):
    signal = rng.integers(0, 60000, (10, 11))
    expected = ipc_taichi.couple(signal.astype(np.float64))
    for arr in (signal.astype(np.int32), signal.astype(">i4"), signal.astype(">f8"),
                signal.astype(np.uint16)):
        np.testing.assert_array_equal(ipc_taichi.couple(arr), expected)


def test_negative_signal_is_valid(cpu, rng):
    signal = rng.normal(0, 200, (20, 20))  # bias-subtracted noise around zero
    measured = ipc_taichi.couple(signal)
    np.testing.assert_allclose(measured, couple_reference(signal), rtol=1e-12, atol=1e-9)
    assert np.abs(ipc_taichi.decouple(measured) - signal).max() < 1e-3


@pytest.mark.parametrize("data, match", [
    (np.zeros((0, 5)), "empty"),
    (np.zeros(5), "1-D"),
    (np.zeros((2, 2, 2, 2)), "4-D"),
    (np.zeros((3, 3), dtype=complex), "not a real number type"),
    ([[1, 2], [3]], "cannot be read"),
])
def test_bad_input_errors(cpu, data, match):
    with pytest.raises(IPCInputError, match=match):
        ipc_taichi.couple(data)


def test_bad_model_arguments(cpu):
    with pytest.raises(IPCInputError, match="edge must be"):
        ipc_taichi.couple(np.zeros((3, 3)), edge="wrap")
    with pytest.raises(GeometryError, match="beyond 2 pixels"):
        Geometry({(0, 3): 1.0})
    with pytest.raises(GeometryError, match=">= 0"):
        Geometry.terms(diagonal=-0.1)
    with pytest.raises(GeometryError, match="NAME=VALUE"):
        Geometry.parse("diag=0.1")


def test_geometry_terms_not_named_are_zero():
    # '--geometry vertical=1' used to keep horizontal=1 silently
    g = Geometry.parse("vertical=1")
    assert g.weight(1, 0) == 1.0 and g.weight(-1, 0) == 1.0
    assert g.weight(0, 1) == 0.0 and g.weight(0, -1) == 0.0
    assert Geometry.parse("horizontal=1,vertical=0.9").weight(1, 0) == 0.9
    assert Geometry.parse("nearest") == Geometry.nearest()

"""The detector chain of ``ipc_taichi.discover``: each effect, the prediction
(mean and propagated variance) against Monte Carlo, and the vocabulary."""

import math

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.discover import EFFECT_NAMES, DetectorModel
from ipc_taichi.discover.effects import brighter_fatter, diffuse, nonlinearity
from ipc_taichi.discover.model import _colouring


def _scene(rng, n=24):
    s = np.full((n, n), 100.0)
    s[5, 5] = 40000.0
    s[5, 15] = 8000.0
    s[15:20, 15:20] = 30000.0
    s[16, 6] = 55000.0
    return s + rng.uniform(0, 50, s.shape)


def test_vocabulary_is_the_format_table():
    # the names fixed by DISCOVERY_FORMAT.md, which the report must use
    fixed = {"diagonal_ipc", "anisotropic_ipc", "second_neighbor_ipc", "signal_dependent_ipc",
             "classical_nonlinearity", "brighter_fatter", "charge_diffusion", "dark_current"}
    assert set(EFFECT_NAMES) == fixed


def test_bare_model_is_the_core_coupling(cpu, rng):
    scene = _scene(rng)
    model = DetectorModel("donlon2018", readnoise=10.0)
    np.testing.assert_array_equal(model.expected(scene), ipc_taichi.couple(scene))


def test_diffusion_kernel_values_and_conservation():
    s = np.zeros((15, 15))
    s[7, 7] = 1000.0
    out = diffuse(s, 0.25)
    w0 = math.erf(0.5 / 0.25 / math.sqrt(2))
    w1 = 0.5 * (math.erf(1.5 / 0.25 / math.sqrt(2)) - w0)
    assert out[7, 8] / out[7, 7] == pytest.approx(w1 / w0, rel=1e-9)
    assert out[8, 8] / out[7, 7] == pytest.approx((w1 / w0) ** 2, rel=1e-9)
    assert out.sum() == pytest.approx(1000.0, rel=1e-12)
    np.testing.assert_array_equal(diffuse(s, 0.0), s)


def test_brighter_fatter_grows_with_signal_and_conserves_charge():
    flat = np.full((12, 12), 30000.0)
    np.testing.assert_allclose(brighter_fatter(flat, 0.02)[2:-2, 2:-2], 30000.0, rtol=1e-8)
    lost = []
    for signal in (10000.0, 40000.0):
        s = np.zeros((9, 9))
        s[4, 4] = signal
        out = brighter_fatter(s, 0.02)
        assert out.sum() == pytest.approx(signal, rel=1e-12)
        assert out[4, 5] == pytest.approx(out[3, 4]) and out[5, 5] == 0.0
        lost.append(1 - out[4, 4] / signal)
    # the deflected fraction grows with the charge already collected: about
    # half the end-of-exposure value (deflection * S / 50 ke-) on average
    assert lost[0] == pytest.approx(0.02 * 10000 / 50000 / 2, rel=0.05)
    assert lost[1] == pytest.approx(0.02 * 40000 / 50000 / 2, rel=0.05)


def test_nonlinearity_deficit_at_50ke():
    x = np.array([0.0, 25000.0, 50000.0])
    y = nonlinearity(x, 0.03, 0.01)
    assert y[2] == pytest.approx(50000.0 * 0.97)
    assert y[1] == pytest.approx(25000.0 * (1 - 0.02 * 0.5 - 0.01 * 0.25))
    assert y[0] == 0.0


@pytest.mark.parametrize("offsets", [
    [(0, 1), (1, 0)], [(1, 1), (1, -1), (0, 1), (1, 0)], [(0, 2), (2, 0), (1, 1), (0, 1)]])
def test_colouring_separates_footprints(offsets):
    period, slope = _colouring(offsets)
    d = {(0, 0)} | set(offsets) | {(-a, -b) for a, b in offsets}
    for a in d:
        for b in d:
            dy, dx = a[0] - b[0], a[1] - b[1]
            if (dy, dx) != (0, 0):
                assert (dx + slope * dy) % period != 0


def test_variance_matches_brute_force_jacobian(cpu, rng):
    scene = _scene(rng)[3:17, 3:17]
    model = DetectorModel("donlon2018", 12.0, effects={
        "second_neighbor_ipc": {"alpha_second": 0.002}, "diagonal_ipc": {"alpha_diag": 0.002},
        "classical_nonlinearity": {"deficit_at_50ke": 0.05, "cubic_term": 0.0}})
    c = model.collected(scene)
    base = model.readout(c)
    jac2 = np.zeros_like(base)
    for y in range(c.shape[0]):
        for x in range(c.shape[1]):
            h = 1e-3 * max(c[y, x], 1.0)
            cp = c.copy()
            cp[y, x] += h
            jac2 += ((model.readout(cp) - base) / h) ** 2 * c[y, x]
    _, var = model.predict(scene)
    np.testing.assert_allclose(var - 144.0, jac2, rtol=2e-4, atol=1e-6)


def test_prediction_matches_monte_carlo(cpu, rng):
    scene = _scene(rng)
    model = DetectorModel("donlon2018", 12.0, effects={
        "diagonal_ipc": {"alpha_diag": 0.002}, "brighter_fatter": {"deflection_at_50ke": 0.02},
        "charge_diffusion": {"sigma_px": 0.2}, "dark_current": {"dark_e": 5.0},
        "classical_nonlinearity": {"deficit_at_50ke": 0.03, "cubic_term": 0.0}})
    mean, var = model.predict(scene)
    n = 400
    sims = model.simulate(np.broadcast_to(scene, (n,) + scene.shape), rng)
    z = (sims.mean(axis=0) - mean) / np.sqrt(var / n)
    assert np.sqrt(np.mean(z ** 2)) < 1.3
    ratio = sims.var(axis=0, ddof=1) / var
    assert abs(ratio.mean() - 1.0) < 0.02
    assert abs(ratio[mean > 5000].mean() - 1.0) < 0.05


def test_model_rejects_unknown_effect():
    with pytest.raises(ValueError, match="unknown effect"):
        DetectorModel("donlon2018", 10.0, effects={"cosmic_rays": {}})

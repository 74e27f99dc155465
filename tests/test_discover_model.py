"""The detector chain of ``ipc_taichi.discover``: each effect, the prediction
(mean and propagated variance) against Monte Carlo, and the vocabulary."""

import math

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.discover import EFFECT_NAMES, DetectorModel
from ipc_taichi.discover.effects import (
    brighter_fatter,
    contradiction,
    diffuse,
    diffusion_weights,
    nonlinearity,
    reciprocity,
    shift_scene,
)
from ipc_taichi.discover.model import _colouring


def _scene(rng, n=24):
    s = np.full((n, n), 100.0)
    s[5, 5] = 40000.0
    s[5, 15] = 8000.0
    s[15:20, 15:20] = 30000.0
    s[16, 6] = 55000.0
    return s + rng.uniform(0, 50, s.shape)


def test_vocabulary_is_the_format_table():
    # the names fixed by docs/discovery_format.md, which the report must use
    fixed = {"diagonal_ipc", "anisotropic_ipc", "second_neighbor_ipc", "signal_dependent_ipc",
             "classical_nonlinearity", "brighter_fatter", "charge_diffusion", "dark_current",
             "flat_field", "reciprocity_failure", "excess_read_noise", "misregistration"}
    assert set(EFFECT_NAMES) == fixed


def test_bare_model_is_the_core_coupling(cpu, rng):
    scene = _scene(rng)
    model = DetectorModel("donlon2018", readnoise=10.0)
    np.testing.assert_array_equal(model.expected(scene), ipc_taichi.couple(scene))


def test_diffusion_of_charge_generated_across_the_pixel():
    # charge generated uniformly across the pixel, spread by a Gaussian and
    # integrated over each collecting pixel: check against direct quadrature
    from scipy import integrate

    sigma = 0.22
    w = diffusion_weights(sigma, 3)

    def share(k):
        f = lambda u: 0.5 * (math.erf((k + 0.5 - u) / (sigma * math.sqrt(2)))
                             - math.erf((k - 0.5 - u) / (sigma * math.sqrt(2))))
        return integrate.quad(f, -0.5, 0.5, epsabs=1e-13)[0]

    for k in (0, 1, 2):
        assert w[3 + k] == pytest.approx(share(k), abs=1e-10)
    # the neighbour share grows linearly from 0 (sigma / sqrt(2 pi)): a fit can move
    assert diffusion_weights(1e-3, 2)[3] == pytest.approx(1e-3 / math.sqrt(2 * math.pi), rel=1e-6)
    s = np.zeros((15, 15))
    s[7, 7] = 1000.0
    out = diffuse(s, sigma)
    assert out[7, 8] / out[7, 7] == pytest.approx(w[4] / w[3], rel=1e-9)
    assert out[8, 8] / out[7, 7] == pytest.approx((w[4] / w[3]) ** 2, rel=1e-9)
    assert out.sum() == pytest.approx(1000.0, rel=1e-12)
    flat = np.full((12, 12), 5000.0)
    np.testing.assert_allclose(diffuse(flat, 0.4), flat, rtol=1e-12)  # flat stays flat
    np.testing.assert_array_equal(diffuse(s, 0.0), s)


def test_brighter_fatter_boundary_shift():
    flat = np.full((12, 12), 30000.0)
    np.testing.assert_allclose(brighter_fatter(flat, 0.02, 0.03)[2:-2, 2:-2], 30000.0,
                               rtol=1e-10)
    lost = []
    for signal in (10000.0, 50000.0):
        s = np.zeros((9, 9))
        s[4, 4] = signal
        out = brighter_fatter(s, 0.01, 0.03, upwind=1.0)
        assert out.sum() == pytest.approx(signal, rel=1e-12)
        assert out[5, 5] == 0.0
        # stronger along y (columns) than along x (rows), as asked
        assert out[3, 4] == pytest.approx(3 * out[4, 5], rel=0.02)
        lost.append(1 - out[4, 4] / signal)
    # an isolated pixel loses (dx + dy)/2 of its charge at 50 ke-, in proportion to S
    assert lost[1] == pytest.approx((0.01 + 0.03) / 2, rel=0.03)
    assert lost[0] == pytest.approx(lost[1] / 5, rel=0.03)
    # a constant arrival rate makes it a flow (d/4)(C_p^2 - C_q^2)/50 ke- between
    # neighbours: the "difference of squared charges" picture, to first order in d
    rng = np.random.default_rng(1)
    c = rng.uniform(1000, 40000, (10, 10))
    d = 0.002
    out = brighter_fatter(c, d, d, upwind=0.0)
    flow_x = d / 4 * (c[:, :-1] ** 2 - c[:, 1:] ** 2) / 50000.0
    flow_y = d / 4 * (c[:-1, :] ** 2 - c[1:, :] ** 2) / 50000.0
    expect = c.copy()
    expect[:, :-1] -= flow_x
    expect[:, 1:] += flow_x
    expect[:-1, :] -= flow_y
    expect[1:, :] += flow_y
    np.testing.assert_allclose(out, expect, rtol=2e-4)


def test_reciprocity_and_shift():
    x = np.array([1.0, 10.0, 1000.0, 50000.0])
    y = reciprocity(x, 0.01)
    # the response rises by alpha per decade of signal (GalSim's power law)
    np.testing.assert_allclose(y / x, (x / 1.0) ** (0.01 / math.log(10)), rtol=1e-12)
    # about +alpha per decade: exp(alpha) per factor 10 of signal
    assert y[3] / x[3] / (y[2] / x[2]) == pytest.approx(math.exp(0.01 * math.log10(50.0)))
    # a smooth source shifted by 0.3 px: charge conserved, values within a
    # fraction of the shot noise of a 40 ke- peak
    from ipc_taichi.datasets import gaussian_spot

    a = gaussian_spot((32, 32), 15.0, 16.0, 2.0e5, 2.0)
    b = gaussian_spot((32, 32), 15.2, 16.3, 2.0e5, 2.0)
    out = shift_scene(a, 0.2, 0.3)
    assert out.sum() == pytest.approx(a.sum(), rel=1e-6)
    assert np.max(np.abs(out - b) / np.sqrt(b.max())) < 1.0
    np.testing.assert_array_equal(shift_scene(a, 0.0, 0.0), a)


def test_contradicting_signs_are_recognised():
    assert contradiction("classical_nonlinearity", {"deficit_at_50ke": -0.01, "cubic_term": 0})
    assert not contradiction("classical_nonlinearity", {"deficit_at_50ke": 0.01,
                                                         "cubic_term": 0})
    assert contradiction("reciprocity_failure", {"alpha_per_decade": -0.002})
    assert contradiction("brighter_fatter", {"deflection_x_at_50ke": -0.01,
                                             "deflection_y_at_50ke": 0.002})
    assert not contradiction("brighter_fatter", {"deflection_x_at_50ke": 0.004,
                                                 "deflection_y_at_50ke": 0.01})
    assert contradiction("dark_current", {"dark_e": -3.0})
    assert contradiction("excess_read_noise", {"excess_variance_e2": -5.0})
    assert contradiction("diagonal_ipc", {"alpha_diag": 0.001}) is None


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
        "diagonal_ipc": {"alpha_diag": 0.002},
        "brighter_fatter": {"deflection_x_at_50ke": 0.01, "deflection_y_at_50ke": 0.03,
                            "upwind": 0.5, "reach": 0.2},
        "reciprocity_failure": {"alpha_per_decade": 0.01}, "excess_read_noise":
        {"excess_variance_e2": 60.0},
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


def test_response_map_is_shared_by_the_pairs_of_a_file(cpu, rng):
    # flat_field: one map per file; two pairs of one file covary by u a1 a2,
    # a^2 = sum_q J_pq^2 C_q^2: the map's noise is smoothed by IPC (about
    # 1 - 8 alpha of u mean^2 inside a flat area)
    scene = np.stack([_scene(rng), _scene(rng)])
    u = 0.02 ** 2
    model = DetectorModel("donlon2018", 5.0, effects={"flat_field": {"response_variance": u}})
    mean, var = model.predict(scene)
    _, var0, a = model.predict_parts(scene)
    np.testing.assert_allclose(var - var0, u * a ** 2)
    inside = (slice(None), slice(16, 19), slice(16, 19))  # the 30 ke- patch's interior
    assert np.all(a[inside] ** 2 / mean[inside] ** 2 < 0.95)
    sims = np.stack([model.simulate(scene, rng) for _ in range(300)])
    r = sims - mean
    bright = mean[0] > 20000
    cov = np.mean(r[:, 0][:, bright] * r[:, 1][:, bright], axis=0)
    expect = u * a[0][bright] * a[1][bright]
    assert np.mean(cov) / np.mean(expect) == pytest.approx(1.0, abs=0.15)
    ratio = np.var(r, axis=0, ddof=1) / var
    assert abs(ratio.mean() - 1.0) < 0.05


def test_model_rejects_unknown_effect():
    with pytest.raises(ValueError, match="unknown effect"):
        DetectorModel("donlon2018", 10.0, effects={"cosmic_rays": {}})

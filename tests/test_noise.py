"""Noise through the decoupler (ipc_taichi.noise): the Jacobian against the
coupling kernels, G against a dense inverse, and Monte Carlo runs of the
decoupler on noisy frames (a rate-like frame and a ramp)."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import jacobian, noise
from ipc_taichi.errors import IPCInputError
from ipc_taichi.geometry import Geometry
from ipc_taichi.laws import TabulatedLaw, donlon2018
from ipc_taichi.model import CouplingModel

SHAPE = (48, 48)
DRAWS = 2000


def _dense(stencil, shape):
    """A stencil ``{(dy, dx): array}`` as a dense matrix on the flattened frame."""
    ny, nx = shape
    out = np.zeros((ny * nx, ny * nx))
    for (oy, ox), a in stencil.items():
        for y in range(ny):
            for x in range(nx):
                if 0 <= y + oy < ny and 0 <= x + ox < nx:
                    out[y * nx + x, (y + oy) * nx + x + ox] += a[y, x]
                else:
                    assert a[y, x] == 0.0
    return out


def _probed_jacobian(x, model, mask, eps=0.01):
    """dC/dx column by column, by central differences of ipc_taichi.couple."""
    cols = []
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = eps
        e = e.reshape(x.shape)
        up = ipc_taichi.couple(x + e, model=model, mask=mask)
        down = ipc_taichi.couple(x - e, model=model, mask=mask)
        cols.append(((np.asarray(up) - np.asarray(down)) / (2 * eps)).ravel())
    return np.stack(cols, axis=1)


def _models():
    asym = Geometry({(0, 1): 1.0, (0, -1): 0.8, (1, 0): 0.9, (-1, 0): 1.1, (1, 1): 0.1,
                     (0, 2): 0.05, (-2, 0): 0.07})
    table = TabulatedLaw.from_callable(donlon2018().alpha, (0.0, 65535.0), n=65)
    return [CouplingModel.resolve("donlon2018", None, "zero"),
            CouplingModel.resolve("donlon2018", None, "isolated"),
            CouplingModel.resolve("donlon2018_printed", asym, "zero"),
            CouplingModel.resolve(table, None, "zero")]


@pytest.mark.parametrize("model", _models(), ids=["zero", "isolated", "asymmetric", "table"])
def test_jacobian_is_the_derivative_of_the_coupling_kernels(cpu, model):
    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 60000.0, (8, 9))
    mask = np.zeros(x.shape, bool)
    mask[2, 2] = mask[0, 6] = mask[4, 5] = True
    jac = jacobian.jacobian(np.where(mask, 0.0, x), model, ~mask)
    expected = _probed_jacobian(x, model, mask)
    assert np.abs(_dense(jac, x.shape) - expected).max() < 1e-7


@pytest.mark.parametrize("model", _models()[:3], ids=["zero", "isolated", "asymmetric"])
def test_variance_matches_the_dense_inverse(model):
    rng = np.random.default_rng(4)
    x = rng.uniform(0.0, 60000.0, (10, 11))
    x[4, 5] = np.nan                        # a bad pixel, as the decoupler leaves it
    mask = np.zeros(x.shape, bool)
    mask[2, 2] = mask[0, 7] = True
    v = rng.uniform(10.0, 1000.0, x.shape)
    v[2, 2] = np.nan                        # a flagged pixel's variance may be NaN
    valid = np.isfinite(x) & ~mask
    g = np.linalg.inv(_dense(jacobian.jacobian(np.where(valid, x, 0.0), model, valid), x.shape))
    exact = (g ** 2 @ np.where(valid, v, 0.0).ravel()).reshape(x.shape)
    for reach, tol in ((1, 1e-3), (2, 1e-5)):
        got = noise.linearise(x, model, mask=mask, reach=reach).variance(v)
        assert np.abs(got[valid] / exact[valid] - 1).max() < tol
        assert np.array_equal(got[~valid], v[~valid], equal_nan=True)  # returned unchanged


def test_neumann_truncation_stays_within_its_bound():
    rng = np.random.default_rng(5)
    x = rng.uniform(0.0, 60000.0, (20, 20))
    rough = noise.linearise(x, "donlon2018", tol=1e-3)
    fine = noise.linearise(x, "donlon2018", tol=1e-13)
    assert 0 < rough.terms < fine.terms
    assert rough.bound <= 1e-3 and fine.bound <= 1e-13
    error = np.abs(rough.stencil - fine.stencil).max()
    assert error <= rough.bound + 1e-13
    assert error > rough.bound / 1e3        # the bound is not vacuous


def test_masked_pixels_keep_their_variance_and_add_none_to_neighbours():
    x = np.full((12, 12), 500.0)
    x[6, 6] = 40000.0
    mask = np.zeros(x.shape, bool)
    mask[6, 6] = True
    v = np.full(x.shape, 300.0)
    lin = noise.linearise(x, "donlon2018", mask=mask)
    a = lin.variance(v)
    v2 = v.copy()
    v2[6, 6] = 1e9
    b = lin.variance(v2)
    assert b[6, 6] == 1e9
    assert np.array_equal(np.delete(a.ravel(), 6 * 12 + 6), np.delete(b.ravel(), 6 * 12 + 6))
    # without the mask the hot pixel's variance reaches its neighbours
    assert noise.linearise(x, "donlon2018").variance(v2)[6, 7] > 2 * a[6, 7]


def test_units_variance_in_data_units_propagated_in_electrons():
    rng = np.random.default_rng(6)
    charge = rng.uniform(100.0, 50000.0, (16, 16))       # decoupled frame, electrons
    var_e = rng.uniform(50.0, 5000.0, charge.shape)      # electrons^2
    gain = rng.uniform(1.5, 2.5, charge.shape)           # e-/DN, per pixel
    in_e = noise.propagate_variance(var_e, charge, "donlon2018")
    in_dn = noise.propagate_variance(var_e / gain ** 2, charge / gain, "donlon2018", scale=gain)
    assert np.allclose(in_dn * gain ** 2, in_e, rtol=1e-12)
    # the law sees electrons: handing DN without the scale is a different answer
    wrong = noise.propagate_variance(var_e / gain ** 2, charge / gain, "donlon2018")
    assert np.abs(wrong * gain ** 2 / in_e - 1).max() > 1e-3
    # a rate: DN/s with gain and integration time, as the product's charge scale
    scale = 2.0 * 50.0
    rate = noise.propagate_variance(var_e / scale ** 2, charge / scale, "donlon2018", scale=scale)
    assert np.allclose(rate * scale ** 2, in_e, rtol=1e-12)


def test_pedestal_is_charge_on_the_node():
    """With a pedestal (electrons) the law is evaluated at solution * scale + pedestal."""
    rng = np.random.default_rng(12)
    sol = rng.uniform(0.0, 20000.0, (12, 12))          # DN since the pedestal
    pedestal = rng.uniform(5000.0, 15000.0, sol.shape)  # electrons
    a = noise.linearise(sol, "donlon2018", scale=2.0, pedestal=pedestal)
    b = noise.linearise(sol + pedestal / 2.0, "donlon2018", scale=2.0)
    c = noise.linearise(sol, "donlon2018", scale=2.0)
    assert np.allclose(a.stencil, b.stencil, rtol=0, atol=1e-12)
    assert np.abs(a.stencil - c.stencil).max() > 1e-4


def test_messages():
    lin = noise.linearise(np.ones((4, 4)), "donlon2018")
    with pytest.raises(IPCInputError) as exc:
        lin.variance(np.ones((4, 4)), "shot")
    assert str(exc.value) == "stage must be one of readout, collected, got 'shot'"
    with pytest.raises(IPCInputError) as exc:
        lin.variance(np.ones((4, 4)), "collected")
    assert str(exc.value) == "stage 'collected' needs the measured frame and the solution"
    with pytest.raises(IPCInputError) as exc:
        lin.variance(np.ones((4, 5)))
    assert str(exc.value) == "variance of shape (4, 5) does not fit the frame (4, 4)"
    assert len(noise.METHOD) <= 68       # fits a FITS card value


# --- Monte Carlo -----------------------------------------------------------------------------


def _scene(rng):
    """A rate-like scene in electrons: sky, three stars, hot pixels (two on the edge)."""
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    s = np.full(SHAPE, 150.0)
    for cy, cx, peak in ((12, 30, 20000.0), (33, 14, 8000.0), (30, 36.4, 30000.0)):
        s += peak * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * 1.1 ** 2))
    for (y, x), q in (((5, 5), 45000.0), ((40, 40), 30000.0), ((0, 20), 40000.0),
                      ((20, 47), 25000.0), ((24, 24), 50000.0)):
        s[y, x] = q
    mask = np.zeros(SHAPE, bool)
    mask[24, 24] = True                    # a flagged hot pixel
    return s, mask


def _pooled(mc_var, predicted, size=30, draws=DRAWS):
    """sigma_MC / sigma_predicted pooled over groups of ``size`` pixels of similar
    predicted variance (the MC's own error on each: ``sqrt(2 / (size (draws - 1))) / 2``,
    0.29 % for 30 pixels and 2000 draws), and the largest per-pixel deviation in
    units of the MC's own error on one pixel's variance (``sqrt(2 / (draws - 1))``)."""
    order = np.argsort(predicted.ravel())
    a, b = mc_var.ravel()[order], predicted.ravel()[order]
    n = a.size // size * size
    ratio = np.sqrt(a[:n].reshape(-1, size).sum(1) / b[:n].reshape(-1, size).sum(1))
    z = (a / b - 1) / np.sqrt(2.0 / (draws - 1))
    return ratio, np.abs(z).max()


def _decouple(measured_e, model, mask):
    return np.asarray(ipc_taichi.decouple(measured_e, model=model, mask=mask))


@pytest.mark.parametrize("law, edge", [("donlon2018", "zero"), ("constant:0.0145", "isolated")])
def test_readout_noise_monte_carlo(cpu, law, edge):
    """Independent noise added to the measured frame (the stage's assumption),
    as large and as structured as shot noise: propagated sigma within 2 %."""
    rng = np.random.default_rng(7)
    model = CouplingModel.resolve(law, None, edge)
    s, mask = _scene(rng)
    mean = np.asarray(ipc_taichi.couple(s, model=model, mask=mask))
    var = mean + 10.0 ** 2
    y = mean + rng.normal(size=(DRAWS,) + SHAPE) * np.sqrt(var)
    x = _decouple(y, model, mask)
    predicted = noise.propagate_variance(var, x[0], model, mask=mask)
    ratio, zmax = _pooled(x.var(axis=0, ddof=1), predicted)
    assert np.abs(ratio - 1).max() < 0.02
    assert zmax < 5.5
    assert predicted[24, 24] == var[24, 24]
    # the unchanged variance is not the answer (the test can fail)
    unchanged, _ = _pooled(x.var(axis=0, ddof=1), var)
    assert np.abs(unchanged - 1).max() > 0.04


def test_rate_frame_monte_carlo(cpu):
    """Shot noise in the collected charge, read noise after the coupling; data in
    DN/s (gain 2 e-/DN, 50 s): ERR, VAR_POISSON, VAR_RNOISE through propagate_noise."""
    rng = np.random.default_rng(8)
    model = CouplingModel.resolve("donlon2018", None, "zero")
    scale = 2.0 * 50.0
    s, mask = _scene(rng)
    shot = rng.poisson(s, size=(DRAWS,) + SHAPE).astype(float)
    read = 6.0
    y_e = np.asarray(ipc_taichi.couple(shot, model=model, mask=mask))
    y_e += rng.normal(0.0, read, y_e.shape)
    x = _decouple(y_e, model, mask) / scale
    y = y_e / scale
    var_poisson = np.asarray(ipc_taichi.couple(s, model=model, mask=mask)) / scale ** 2
    var_rnoise = np.full(SHAPE, read ** 2 / scale ** 2)
    err = np.sqrt(var_poisson + var_rnoise)
    out = noise.propagate_noise(x[0], model, measured=y[0], err=err, var_poisson=var_poisson,
                                var_rnoise=var_rnoise, mask=mask, scale=scale)
    mc = x.var(axis=0, ddof=1)
    ratio, zmax = _pooled(mc, out["err"] ** 2)
    assert np.abs(ratio - 1).max() < 0.02
    assert zmax < 5.5
    assert np.allclose(out["err"] ** 2, out["var_poisson"] + out["var_rnoise"], rtol=1e-9)
    assert out["err"][24, 24] == err[24, 24]
    # the neighbours of the unflagged hot pixels: pooled, 14 pixels (MC error 0.4 %)
    near = [(4, 5), (6, 5), (5, 4), (5, 6), (39, 40), (41, 40), (40, 39), (40, 41),
            (1, 20), (0, 19), (0, 21), (19, 47), (21, 47), (20, 46)]
    rows, cols = np.array(near).T
    sigma = np.sqrt(mc[rows, cols].sum() / (out["err"][rows, cols] ** 2).sum())
    assert abs(sigma - 1) < 0.02
    assert np.sqrt((err[rows, cols] ** 2).sum() / mc[rows, cols].sum()) > 1.3  # input ERR
    # shot noise taken as readout noise is too large by ~8 alpha on the sky
    as_readout = noise.propagate_variance(var_poisson + var_rnoise, x[0], model, mask=mask,
                                          scale=scale)
    sky = s < 151.0
    excess = np.sqrt(as_readout[sky].sum() / mc[sky].sum()) - 1
    assert 0.04 < excess < 0.07


def test_ramp_monte_carlo(cpu):
    """Four groups of a ramp (cumulative shot noise, read noise in each group, DN with
    gain 2), decoupled group by group as one stack: per-group ERR within 2 %."""
    rng = np.random.default_rng(9)
    model = CouplingModel.resolve("donlon2018", None, "zero")
    gain, groups, read = 2.0, 4, 8.0
    s, mask = _scene(rng)
    per_group = s / groups
    q = np.cumsum(rng.poisson(per_group, size=(DRAWS // 2, groups) + SHAPE), axis=1)
    y_e = np.asarray(ipc_taichi.couple(q.reshape((-1,) + SHAPE).astype(float), model=model,
                                       mask=mask)).reshape(q.shape)
    y_e += rng.normal(0.0, read, y_e.shape)
    x = _decouple(y_e.reshape((-1,) + SHAPE), model, mask).reshape(q.shape) / gain
    y = y_e / gain
    means = np.cumsum(np.broadcast_to(per_group, (groups,) + SHAPE), axis=0)
    var_poisson = np.asarray(ipc_taichi.couple(means, model=model, mask=mask)) / gain ** 2
    err = np.sqrt(var_poisson + read ** 2 / gain ** 2)
    got = noise.propagate_error(err, x[0], model, var_poisson=var_poisson, measured=y[0],
                                mask=mask, scale=gain)
    assert np.array_equal(got[:, 24, 24], err[:, 24, 24])  # the flagged pixel, every group
    one = noise.propagate_error(err[2], x[0, 2], model, var_poisson=var_poisson[2],
                                measured=y[0, 2], mask=mask, scale=gain)
    assert np.array_equal(one, got[2])
    for k in range(groups):
        ratio, zmax = _pooled(x[:, k].var(axis=0, ddof=1), got[k] ** 2, size=60,
                               draws=x.shape[0])
        assert np.abs(ratio - 1).max() < 0.02, k
        assert zmax < 5.5


def test_neighbour_covariance_monte_carlo(cpu):
    """Decoupled white read noise is anti-correlated between nearest neighbours
    (about -2 alpha); the covariance function agrees with a Monte Carlo."""
    rng = np.random.default_rng(10)
    model = CouplingModel.resolve("constant:0.0145", None, "zero")
    s = np.full((24, 24), 1000.0)
    y = s[None] + rng.normal(0.0, 20.0, (4 * DRAWS, 24, 24))
    x = _decouple(y, model, None)
    x -= x.mean(axis=0)
    cov = noise.neighbour_covariance(np.full(s.shape, 400.0), s, model)
    inner = (slice(2, -2), slice(2, -2))
    for k, (dy, dx) in enumerate(noise.NEIGHBOUR_OFFSETS):
        shifted = np.roll(x, (-dy, -dx), axis=(1, 2))
        mc = (x * shifted).mean(axis=0)[inner].mean()
        assert abs(mc - cov[k][inner].mean()) < 0.002 * 400.0
    right = noise.NEIGHBOUR_OFFSETS.index((0, 1))
    assert -2.6 * 0.0145 < cov[right][inner].mean() / 400.0 < -2.0 * 0.0145


def test_bands_give_the_whole_frames_answer(monkeypatch):
    """Large frames are linearised in bands of rows with a halo (bounded memory)."""
    rng = np.random.default_rng(11)
    x = rng.uniform(0.0, 60000.0, (90, 30))
    x[40, 5] = np.nan
    mask = np.zeros(x.shape, bool)
    mask[31:34, 10] = True
    whole = noise.linearise(x, "donlon2018", mask=mask)
    monkeypatch.setattr(jacobian, "_BAND", 16)
    banded = noise.linearise(x, "donlon2018", mask=mask)
    assert np.abs(whole.stencil - banded.stencil).max() <= 2 * max(whole.bound, banded.bound)

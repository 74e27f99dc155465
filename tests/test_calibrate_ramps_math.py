"""Flat ramps (calibrate.ramps): the sums, the covariance model and the joint fit.

The synthetic ramps here are made by a collection loop written in this file:
each group is collected in a few steps, each step Poisson at the rate set by
the charge at its start (brighter-fatter), then read through a constant
coupling kernel, a quadratic non-linearity, a bias and read noise.
"""

import numpy as np
import pytest

from ipc_taichi.calibrate import rampmodel, ramps
from ipc_taichi.calibrate.flats import TERMS, kernel_autocorrelation
from ipc_taichi.calibrate.ramps import SYMMETRIC_LAGS, FlatRamps

BF = 1e-6 * np.array([[0.0, 0.0, 0.2, 0.0, 0.0],
                      [0.0, 1.0, 4.0, 1.0, 0.0],
                      [0.2, 5.0, -22.8, 5.0, 0.2],
                      [0.0, 1.0, 4.0, 1.0, 0.0],
                      [0.0, 0.0, 0.2, 0.0, 0.0]])
"""A strong brighter-fatter kernel (x: 5e-6, y: 4e-6 per e-; sum 0)."""


def _neighbours(image, kernel):
    """``sum_d kernel[2 + dy][2 + dx] image(p + d)`` on a periodic frame."""
    out = np.zeros_like(image)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            if kernel[2 + dy, 2 + dx]:
                out += kernel[2 + dy, 2 + dx] * np.roll(image, (-dy, -dx), axis=(-2, -1))
    return out


def _ramps(seed, *, nints=4, ngroups=8, shape=(128, 128), current=2000.0, steps=4, bf=BF,
           k=(0.01, 0.012, 0.0, 0.0, 0.0), beta=2e-6, read_noise=5.0, response=0.02):
    """Flat ramps [e-] from the collection loop (see the module docstring)."""
    rng = np.random.default_rng(seed)
    gain_pattern = 1.0 + response * rng.standard_normal(shape)
    bias = 1000.0 + 50.0 * rng.standard_normal(shape)
    coupling = ramps.kernel_from_symmetric([0.0, *k, 0.0, 0.0, 0.0])
    coupling[2, 2] = 1.0 - coupling.sum()
    out = np.empty((nints, ngroups) + shape)
    for i in range(nints):
        q = np.zeros(shape)
        out[i, 0] = q
        for g in range(1, ngroups):
            for _ in range(steps):
                rate = current / steps * gain_pattern * (1.0 + _neighbours(q, bf))
                q = q + rng.poisson(rate)
            out[i, g] = q
    measured = _neighbours(out, coupling)
    measured -= beta * measured ** 2
    return measured + bias + read_noise * rng.standard_normal(out.shape)


@pytest.fixture(scope="module")
def bf_ramps():
    """Ramps with brighter-fatter, IPC, non-linearity and a pixel-response pattern."""
    return _ramps(11)


@pytest.fixture(scope="module")
def bf_measured(bf_ramps):
    flat = FlatRamps.from_ramps(bf_ramps, collection_steps=4)
    return flat, flat.measure()


# ---- the sums ------------------------------------------------------------------------

def test_sums_match_a_direct_computation():
    """Per-block sums of d_k(p) d_l(p + delta) == a loop over pixel pairs."""
    rng = np.random.default_rng(3)
    nints, ngroups, ny, nx = 3, 5, 22, 19
    cube = 100.0 * rng.standard_normal((nints, ngroups, ny, nx)) + np.arange(ngroups)[:, None,
                                                                                        None]
    mask = np.zeros(cube.shape, bool)
    mask[1, 2, 7, 8] = True
    cube[0, 3, 12, 4] = np.nan
    flat = FlatRamps.from_ramps(cube, mask, border=2, blocks=(2, 2))

    good = np.ones((ny, nx), bool)
    good[7, 8] = good[12, 4] = False
    good[:2] = good[-2:] = good[:, :2] = good[:, -2:] = False
    d = np.diff(np.where(good, cube, 0.0), axis=1)
    resid = (d - d.mean(axis=0)) * np.sqrt(nints / (nints - 1))
    resid -= resid[:, :, good].mean(axis=2)[:, :, None, None]
    resid[:, :, ~good] = 0.0
    rows, cols = (0, 11, 22), (0, 10, 19)  # np.linspace(0, n, 3).round()
    for block, (by, bx) in enumerate([(0, 0), (0, 1), (1, 0), (1, 1)]):
        total = np.zeros((9, ngroups - 1, ngroups - 1))
        pairs = np.zeros(9)
        for dy, dx in ramps.LAGS:
            c = SYMMETRIC_LAGS.index((abs(dy), abs(dx)))
            for y in range(rows[by], rows[by + 1]):
                for x in range(cols[bx], cols[bx + 1]):
                    if not (good[y, x] and 0 <= y + dy < ny and 0 <= x + dx < nx
                            and good[y + dy, x + dx]):
                        continue
                    for i in range(nints):
                        outer = np.outer(resid[i, :, y, x], resid[i, :, y + dy, x + dx])
                        total[c] += outer + outer.T
                        pairs[c] += 1
        got = flat.covariances([block])
        np.testing.assert_allclose(got["pairs"], pairs)
        np.testing.assert_allclose(got["cov"], total / (2 * pairs[:, None, None]),
                                   rtol=1e-10, atol=1e-9)


def test_saturated_reads_are_not_used():
    cube = _ramps(5, nints=2, ngroups=6, shape=(48, 48), bf=np.zeros((5, 5)))
    flat = FlatRamps.from_ramps(cube, saturation=1000.0 + 4.5 * 2000.0, blocks=(2, 2))
    assert flat.n_groups == 5
    assert any("saturation" in n for n in flat.notes)


# ---- the model -----------------------------------------------------------------------

def _params(**kw):
    p = {"r": 1.0, "s2": 0.0, "k0": np.zeros(5), "k1": np.zeros(5), "a": np.zeros(9),
         "pattern": None}
    p.update(kw)
    return p


def test_constant_ipc_without_brighter_fatter_is_exact():
    """No brighter-fatter, no non-linearity: later increments are uncorrelated (but
    for -sigma^2 between neighbours in time) and C_kk = (I/r) K*K + 2 sigma^2."""
    k0 = np.array([0.011, 0.013, 0.001, 0.0004, 0.0002])
    current, r, s2 = 1500.0, 1.2, 40.0
    model = rampmodel.RampCovariance(7, current, 0.0)
    cov = model.increments(_params(r=r, s2=s2, k0=k0))
    for c, lag in enumerate(SYMMETRIC_LAGS):
        same = current / r * kernel_autocorrelation(k0, lag) + (2 * s2 if c == 0 else 0.0)
        np.testing.assert_allclose(np.diagonal(cov[:, :, c]), same, rtol=1e-12,
                                   atol=1e-12 * current)
        later = cov[:, :, c][np.triu_indices(6, 1)]
        expect = np.where(np.triu_indices(6, 1)[1] - np.triu_indices(6, 1)[0] == 1,
                          -s2 if c == 0 else 0.0, 0.0)
        np.testing.assert_allclose(later, expect, atol=1e-9 * current)
    # the "covariance is twice alpha times the variance" rule, to first order
    ratio = cov[0, 0, 1] / (cov[0, 0, 0] - 2 * s2)
    assert ratio == pytest.approx(2 * k0[0], rel=0.1)


def _convolution_matrix(kernel, n):
    """(n^2, n^2) matrix of ``sum_d kernel(d) x(p + d)`` on a periodic n x n grid."""
    eye = np.eye(n * n).reshape(n * n, n, n)
    return _neighbours(eye, kernel).reshape(n * n, n * n).T


@pytest.mark.parametrize("steps", [None, 3])
def test_model_equals_real_space_linear_response(steps):
    """The Fourier model == the same linear response built in real space (20 x 20
    periodic grid, brighter-fatter by explicit matrix powers / eigenvectors)."""
    n, groups, current, r, beta, s2 = 20, 5, 1800.0, 1.07, 1.5e-6, 30.0
    k0 = np.array([0.01, 0.012, 0.001, 0.0005, 0.0003])
    k1 = np.array([2e-7, 1e-7, 3e-8, 0.0, -1e-8])
    a = 3 * ramps.symmetric_from_kernel(BF)
    p = _params(r=r, s2=s2, k0=k0, k1=k1, a=a)
    got = rampmodel.RampCovariance(groups, current, beta, steps).increments(p)

    growth = r * current * _convolution_matrix(ramps.kernel_from_symmetric(a), n)
    lam, vec = np.linalg.eigh(growth)
    t = np.arange(groups)
    J = []
    for i in range(groups):
        K = ramps.kernel_from_symmetric([0.0, *(k0 + k1 * current * t[i]), 0, 0, 0])
        K[2, 2] = 1.0 - K.sum()
        J.append((1 - 2 * beta * current * t[i]) * _convolution_matrix(K, n))
    reads = np.empty((groups, groups, n * n))  # row of pixel 0 of Cov(M_i, M_j)
    for i in range(groups):
        for j in range(groups):
            lo, hi = min(t[i], t[j]), max(t[i], t[j])
            if steps is None:
                den = np.where(np.abs(lam) > 0, 2 * lam, 1.0)
                w = np.where(np.abs(lam) > 0, np.expm1(2 * lam * lo) / den, lo)
                diag = np.exp(lam * (hi - lo)) * w
            else:  # sum over the collection steps of (1 + G)^(N_i - m) (1 + G)^(N_j - m)
                g1 = 1.0 + lam / steps
                diag = sum(g1 ** (steps * lo - m) * g1 ** (steps * hi - m)
                           for m in range(1, steps * lo + 1)) / steps
            row = ((J[i][0] @ vec) * diag * current / r) @ vec.T  # J_i S_ij, row 0
            reads[i, j] = row @ J[j].T + (s2 * (np.arange(n * n) == 0) if i == j else 0.0)
    inc = reads[1:, 1:] - reads[1:, :-1] - reads[:-1, 1:] + reads[:-1, :-1]
    for c, (dy, dx) in enumerate(SYMMETRIC_LAGS):
        expect = inc[:, :, dy * n + dx]
        np.testing.assert_allclose(got[:, :, c], expect, rtol=1e-9,
                                   atol=1e-9 * current)


def test_brighter_fatter_adds_kka_to_every_pair():
    """To first order every pair of increments gets I^2 (K*K*a)(delta)."""
    from scipy.signal import convolve2d

    k0 = np.array([0.01, 0.01, 0.0, 0.0, 0.0])
    a = 0.01 * ramps.symmetric_from_kernel(BF)  # weak: first order holds
    current = 2000.0
    model = rampmodel.RampCovariance(6, current, 0.0)
    with_bf = model.increments(_params(k0=k0, a=a))
    without = model.increments(_params(k0=k0))
    K = ramps.kernel_from_symmetric([0.0, *k0, 0, 0, 0])
    K[2, 2] = 1 - K.sum()
    kka = convolve2d(convolve2d(K, K), ramps.kernel_from_symmetric(a))  # 13 x 13, centre 6
    for c, (dy, dx) in enumerate(SYMMETRIC_LAGS):
        extra = (with_bf - without)[:, :, c][np.triu_indices(5)]
        np.testing.assert_allclose(extra, current ** 2 * kka[6 + dy, 6 + dx], rtol=0.01,
                                   atol=1e-3 * current ** 2 * abs(kka[6, 7]))


# ---- the fit -------------------------------------------------------------------------

def test_fit_recovers_brighter_fatter_ipc_and_nonlinearity(bf_measured):
    _, m = bf_measured
    bf = m["brighter_fatter"]
    kernel, err = np.array(bf["kernel"]), np.array(bf["kernel_error"])
    assert bf["measured"] and bf["detected"] and bf["significance"] > 5
    for (y, x), truth in (((2, 3), 5e-6), ((3, 2), 4e-6), ((3, 3), 1e-6), ((2, 2), -22.8e-6)):
        assert abs(kernel[y, x] - truth) < 4 * err[y, x], (y, x, kernel[y, x], err[y, x])
        assert err[y, x] < 0.3 * abs(truth) or (y, x) == (3, 3)
    for i, truth in enumerate((0.01, 0.012, 0.0, 0.0, 0.0)):
        term = m["ipc"]["terms"][TERMS[i]]
        assert abs(term["value"] - truth) < 4 * term["error"], (TERMS[i], term)
    assert not m["nonlinear_ipc"]["detected"]
    nl = m["classical_nonlinearity"]
    assert nl["detected"] and abs(nl["beta"] - 2e-6) < 4 * nl["error"]
    assert abs(m["gain_ratio"]["value"] - 1.0) < 4 * m["gain_ratio"]["error"]
    assert abs(m["read_noise"]["value"] - 5.0) < 4 * m["read_noise"]["error"]
    assert 0.7 < m["chi2_per_dof"] < 1.5
    # brighter-fatter explains the data, non-linear IPC alone does not
    chi2 = m["covariance_curves"]["chi2_per_dof"]
    assert chi2["brighter_fatter"] < chi2["nonlinear_ipc"] - 0.2


def test_subset_of_blocks_and_given_read_noise(bf_measured):
    flat, m = bf_measured
    part = flat.measure(blocks=range(8), read_noise=5.0)
    assert part["n_pixels"] < 0.6 * m["n_pixels"]
    assert part["read_noise"] == {"value": 5.0, "error": None, "source": "given"}
    err = [r["brighter_fatter"]["kernel_error"][2][3] for r in (part, m)]
    assert err[0] > err[1]


def test_levels_are_flat_with_brighter_fatter_removed(bf_measured):
    flat, m = bf_measured
    for method in ("difference", "increments"):
        rows = flat.levels(method=method)
        assert len(rows) >= 5
        for row in rows:
            for term, truth in (("x", 0.01), ("y", 0.012)):
                v = row["terms"][term]
                assert abs(v["value"] - truth) < 4 * v["error"], (method, row["level"], v)
    # removing nothing leaves the brighter-fatter growth in (difference points rise)
    raw = flat.levels(bf_kernel=np.zeros((5, 5)), method="difference")
    assert raw[-1]["terms"]["x"]["value"] > 0.01 + 4 * raw[-1]["terms"]["x"]["error"]


def test_predict_variants(bf_measured):
    """Each variant switches off its parts; the full fit follows the measured curve."""
    flat, m = bf_measured
    p = m["params"]
    ipc = flat.predict(p, (0, 1), "ipc_only")
    level = ipc["level"]
    assert level == pytest.approx(p["current"] * np.arange(1, flat.n_groups))
    k0 = [p["k0"][t] for t in TERMS]
    expect = (1 - 2 * p["beta"] * level) ** 2 * kernel_autocorrelation(k0, (0, 1))
    np.testing.assert_allclose(ipc["value"], expect, rtol=2e-3)
    no_bf = dict(p, brighter_fatter=[0.0] * 9)
    np.testing.assert_allclose(flat.predict(no_bf, (0, -1), "brighter_fatter")["value"],
                               ipc["value"], rtol=1e-12)
    assert np.all(flat.predict(p, (0, 1), "brighter_fatter")["value"] > ipc["value"] + 0.002)
    curve = m["covariance_curves"]["lags"]["0,1"]
    resid = (np.array(curve["measured"]) - np.array(curve["full"])) / np.array(curve["error"])
    assert np.mean(resid ** 2) < 3
    assert curve["full"] == pytest.approx(flat.predict(p, (0, 1), "full")["value"].tolist())


def test_one_integration_does_not_measure_brighter_fatter(bf_ramps):
    flat = FlatRamps.from_ramps(bf_ramps[:1], collection_steps=4)
    m = flat.measure()
    bf = m["brighter_fatter"]
    assert bf["measured"] is False and bf["kernel"] is None
    assert "two integrations" in bf["note"]
    # IPC is still told apart from the (pattern + brighter-fatter) term by time
    for i, truth in enumerate((0.01, 0.012)):
        term = m["ipc"]["terms"][TERMS[i]]
        assert abs(term["value"] - truth) < 4 * term["error"], term
    row = flat.levels(method="increments")[-1]
    assert "brighter-fatter not measured" in row["notes"][0]


def test_jackknife_errors_match_the_scatter_over_seeds():
    values, errors = [], []
    for seed in range(6):
        cube = _ramps(100 + seed, nints=3, ngroups=6, shape=(72, 72), bf=np.zeros((5, 5)),
                      response=0.0)
        m = FlatRamps.from_ramps(cube, blocks=(3, 3), collection_steps=4).measure()
        values.append(m["ipc"]["terms"]["x"]["value"])
        errors.append(m["ipc"]["terms"]["x"]["error"])
        assert not m["brighter_fatter"]["detected"]
        assert not m["nonlinear_ipc"]["detected"]
    ratio = np.std(values, ddof=1) / np.sqrt(np.mean(np.square(errors)))
    assert 0.4 < ratio < 2.5, (ratio, values, errors)

"""The weighted IPC-aware forward fit on noisy frames that the fitter's PSF did not make.

No inverse crime: the frames come from a 12x oversampled optical PSF with the
stars at positions off the fitter's quarter-pixel grid, through the shared
detector chain (Poisson, coupling, read noise); the fitter only has the 4x
pixel-integrated ePSF of the same optics. Unbiased means: the mean error over
the realisations lies within a few standard errors of zero.
"""

import numpy as np
import pytest

from analysis.photometry_forward import fit_stars_forward
from analysis.psf import airy_psf, effective_psf, point_source_image
from ipc_taichi.detector import expose

O_FINE = 12
X1, Y1 = 12 + 5 / 12, 12 + 7 / 12          # off the 1/4 grid
X2, Y2 = X1 + 3 + 1 / 12, Y1 - 2 / 12
F1, F2, RN = 4.0e5, 1.0e5, 10.0
SHAPE = (25, 29)
N = 30


@pytest.fixture(scope="module")
def fits():
    fine = airy_psf(O_FINE)
    epsf = effective_psf(airy_psf(4), 1.0, stage="truth")
    scene = (point_source_image(fine, X1, Y1, SHAPE, F1, O_FINE)
             + point_source_image(fine, X2, Y2, SHAPE, F2, O_FINE))
    rng = np.random.default_rng(2018)
    init = ([X1 + 0.1, X2 - 0.1], [Y1 + 0.05, Y2 - 0.05], [1.05 * F1, 0.95 * F2])
    out = {"forward": [], "plain": [], "reported": []}
    for _ in range(N):
        measured = expose(scene, "donlon2018", RN, rng).measured
        fw = fit_stars_forward(measured, epsf, *init, read_noise=RN)
        plain = fit_stars_forward(measured, epsf, *init, law=None, read_noise=RN)
        assert np.all(fw.flags == 0)
        for key, f in (("forward", fw), ("plain", plain)):
            out[key].append([f.flux[0] / F1 - 1, f.flux[1] / F2 - 1, f.x[0] - X1, f.x[1] - X2,
                             f.y[0] - Y1, f.y[1] - Y2, (f.x[1] - f.x[0]) - (X2 - X1)])
        out["reported"].append([fw.flux_err[0] / F1, fw.flux_err[1] / F2, fw.x_err[0], fw.x_err[1],
                                fw.y_err[0], fw.y_err[1]])
    return {k: np.array(v) for k, v in out.items()}


def test_weighted_forward_fit_is_unbiased_within_its_standard_error(fits):
    err = fits["forward"]
    z = err.mean(axis=0) / (err.std(axis=0, ddof=1) / np.sqrt(N))
    assert np.all(np.abs(z) < 3.5), z


def test_reported_errors_match_the_scatter(fits):
    scatter = fits["forward"][:, :6].std(axis=0, ddof=1)
    reported = fits["reported"].mean(axis=0)
    # sqrt(2/(N-1)) ~ 26 % is the scatter's own sampling error at N = 30
    np.testing.assert_allclose(reported, scatter, rtol=0.45)


def test_same_fit_without_the_coupling_is_biased_on_the_same_frames(fits):
    err = fits["plain"]
    z = err.mean(axis=0) / (err.std(axis=0, ddof=1) / np.sqrt(N))
    assert z[6] < -2.0            # the pair pulled together, as the paper says (-2.6 sigma here)
    assert np.max(np.abs(z)) > 4.0

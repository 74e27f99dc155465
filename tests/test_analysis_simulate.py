"""Known-answer tests for analysis.simulate (the paper's flow chart) and analysis.deconvolution."""

import numpy as np
import pytest

import ipc_taichi
from analysis.deconvolution import effective_alpha, ipc_kernel, lucy_richardson, wiener_filter
from analysis.psf import optical_psf, point_source_image
from analysis.simulate import (
    MAGNITUDES,
    SATURATION,
    ZERO_POINT,
    Source,
    flux_from_mag,
    mag_from_flux,
    simulate,
)


@pytest.fixture(scope="module")
def psf():
    return optical_psf("airy", 4)


def test_flux_conserved_through_chain_without_ipc(cpu, psf):
    sources = [Source(30.0, 30.0, 22.0), Source(33.25, 27.5, 24.0)]
    sim = simulate(sources, (61, 61), psf=psf, background=0.0, dark=0.0, read_noise=0.0,
                   poisson=False, law="constant:0")
    expected = flux_from_mag(22.0) + flux_from_mag(24.0)
    # both sources lie wholly inside the frame (the PSF array spans +-20 px)
    assert sim.truth.sum() == pytest.approx(expected, rel=1e-9)
    assert np.array_equal(sim.coupled, sim.truth)
    assert np.abs(sim.decoupled - sim.truth).max() == 0.0


def test_ipc_with_isolated_edge_conserves_charge(cpu, psf):
    sim = simulate([Source(20.0, 20.0, 21.4)], (41, 41), psf=psf, read_noise=0.0, poisson=False,
                   edge="isolated", background=0.01, dark=0.0)
    assert np.abs(sim.coupled - sim.truth).max() > 100.0
    assert sim.coupled.sum() == pytest.approx(sim.truth.sum(), rel=1e-12)


def test_same_read_noise_in_truth_and_coupled(cpu, psf):
    sim = simulate([Source(16.0, 16.0, 23.1)], (33, 33), psf=psf, read_noise=25.0, seed=7)
    assert sim.read_noise.std() == pytest.approx(25.0, rel=0.1)
    ipc_only = ipc_taichi.couple(sim.signal) - sim.signal
    assert np.allclose(sim.coupled - sim.truth, ipc_only, rtol=0, atol=1e-8)


def test_poisson_statistics_of_flat_scene(cpu, psf):
    sim = simulate([], (200, 200), psf=psf, background=0.05, dark=0.0, read_noise=0.0, seed=3)
    mean = 0.05 * 1e4
    assert sim.scene.mean() == pytest.approx(mean)
    assert sim.signal.mean() == pytest.approx(mean, rel=0.005)
    assert sim.signal.var() == pytest.approx(mean, rel=0.03)  # Poisson: variance = mean
    assert np.all(sim.signal == np.round(sim.signal))


def test_simulation_is_seeded(cpu, psf):
    a = simulate([Source(10.0, 10.0, 24.0)], (21, 21), psf=psf, seed=11)
    b = simulate([Source(10.0, 10.0, 24.0)], (21, 21), psf=psf, seed=11)
    c = simulate([Source(10.0, 10.0, 24.0)], (21, 21), psf=psf, seed=12)
    assert np.array_equal(a.decoupled, b.decoupled)
    assert not np.array_equal(a.truth, c.truth)


def test_noise_free_decoupled_equals_truth(cpu):
    sim = simulate([Source(20.5, 19.75, 21.4), Source(23.0, 21.0, 23.1)], (41, 41),
                   read_noise=0.0, poisson=False, max_iter=40, tol=1e-14)
    assert np.abs(sim.coupled - sim.truth).max() > 100.0
    assert np.abs(sim.decoupled - sim.truth).max() < 1e-8 * sim.truth.max()


def test_zero_point_derivation():
    # mag 21.4 at 10 ks puts SATURATION counts in the central pixel of the JWST-like PSF
    flux = flux_from_mag(MAGNITUDES["bright"])
    peak = point_source_image(optical_psf("jwst_f405n"), 20, 20, (41, 41), flux).max()
    assert peak == pytest.approx(SATURATION, rel=1e-3)
    assert flux_from_mag(ZERO_POINT, exptime=1.0) == pytest.approx(1.0)
    assert mag_from_flux(flux_from_mag(23.1)) == pytest.approx(23.1)


def test_bad_parameters_raise(psf):
    with pytest.raises(ValueError, match="read_noise"):
        simulate([], (8, 8), psf=psf, read_noise=-1.0)
    with pytest.raises(ValueError, match="grid"):
        simulate([Source(3.1, 3.0, 22.0)], (8, 8), psf=psf)


def test_effective_alpha_of_flat_frame():
    frame = np.full((20, 30), 12345.0)
    law = ipc_taichi.get_law("donlon2018")
    assert effective_alpha(frame) == pytest.approx(float(law.alpha(12345.0, 12345.0)), rel=1e-12)


def test_linear_deconvolution_undoes_constant_ipc(cpu):
    truth = np.random.default_rng(5).uniform(1000.0, 60000.0, (96, 96))
    alpha = 0.012
    measured = ipc_taichi.couple(truth, law=f"constant:{alpha}")
    kernel = ipc_kernel(alpha)
    before = np.abs(measured - truth).mean()
    lr, clipped = lucy_richardson(measured, kernel, num_iter=30)
    wiener = wiener_filter(measured, kernel, 1e-6)
    inner = (slice(4, -4), slice(4, -4))  # Wiener is periodic at the frame edge
    assert clipped == 0
    assert np.abs(lr - truth).mean() < 0.05 * before
    assert np.abs(wiener - truth)[inner].mean() < 0.05 * before


def test_lucy_richardson_reports_negative_pixels():
    frame = np.full((16, 16), 100.0)
    frame[3, 4] = -5.0
    frame[7, 7] = -1.0
    restored, clipped = lucy_richardson(frame, ipc_kernel(0.01), num_iter=5)
    assert clipped == 2
    assert np.all(restored >= 0)


def test_wiener_balance_rule_and_zero_padded_edges(cpu):
    from analysis.deconvolution import wiener_balance

    truth = np.random.default_rng(6).uniform(1000.0, 60000.0, (96, 96))
    alpha = 0.012
    measured = ipc_taichi.couple(truth, law=f"constant:{alpha}")
    assert wiener_balance(measured, 0.0) == 0.0
    # scale-free: the rule depends on the read noise relative to the frame
    assert wiener_balance(10 * measured, 100.0) == pytest.approx(wiener_balance(measured, 10.0))
    assert wiener_balance(measured, 20.0) == pytest.approx(4 * wiener_balance(measured, 10.0))
    # zero padding gives the FFT the zeros beyond the frame that the zero edge had:
    # the edge rows are restored far better than with the periodic wrap
    kernel = ipc_kernel(alpha)
    edge = np.zeros(truth.shape, bool)
    edge[:2] = edge[-2:] = True
    edge[:, :2] = edge[:, -2:] = True
    padded = np.abs(wiener_filter(measured, kernel, 0.0) - truth)[edge].mean()
    periodic = np.abs(wiener_filter(measured, kernel, 0.0, pad=0) - truth)[edge].mean()
    assert padded < 0.2 * periodic


def test_lucy_richardson_path_equals_scikit_image_and_converges():
    from skimage.restoration import richardson_lucy

    from analysis.deconvolution import lucy_richardson_path

    truth = np.random.default_rng(8).uniform(1000.0, 60000.0, (48, 40))
    measured = ipc_taichi.couple(truth, law="constant:0.01")
    kernel = ipc_kernel(0.009)
    scale = measured.max()
    path = lucy_richardson_path(measured, kernel, (3, 12), tol=1e-9, max_iter=2000)
    for it, restored in zip(path.iterations[:2], path.restored[:2]):
        reference = richardson_lucy(measured / scale, kernel, num_iter=it, clip=False) * scale
        assert np.abs(restored - reference).max() < 1e-8 * scale
    assert path.iterations[:2] == [3, 12]
    assert path.converged and 12 < path.iterations[-1] < 2000
    # at convergence one more iteration changes nothing above the tolerance
    more = lucy_richardson_path(measured, kernel, (path.iterations[-1] + 1,))
    assert np.abs(more.restored[0] - path.restored[-1]).max() < 1e-9 * scale
    # not converged within max_iter: the last iterate is still returned, flagged
    short = lucy_richardson_path(measured, kernel, (), tol=1e-15, max_iter=5)
    assert short.iterations == [5] and not short.converged

"""The PSF studies apply IPC to detector pixels, once, never to oversampled PSF samples.

IPC couples a pixel to its neighbours on the detector; a PSF model sampled every 1/4
pixel is not a detector. A known failure elsewhere: PSF reference files that applied
the coupling kernel to the 4x oversampled samples (neighbours 1/4 pixel apart) and
applied it twice. These tests pin what analysis.psf.effective_psf (the FWHM study and
the binary-star ePSFs) and analysis.simulate.simulate (the binary-star frames) do: with
a constant alpha the coupled effective PSF must equal the 4-neighbour stencil applied
with neighbours ``oversample`` samples (one detector pixel) apart, exactly, and must
differ from the stencil at sample spacing and from coupling applied twice.
"""

import numpy as np
import pytest

import ipc_taichi
from analysis.psf import effective_psf, optical_psf, point_source_image
from analysis.simulate import Source, simulate

OVERSAMPLE = 4
ALPHA = 0.02


def stencil(a, step, alpha=ALPHA):
    """(1 - 4 alpha) a + alpha (4 neighbours ``step`` samples away), zero beyond the array."""
    p = np.pad(a, step)
    n = (p[:-2 * step, step:-step] + p[2 * step:, step:-step]
         + p[step:-step, :-2 * step] + p[step:-step, 2 * step:])
    return (1 - 4 * alpha) * a + alpha * n


def interior_gap(model, coupled, margin):
    """Largest difference over the samples ``margin`` from the edges, after matching totals
    (both are normalised to sum oversample**2; zero-edge losses differ by ~1e-9)."""
    inner = (slice(margin, -margin),) * 2
    k = coupled[inner].sum() / model[inner].sum()
    return float(np.abs(k * model - coupled)[inner].max() / coupled.max())


@pytest.fixture(scope="module")
def psf():
    return optical_psf("airy", OVERSAMPLE)


@pytest.mark.parametrize("sampling", ["integrated", "point"])
def test_effective_psf_couples_detector_pixels_once(cpu, psf, sampling):
    truth = effective_psf(psf, 1.0, "truth", oversample=OVERSAMPLE, sampling=sampling)
    coupled = effective_psf(psf, 1.0, "coupled", law=f"constant:{ALPHA}", oversample=OVERSAMPLE,
                            sampling=sampling)
    detector = interior_gap(stencil(truth, OVERSAMPLE), coupled, 2 * OVERSAMPLE)
    on_samples = interior_gap(stencil(truth, 1), coupled, 2 * OVERSAMPLE)
    twice = interior_gap(stencil(stencil(truth, OVERSAMPLE), OVERSAMPLE), coupled, 3 * OVERSAMPLE)
    assert detector < 1e-9
    # the two known mistakes are far from it: at sample spacing, or applied twice
    assert on_samples > 1e-3
    assert twice > 1e-3


def test_effective_psf_with_the_law_sees_detector_counts(cpu, psf):
    """Signal-dependent coupling must see the counts of a detector pixel (the source's
    flux integrated over the pixel), not the ~oversample**2 times smaller counts of a sample."""
    flux = 2e5
    epsf = effective_psf(psf, flux, "coupled", oversample=OVERSAMPLE)
    size = (epsf.shape[0] - 1) // OVERSAMPLE + 1
    c = size // 2
    image = point_source_image(psf, c, c, (size, size), flux, OVERSAMPLE)
    # the zero-phase samples of the effective PSF are the coupled detector image itself
    phase0 = epsf[::OVERSAMPLE, ::OVERSAMPLE]

    def normalised(a):
        return a / a[c, c]

    detector = normalised(ipc_taichi.couple(image))
    per_sample = normalised(ipc_taichi.couple(image / OVERSAMPLE ** 2))
    assert np.abs(normalised(phase0) - detector).max() < 1e-12
    # the law at sample counts (1/16 of them) couples visibly more
    assert np.abs(normalised(phase0) - per_sample).max() > 1e-4


def test_simulated_frames_couple_detector_pixels(cpu, psf):
    kw = dict(psf=psf, background=0.0, dark=0.0, read_noise=0.0, poisson=False)
    sim = simulate([Source(15.0, 15.25, 22.0)], (31, 31), law=f"constant:{ALPHA}", **kw)
    assert sim.coupled.shape == (31, 31)  # detector pixels, not samples
    expected = stencil(sim.truth, 1)
    assert np.abs(sim.coupled - expected).max() < 1e-9 * sim.truth.max()

"""The discrepancy workflow, blind, on files from an independent generator
(``tests/independent/peerlab.py``: GalSim's detector physics, and NumPy
forms that differ from the project's). The workflow sees only the FITS
file; what was hidden is known to the test alone."""

import numpy as np
import pytest

from ipc_taichi.brighterfatter import kernel_plausibility
from tests.discover_helpers import SILICON_BF, assert_complete, final, peer_report


def test_null_file_names_nothing(tmp_path_factory):
    report = peer_report(tmp_path_factory, seed=31, n=64)
    assert report["missing_effects"] == []
    assert_complete(report)


# GalSim's sensor's own kernel centre, measured with the area picture
# (ipc_taichi.brighterfatter; docs/discover.md), per electron
SILICON_CENTRE = -1.01e-6


@pytest.mark.slow  # GalSim's photon shooting with moving boundaries: 17 s of CPU
def test_peer_silicon_brighter_fatter(tmp_path_factory):
    # GalSim's SiliconSensor: pixel boundaries moved by the field of the charge
    # already collected (no diffusion); our form must fit it to the floor, and
    # its kernel must be a real detector's, with the sensor's own centre term
    report = peer_report(tmp_path_factory, seed=21, n=48, levels=(15000.0, 40000.0),
                         silicon=SILICON_BF)
    assert report["missing_effects"] == ["brighter_fatter"]
    params, _ = final(report, "brighter_fatter")
    assert params["deflection_x_at_50ke"] > 0.005 and params["deflection_y_at_50ke"] > 0.005
    kernel = np.array(report["brighter_fatter"]["kernel"])
    error = np.array(report["brighter_fatter"]["kernel_error"])
    assert kernel_plausibility(kernel, error) is None
    # measured -0.97e-6 +- 0.18e-6; the hot pixels here see 80 % of their own field
    assert kernel[2, 2] == pytest.approx(SILICON_CENTRE, rel=0.35)
    assert_complete(report)


def test_diffusion_and_squared_charge_brighter_fatter_both_named(tmp_path_factory):
    # Monte Carlo diffusion of every electron (charge generated across the
    # pixel) and a flow driven by the difference of squared charges (an
    # isolated 50 ke- pixel loses 4 %): both named, the blur width unbiased
    report = peer_report(tmp_path_factory, seed=20, n=64, mc_diffusion=0.2, squares_bf=0.04)
    assert sorted(report["missing_effects"]) == ["brighter_fatter", "charge_diffusion"]
    diff, diff_err = final(report, "charge_diffusion")
    assert abs(diff["sigma_px"] - 0.2) < max(3 * diff_err["sigma_px"], 0.01)
    bf, _ = final(report, "brighter_fatter")
    loss = 0.5 * (bf["deflection_x_at_50ke"] + bf["deflection_y_at_50ke"])
    assert loss == pytest.approx(0.04, rel=0.2)
    assert_complete(report)


def test_peer_reciprocity_failure(tmp_path_factory):
    # GalSim's addReciprocityFailure: the response rises above linear. It
    # must not come out as a non-linearity with a negative deficit.
    report = peer_report(tmp_path_factory, seed=22, n=64, reciprocity_alpha=0.01)
    assert report["missing_effects"] == ["reciprocity_failure"]
    params, errors = final(report, "reciprocity_failure")
    assert abs(params["alpha_per_decade"] - 0.01) < 3 * errors["alpha_per_decade"] + 5e-4
    assert_complete(report)


def test_misregistration_is_found_first(tmp_path_factory):
    # MEASURED made from a sky redrawn 0.3 px to the right of its SCENE
    report = peer_report(tmp_path_factory, seed=25, n=64, sky=True, shift=(0.0, 0.3))
    assert report["missing_effects"][0] == "misregistration"
    params, _ = final(report, "misregistration")
    assert params["shift_x_px"] == pytest.approx(0.3, abs=0.01)
    assert abs(params["shift_y_px"]) < 0.01
    assert report["missing_effects"] == ["misregistration"]
    # the sky's 1.8-2.8 px FWHM stars cannot be shifted exactly from their pixel
    # values alone: the verdict says so first, as a limit of SCENE, not a new effect
    assert report["complete"] is False
    assert report["unexplained"][0].startswith("misregistration is in the model, but")
    assert "limit of the data" in report["unexplained"][0]


def test_persistence_is_reported_incomplete_not_misnamed(tmp_path_factory):
    # GalSim's applyPersistence: 1 % of the previous pair's charge; no name
    # in the vocabulary fits, so the honest verdict is "incomplete"
    report = peer_report(tmp_path_factory, seed=3, n=64, persistence=(0.01,))
    assert report["complete"] is False
    assert report["final_gap"] - report["gap_floor"] > 3 * report["gap_floor_sigma"]
    assert any("after-image" in u for u in report["unexplained"]), report["unexplained"]
    for step in report["steps"]:  # no step that explains under 10 % of the excess
        assert step["explained_fraction"] >= 0.25
    from ipc_taichi.discover.report import summary_line

    assert summary_line(report).startswith("INCOMPLETE")


def test_peer_silicon_diffusion_is_our_kernel_for_light_uniform_in_its_pixel():
    # GalSim's SiliconSensor diffusion (factor 0.5, no brighter-fatter) on a
    # uniform 1x1 source: our closed form, at one sigma, gives its centre,
    # side and diagonal shares. On a star its peak is that of the star
    # convolved with the same Gaussian, which our form (charge generated
    # uniformly across each pixel) puts ~11 % too low: the limit written in
    # docs/discover.md, why GalSim's diffusion is named but left incomplete.
    import galsim
    import numpy as np
    from scipy.optimize import minimize_scalar

    from ipc_taichi.discover.effects import diffuse

    n, c = 15, 7

    def collect(profile, photons, sensor=None, seed=1):
        img = galsim.ImageD(n, n, xmin=0, ymin=0, scale=1.0)
        total = np.zeros((n, n))
        for k in range(photons // 250000):
            img.setZero()
            how = ({"method": "phot", "sensor": sensor, "poisson_flux": False,
                    "rng": galsim.BaseDeviate(seed + k)} if sensor else {"method": "auto"})
            profile.withFlux(250000).drawImage(img, center=galsim.PositionD(c, c), **how)
            total += img.array
        return total / total.sum()

    sensor = galsim.SiliconSensor(strength=1e-6, diffusion_factor=0.5, nrecalc=10 ** 9,
                                  rng=galsim.BaseDeviate(3))
    box = collect(galsim.Box(1, 1), 2000000, sensor)
    scene = collect(galsim.Box(1, 1), 250000)
    sigma = minimize_scalar(lambda s: float(np.sum((diffuse(scene, s) - box) ** 2)),
                            bounds=(0.01, 0.6), method="bounded").x
    assert 0.19 < sigma < 0.25
    ours = diffuse(scene, sigma)
    for dy, dx in ((0, 0), (0, 1), (1, 0), (1, 1), (0, 2)):
        assert ours[c + dy, c + dx] == pytest.approx(box[c + dy, c + dx], abs=6e-4)
    star = galsim.Moffat(beta=3.5, fwhm=1.8)
    shot = collect(star, 1000000, sensor)
    continuous = collect(galsim.Convolve(star, galsim.Gaussian(sigma=sigma)), 250000)
    assert shot.max() == pytest.approx(continuous.max(), rel=0.01)
    assert diffuse(collect(star, 250000), sigma).max() < 0.92 * shot.max()

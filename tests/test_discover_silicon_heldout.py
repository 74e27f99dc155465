"""GalSim's silicon sensor on held-out files of another session (issue 38's
pixel-total must-show, re-checked on new seeds, fluxes and strengths; the
files of ``tests/test_discover_silicon.py`` are seeds 64-66). What is
asserted is what was measured (the helper's report, "held-out GalSim files"):
the cases that file lacks, top-hat hot pixels and the ``OVERSAMP`` twin of
brighter-fatter beside diffusion, and seed 133 (the same sensor as seed 132,
mixed hot pixels), which named ``misregistration``, ``signal_dependent_ipc``
and ``diagonal_ipc`` on pixel totals and never the diffusion until a shift
had to keep half its evidence beside the strongest candidate to go first
(``gates.choose``). Marked ``slow``: GalSim's photon shooting, 10-70 s a
file."""

import pytest

from tests.discover_helpers import assert_complete, peer_report

BF = {"strength": 1.1, "diffusion_factor": 0.0, "nrecalc": 10000}
BF_DIFFUSION = {"strength": 1.0, "diffusion_factor": 0.5, "nrecalc": 10000}
DIFFUSION = {"strength": 1e-6, "diffusion_factor": 0.5, "nrecalc": 10 ** 9}
FILE = {"n": 48, "pairs": 1}


@pytest.mark.slow
def test_silicon_brighter_fatter_top_hat_pixel_totals(tmp_path_factory):
    """Seed 121, strength 1.1, 15/42 ke-, top-hat hot pixels: brighter_fatter
    alone on pixel totals, complete (measured 14.60 -> 1.022, floor 1.009 +-
    0.032); the twin the same (1.023, floor 0.986 +- 0.031)."""
    for oversample in (5, 1):
        report = peer_report(tmp_path_factory, seed=121, silicon=BF, hot="tophat",
                             levels=(15000.0, 42000.0), oversample=oversample, **FILE)
        assert report["missing_effects"] == ["brighter_fatter"]
        assert_complete(report)


@pytest.mark.slow
def test_silicon_diffusion_top_hat_is_never_brighter_fatter(tmp_path_factory):
    """Seed 141, diffusion 0.5, 16/40 ke-, top-hat hot pixels: charge_diffusion
    alone (sigma 0.219 px, the twin's 0.220), incomplete on pixel totals with
    the sub-pixel entry, complete on the twin."""
    twin = peer_report(tmp_path_factory, seed=141, silicon=DIFFUSION, hot="tophat",
                       levels=(16000.0, 40000.0), oversample=5, **FILE)
    assert twin["missing_effects"] == ["charge_diffusion"]
    assert_complete(twin)
    report = peer_report(tmp_path_factory, seed=141, silicon=DIFFUSION, hot="tophat",
                         levels=(16000.0, 40000.0), **FILE)
    assert report["missing_effects"] == ["charge_diffusion"]
    assert report["complete"] is False
    assert any(u.startswith("charge_diffusion is in the model, but") for u in
               report["unexplained"])


@pytest.mark.slow
def test_silicon_brighter_fatter_and_diffusion_twin_names_both(tmp_path_factory):
    """Seed 132, strength 1.0 with diffusion 0.5, 13/36 ke-, pinhole hot
    pixels: the OVERSAMP twin names charge_diffusion and brighter_fatter,
    complete (0.980, floor 1.000 +- 0.035); pixel totals name the diffusion,
    nothing of the coupling, and say the sub-pixel light is unknown."""
    twin = peer_report(tmp_path_factory, seed=132, silicon=BF_DIFFUSION, hot="point",
                       levels=(13000.0, 36000.0), oversample=5, **FILE)
    assert twin["missing_effects"] == ["charge_diffusion", "brighter_fatter"]
    assert_complete(twin)
    report = peer_report(tmp_path_factory, seed=132, silicon=BF_DIFFUSION, hot="point",
                         levels=(13000.0, 36000.0), **FILE)
    assert report["missing_effects"] == ["charge_diffusion"]
    assert report["complete"] is False
    assert any("OVERSAMP" in u or u.startswith("charge_diffusion is in the model, but")
               for u in report["unexplained"])


@pytest.mark.slow
def test_silicon_diffusion_is_not_taken_for_a_shift(tmp_path_factory):
    """Seed 133, strength 1.0 with diffusion 0.5, 13/36 ke-, mixed hot pixels.
    On pixel totals a 0.09 px shift fitted alone gains delta BIC 361,810
    (the diffusion 478,671) but only 144 with the diffusion in the model: it
    is the diffusion's leftovers and may not go first. Measured: the
    diffusion alone (sigma 0.179 px, 304.5 -> 9.66, 97 % of the excess),
    incomplete with the sub-pixel entry; the twin the diffusion alone
    (0.224 px), complete (1.042, floor 0.993 +- 0.035; its brighter-fatter
    at delta BIC 24.9, under the threshold)."""
    twin = peer_report(tmp_path_factory, seed=133, silicon=BF_DIFFUSION, hot="mixed",
                       levels=(13000.0, 36000.0), oversample=5, **FILE)
    assert twin["missing_effects"][0] == "charge_diffusion"
    assert set(twin["missing_effects"]) <= {"charge_diffusion", "brighter_fatter"}
    assert_complete(twin)
    report = peer_report(tmp_path_factory, seed=133, silicon=BF_DIFFUSION, hot="mixed",
                         levels=(13000.0, 36000.0), **FILE)
    assert report["missing_effects"] == ["charge_diffusion"]
    assert report["complete"] is False
    assert any(u.startswith("charge_diffusion is in the model, but") for u in
               report["unexplained"])
    sigma = report["final_model"]["effects"]["charge_diffusion"]["sigma_px"]
    assert 0.1 < sigma < 0.3


@pytest.mark.slow
def test_a_real_shift_beside_diffusion_is_named_at_its_truth(tmp_path_factory):
    """Seed 152, diffusion 0.5 and a real 0.1 px shift along x, 13/36 ke-,
    mixed hot pixels, OVERSAMP 5: the shift alone (delta BIC 1,226,597) has
    2 % of it beside the diffusion (24,432), so the diffusion (1,434,509)
    goes first and the shift is named next at its truth. Before, the shift
    went first, removed 23 % of the excess and nothing was named (gap 945).
    Measured: sigma 0.232 px, shift (0.004, 0.098), then an
    ``anisotropic_ipc`` that is not there (-0.61), incomplete 1.121 (floor
    0.979 +- 0.025): not asserted, a flaw left open."""
    report = peer_report(tmp_path_factory, seed=152, silicon=DIFFUSION, hot="mixed",
                         levels=(13000.0, 36000.0), shift=(0.0, 0.1), oversample=5, **FILE)
    assert report["missing_effects"][:2] == ["charge_diffusion", "misregistration"]
    shift = report["final_model"]["effects"]["misregistration"]
    assert shift["shift_x_px"] == pytest.approx(0.1, abs=0.01)
    assert abs(shift["shift_y_px"]) < 0.01

"""The binary-star study: frames, the quick grid, caching and the process pool."""

import numpy as np
import pytest

import ipc_taichi
from analysis import binary
from analysis.binary import (
    FITS,
    METHODS,
    OFFSETS,
    BinaryGrid,
    MethodStudy,
    pair_frames,
    run_study,
    summarise,
)
from analysis.psf import point_source_image


def test_pair_frames_follow_the_flow_chart(psf):
    pos, flux, frames = pair_frames(psf, "mid", 0.5, 2.5, OFFSETS[:3], half=8)
    assert frames["truth"].shape == (3, 17, 20)
    np.testing.assert_allclose(pos[1], [[8.25, 8.0], [10.75, 8.0]])
    np.testing.assert_allclose(flux, [binary.FLUX["mid"], 0.5 * binary.FLUX["mid"]], rtol=1e-12)
    scene = (point_source_image(psf, 8.25, 8.0, (17, 20), flux[0])
             + point_source_image(psf, 10.75, 8.0, (17, 20), flux[1]))
    np.testing.assert_allclose(frames["truth"][1], scene, atol=1e-9)
    np.testing.assert_allclose(frames["coupled"][1], ipc_taichi.couple(scene), atol=1e-9)
    assert np.abs(frames["decoupled"] - frames["truth"]).max() < 1e-4 * scene.max()
    # with noise: the same read-noise instance is in truth and coupled (paper section 3.1)
    _, _, noisy = pair_frames(psf, "mid", 0.5, 2.5, OFFSETS[:1], half=8, seed=7, read_noise=20.0)
    residual = noisy["coupled"][0] - noisy["truth"][0]
    # far from the stars the frames hold read noise (20 e-) and little signal; the
    # instance is shared, so it cancels in coupled - truth (independent draws would not)
    far = noisy["truth"][0][:3] - frames["truth"][0][:3]
    expected = np.sqrt(frames["truth"][0][:3].mean() + 20.0 ** 2)   # Poisson + read noise
    assert np.std(far) == pytest.approx(expected, rel=0.3)
    assert np.abs(residual[:3, :]).max() < 5.0       # independent draws: ~28 e- rms
    _, _, again = pair_frames(psf, "mid", 0.5, 2.5, OFFSETS[:1], half=8, seed=7, read_noise=20.0)
    np.testing.assert_array_equal(again["coupled"], noisy["coupled"])


@pytest.fixture(scope="module")
def quick_grid(tmp_path_factory):
    cache = tmp_path_factory.mktemp("binary") / "cache.npz"
    grid = BinaryGrid.quick()
    tasks, results = run_study(grid, workers=0, cache_path=str(cache), progress=False)
    return grid, tasks, results, cache


def _row(summary, separation, noise):
    return next(r for r in summary["rows"] if r["separation"] == separation and r["noise"] == noise)


def test_quick_grid_truth_exact_and_decoupled_within_paper_targets(quick_grid):
    grid, tasks, results, _ = quick_grid
    summary = summarise(grid, tasks, results)
    for sep in (3.0, 20.0):
        row = _row(summary, sep, False)
        assert np.abs(row["truth"]["flux_error_pct"]).max() < 1e-7
        assert abs(row["truth"]["separation_error_mpix"][0]) < 1e-6
        # the paper's "decoupled: flux error <= 0.01 %, separation error <= 1 mpix"
        assert np.abs(np.array(row["decoupled"]["flux_error_pct"])[:, 0]).max() < 0.01
        assert abs(row["decoupled"]["separation_error_mpix"][0]) < 1.0
        assert row["decoupled"]["n"] == 16 and row["coupled"]["flagged"] == 0
    # coupled 3 px pair fitted with the IPC-free PSF: stars pulled together, flux lost
    row = _row(summary, 3.0, False)
    assert row["coupled_optical"]["separation_error_mpix"][0] < -5.0
    assert row["coupled_optical"]["flux_error_pct"][0][0] < -0.5
    # detection at an explicit min_separation: at photutils' default (2.5 FWHM = 5.25 px)
    # the 3 px pair is merged by the setting; at 1 px the finder splits most of them,
    # and IPC costs nothing against the truth frame; 20 px apart both are always found
    det = row["detected"]
    assert det["coupled"]["5.25"] <= 0.55 < 0.8 <= det["coupled"]["1"]
    assert det["coupled"]["1"] == pytest.approx(det["truth"]["1"], abs=0.07)
    assert all(v == 1.0 for v in _row(summary, 20.0, False)["detected"]["coupled"].values())
    assert _row(summary, 3.0, True)["detected"] is None      # studied noise-free only
    # the abstract's scenario: the bright field star's coupled PSF on this (bright) pair is
    # the pair's own coupled PSF, so the two fits agree
    assert row["coupled_brightpsf"]["flux_error_pct"] == row["coupled"]["flux_error_pct"]
    # noise present: a spread over offsets and realisations, no longer exact
    assert _row(summary, 3.0, True)["truth"]["flux_error_pct"][1][1] > 0.01


def test_cache_is_reused_and_keyed_by_parameters(quick_grid, monkeypatch):
    grid, tasks, results, cache = quick_grid

    def fail(task):
        raise AssertionError("recomputed a cached task")

    monkeypatch.setattr(binary, "_run_task", fail)
    monkeypatch.setattr(binary, "_build_state", lambda study: {})
    again_tasks, again = run_study(grid, workers=0, cache_path=str(cache), progress=False)
    assert again_tasks == tasks
    for a, b in zip(results, again):
        for name in a:
            np.testing.assert_array_equal(a[name], b[name])
    with pytest.raises(AssertionError, match="recomputed"):
        run_study(BinaryGrid(brightness=("bright",), ratios=(0.5,), separations=(3.0,), n_noise=0),
                  workers=0, cache_path=str(cache), progress=False)


def test_method_study_forward_fit_unbiased_where_plain_fit_is_not():
    study = MethodStudy(brightness=("bright",), read_noise=(), offsets=OFFSETS[:4], n_noise=0)
    tasks, results = run_study(study, workers=0, progress=False)
    row = summarise(study, tasks, results)["rows"][0]
    assert row["read_noise"] == -1.0 and set(METHODS) <= set(row)
    forward, plain = row["forward"], row["plain"]
    assert np.abs(np.array(forward["flux_error_pct"])[:, 0]).max() < 1e-2
    assert abs(forward["separation_error_mpix"][0]) < 0.1
    assert abs(plain["flux_error_pct"][1][0]) > 10 * abs(forward["flux_error_pct"][1][0])
    # the least-squares fitter and photutils agree on the plain fit
    assert plain["flux_error_pct"][1][0] == pytest.approx(
        row["plain_photutils"]["flux_error_pct"][1][0], abs=0.02)


def test_process_pool_gives_the_serial_results():
    study = BinaryGrid(brightness=("dim",), ratios=(0.5,), separations=(2.5,),
                       offsets=OFFSETS[5:7], n_noise=1)
    _, serial = run_study(study, workers=0, progress=False)
    _, pooled = run_study(study, workers=2, progress=False)
    assert len(serial) == 2
    for a, b in zip(serial, pooled):
        np.testing.assert_allclose(a["flux_error"], b["flux_error"], rtol=0, atol=1e-10)
        np.testing.assert_allclose(a["separation_error"], b["separation_error"], rtol=0, atol=1e-8)
    assert serial[0]["flux_error"].shape == (len(FITS), 2, 2)

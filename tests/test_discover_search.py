"""Blind tests of the discrepancy workflow: data are made by ``simulate-lab``
(the generator's own command-line path) into a FITS file, and the workflow
sees only that file (``ipc-taichi discover`` or :func:`discover`); which
effect was hidden is known to the test alone."""

import json
import os

import numpy as np
import pytest

from ipc_taichi.cli import main
from ipc_taichi.discover import discover
from tests.discover_helpers import assert_complete, final


def _make(tmp_path, effects, seed, readnoise=12.0, law="donlon2018", extra=()):
    path = tmp_path / "lab.fits"
    # 2 pairs of 80x80 keep each file to a few seconds on 2 cores
    argv = ["simulate-lab", str(path), "--seed", str(seed), "--readnoise", str(readnoise),
            "--law", law, "--size", "80", *extra]
    for name, value in effects.items():
        argv += ["--effect", f"{name}={value}"]
    assert main(argv) == 0
    return str(path)


def _discover_cli(tmp_path, path, figures=None):
    report = tmp_path / "report.json"
    argv = ["discover", path, "--report", str(report), "--quiet"]
    if figures:
        argv += ["--figures", str(figures)]
    assert main(argv) == 0
    return json.loads(report.read_text())


def _final(report, effect, param):
    params, errors = final(report, effect)
    return params[param], errors[param]


def _assert_gap_shrinks_to_floor(report):
    floor, sigma = report["gap_floor"], report["gap_floor_sigma"]
    assert 0 < sigma < 0.05
    assert_complete(report)
    assert report["baseline_gap"] - floor > 3 * sigma, report
    gaps = [report["baseline_gap"]] + [s["gap_after"] for s in report["steps"]]
    assert all(b < a for a, b in zip(gaps, gaps[1:]))  # every step closes part of the gap
    for step in report["steps"]:  # and a real share of the excess it faced
        frac = (step["gap_before"] - step["gap_after"]) / (step["gap_before"]
                                                           - step["floor_before"])
        assert step["explained_fraction"] == pytest.approx(frac)


# effect, hidden value, reported parameter, its true value, read noise, extra generator options
CASES = [
    ("diagonal_ipc", 0.0018, "alpha_diag", 0.0018, 12.0, ()),
    ("anisotropic_ipc", 0.15, "anisotropy", 0.15, 10.0, ()),
    ("second_neighbor_ipc", 0.0015, "alpha_second", 0.0015, 12.0, ()),
    ("classical_nonlinearity", 0.03, "deficit_at_50ke", 0.03, 15.0, ()),
    # float32 on disk (big-endian) with bad pixels: NaNs are masked, not propagated
    ("dark_current", 6.0, "dark_e", 6.0, 12.0, ("--float32", "--nan-fraction", "0.003")),
    ("flat_field", 0.015, "response_rms", 0.015, 12.0, ()),
    ("excess_read_noise", 15.6, "readnoise_e", 15.6, 12.0, ()),
]


@pytest.mark.parametrize("effect, value, param, truth, readnoise, extra", CASES,
                         ids=[c[0] for c in CASES])
def test_names_the_hidden_effect(tmp_path, effect, value, param, truth, readnoise, extra):
    seed = 100 + [c[0] for c in CASES].index(effect)
    path = _make(tmp_path, {effect: value}, seed, readnoise, extra=extra)
    report = _discover_cli(tmp_path, path)
    assert report["missing_effects"] == [effect]
    fitted, sigma = _final(report, effect, param)
    assert 0 < sigma < 0.25 * abs(truth)
    # a response map is one draw: the RMS realised over the ~900 bright pixels
    # that measure it differs from the nominal one by ~2.4 % (1 sigma)
    slack = 0.05 * truth if effect == "flat_field" else 0.0
    assert abs(fitted - truth) < 3 * sigma + slack, (fitted, sigma, truth)
    _assert_gap_shrinks_to_floor(report)
    assert report["steps"][0]["evidence"] > report["evidence_threshold"]["delta_bic"]
    assert np.isfinite(report["final_gap"])


def test_null_case_adds_nothing(tmp_path, capsys):
    path = _make(tmp_path, {}, seed=200)
    capsys.readouterr()
    report = _discover_cli(tmp_path, path)
    assert capsys.readouterr().out.startswith("complete: missing effects none; gap ")
    assert report["missing_effects"] == [] and report["steps"] == []
    assert report["final_gap"] == report["baseline_gap"]
    assert abs(report["final_gap"] - report["gap_floor"]) < 3 * report["gap_floor_sigma"]
    assert report["complete"] is True and report["unexplained"] == []
    assert report["stop"]["evidence"] < report["evidence_threshold"]["delta_bic"]


def test_two_hidden_effects_both_named_with_figures(tmp_path):
    path = _make(tmp_path, {"diagonal_ipc": 0.0015, "classical_nonlinearity": 0.03}, seed=201)
    figures = tmp_path / "figs"
    report = _discover_cli(tmp_path, path, figures)
    assert sorted(report["missing_effects"]) == ["classical_nonlinearity", "diagonal_ipc"]
    for effect, param, truth in (("diagonal_ipc", "alpha_diag", 0.0015),
                                 ("classical_nonlinearity", "deficit_at_50ke", 0.03)):
        fitted, sigma = _final(report, effect, param)
        assert abs(fitted - truth) < 3 * sigma
    _assert_gap_shrinks_to_floor(report)
    names = sorted(os.listdir(figures))
    assert names == ["gap_per_step.png", "residual_map.png", "residual_vs_signal.png",
                     "residuals_by_probe.png", "stacked_windows.png"]
    assert all((figures / n).stat().st_size > 5000 for n in names)
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".tmp-")]
    # the stacked windows localise the diagonal coupling: after the fit the
    # brightest bin's diagonal residual is gone
    before = np.array(report["diagnostics"]["baseline"]["stack_mean_residual"][-1], float)
    after = np.array(report["diagnostics"]["final"]["stack_mean_residual"][-1], float)
    diag = [(1, 1), (1, 3), (3, 1), (3, 3)]
    assert np.mean([before[i] for i in diag]) > 0.5
    assert abs(np.mean([after[i] for i in diag])) < 0.3


def test_constant_law_start_finds_signal_dependence(tmp_path):
    path = _make(tmp_path, {"signal_dependent_ipc": "donlon2018"}, seed=202,
                 law="constant:0.0125")
    result = discover(path)  # the Python API
    report = result.report
    assert report["ipclaw"] == "constant:0.0125"
    assert report["missing_effects"] == ["signal_dependent_ipc"]
    params = report["final_model"]["effects"]["signal_dependent_ipc"]
    errors = report["final_model"]["uncertainties"]["signal_dependent_ipc"]
    for name, truth in (("amp_diff", 0.004), ("amp_level", 0.004), ("alpha_floor", 0.0065)):
        assert abs(params[name] - truth) < 3 * errors[name], (name, params, errors)
    _assert_gap_shrinks_to_floor(report)


def test_report_refuses_to_overwrite(tmp_path, capsys):
    path = _make(tmp_path, {}, seed=203, extra=("--size", "64", "--pairs", "1"))
    report = tmp_path / "report.json"
    report.write_text("keep")
    assert main(["discover", path, "--report", str(report), "--quiet"]) == 2
    assert report.read_text() == "keep"
    assert "exists" in capsys.readouterr().err


def test_deviance_with_a_shared_response_map_is_the_gaussian_likelihood(rng):
    # the rank-one covariance u mean_k mean_l between the pairs of a pixel,
    # against the multivariate normal written out in full
    from scipy.stats import multivariate_normal

    from ipc_taichi.discover.blocks import deviance

    k, shape, u = 3, (4, 5), 4e-4
    mean = rng.uniform(100, 40000, (k,) + shape)
    var = mean + 144.0
    valid = rng.random((k,) + shape) > 0.1
    r = rng.normal(0, 1, (k,) + shape) * np.sqrt(var)
    expect = 0.0
    for y in range(shape[0]):
        for x in range(shape[1]):
            w = valid[:, y, x]
            m = mean[w, y, x]
            cov = np.diag(var[w, y, x]) + u * np.outer(m, m)
            expect += -2 * multivariate_normal(np.zeros(w.sum()), cov).logpdf(r[w, y, x])
    expect -= valid.sum() * np.log(2 * np.pi)  # the constant deviance() leaves out
    assert deviance([r], [var], [mean], [valid], u) == pytest.approx(expect, rel=1e-10)


def test_an_effect_that_fell_back_to_off_is_pruned(tmp_path):
    # an earlier effect whose parameter a later refit sent back to "off" (here
    # diffusion at sigma 0, beside the diagonal coupling that made the data)
    # costs nothing to remove: prune() drops it and keeps the effect the data need
    from ipc_taichi.discover import read_lab
    from ipc_taichi.discover.blocks import PairBlocks
    from ipc_taichi.discover.fitting import prune

    path = _make(tmp_path, {"diagonal_ipc": 0.0018}, seed=5)
    frames = PairBlocks.from_lab(read_lab(path))
    truth = read_lab(path).model().with_effects({"diagonal_ipc": {"alpha_diag": 0.0018}})
    stale = truth.with_effects({"charge_diffusion": {"sigma_px": 0.0}})
    model, dropped = prune(frames, stale)
    assert sorted(model.effects) == ["diagonal_ipc"]
    [(name, params, worth)] = dropped
    assert name == "charge_diffusion" and params == {"sigma_px": 0.0}
    # nothing gained, one parameter paid for: delta BIC = -ln n
    assert worth == pytest.approx(-np.log(frames.n), abs=1e-6)
    # a real effect is kept even when nothing protects it
    assert prune(frames, truth)[1] == []
    # and one the data do not need, though not at "off", is dropped too
    weak = truth.with_effects({"dark_current": {"dark_e": 0.05}})
    assert [d[0] for d in prune(frames, weak)[1]] == ["dark_current"]

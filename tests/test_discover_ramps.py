"""Ramps (``docs/discovery_format.md``, "Ramps"): read, simulated read by
read, and the gap from increments, on files of an independent generator
(``tests/independent/ramplab.py``: NumPy only, its own IPC, persistence,
row noise, telegraph pixels and one-way steps). The statistics: a null ramp
is complete and each hidden time-domain effect
leaves the verdict incomplete with the words that point at it; the search
(``ramp_search``) names persistence, correlated read noise and telegraph
pixels, each at its truth, and refuses what contradicts them (the frame
effects on ramps: ``tests/test_discover_ramp_chain.py``)."""

import json

import numpy as np
import pytest

from ipc_taichi.discover import read_lab
from ipc_taichi.discover.ramp_effects import (
    RAMP_EFFECTS,
    RAMP_LIMITS,
    RampEffect,
    ramp_contradiction,
    ramp_implausible,
)
from ipc_taichi.discover.ramp_search import discover_ramps
from ipc_taichi.discover.ramps import (
    expected_reads,
    ramp_gap,
    read_ramps,
    simulate_ramp,
    write_ramps,
)
from ipc_taichi.discover.record import Param
from ipc_taichi.errors import IPCInputError
from tests.discover_helpers import write_hdus
from tests.independent import ramplab


def _ramp_file(tmp_path, seed, **hidden):
    path = tmp_path / f"ramp{seed}.fits"
    ramplab.make_file(str(path), seed=seed, **hidden)
    return str(path)


def test_ramp_file_round_trip_and_times(tmp_path):
    rate = np.full((8, 8), 5.0)
    reads = np.cumsum(np.full((4, 8, 8), 10.0), axis=0)
    path = write_ramps(str(tmp_path / "r.fits"), [(rate, reads, 2.0)], readnoise=7.0,
                       law="constant:0.01")
    data = read_ramps(path)
    assert data.readnoise == 7.0 and data.law == "constant:0.01"
    (ramp,) = data.ramps
    assert np.array_equal(ramp.times, [2.0, 4.0, 6.0, 8.0])  # TFIRST defaults to TFRAME
    assert np.array_equal(ramp.reads, reads) and ramp.valid.all()
    # the frame reader names the ramp reader instead of a bare shape error
    with pytest.raises(IPCInputError, match="ramps reads it"):
        read_lab(path)


@pytest.mark.parametrize("keywords, data, match", [
    ({}, np.zeros((3, 8, 8)), "needs TFRAME"),
    ({"TFRAME": -1.0}, np.zeros((3, 8, 8)), "must be finite and > 0"),
    ({"TFRAME": 1.0}, np.zeros((1, 8, 8)), "at least 2 reads"),
    ({"TFRAME": 1.0}, np.zeros((3, 8, 6)), "is not OVERSAMP = 1 times"),
])
def test_bad_ramps_name_the_hdu(tmp_path, keywords, data, match):
    path = write_hdus(tmp_path / "bad.fits", [("SCENE", 1, np.ones((8, 8))),
                                              ("MEASURED", 1, data, keywords)], READNOIS=5.0)
    with pytest.raises(IPCInputError, match=r"\[MEASURED,1\]|\[SCENE,1\]") as err:
        read_ramps(path)
    assert match in str(err.value)


def test_expected_reads_grow_with_time_and_simulation_matches(tmp_path):
    rate = np.full((16, 16), 50.0)
    rate[8, 8] = 2000.0
    reads = np.zeros((6, 16, 16))
    data = read_ramps(write_ramps(str(tmp_path / "r.fits"), [(rate, reads, 3.0)], 8.0,
                                  law="constant:0.0125"))
    model, ramp = data.model(), data.ramps[0]
    mean, shot, r = expected_reads(model, ramp)
    assert r == pytest.approx(64.0)
    # charge conserved by the coupling away from the edge, linear in time
    assert mean[:, 6:11, 6:11].sum(axis=(1, 2)) == pytest.approx(
        (rate[6:11, 6:11].sum()) * ramp.times, rel=2e-3)
    assert np.all(np.diff(shot, axis=0) > 0)
    sims = np.stack([simulate_ramp(model, ramp, np.random.default_rng(k)) for k in range(40)])
    assert sims.mean(axis=0)[:, 8, 8] == pytest.approx(mean[:, 8, 8], rel=0.02)
    # the increments' variance: the shot collected between reads plus two reads' noise
    # (background pixels away from the hot one; the coupling keeps 0.9 of a
    # pixel's own shot variance: (1 - 4 alpha)^2 + 4 alpha^2)
    inc = np.diff(sims[:, :, 2:5, 2:14], axis=1)
    assert inc.var(axis=0).mean() == pytest.approx(0.9 * 50.0 * 3.0 + 2 * 64.0, rel=0.1)
    # and the neighbouring increments share one read's noise with opposite signs
    lag = np.mean((inc[:, 1:] - inc[:, 1:].mean(0)) * (inc[:, :-1] - inc[:, :-1].mean(0)))
    assert lag == pytest.approx(-64.0, abs=20.0)


def test_null_ramp_is_complete(tmp_path):
    stats = ramp_gap(_ramp_file(tmp_path, seed=301))
    assert stats["complete"] is True and stats["unexplained"] == []
    assert abs(stats["gap"] - 1.0) < 0.05


def test_persistence_is_a_misfit_falling_with_time(tmp_path):
    stats = ramp_gap(_ramp_file(tmp_path, seed=302, persistence=(0.002, 5.0)))
    assert stats["complete"] is False
    per_read = stats["gap_per_read"]
    assert per_read[0] > 2 * per_read[-1]
    assert "falling with time" in stats["unexplained"][0] and "persistence" in \
        stats["unexplained"][0]


def test_row_noise_is_correlated_along_x_only(tmp_path):
    stats = ramp_gap(_ramp_file(tmp_path, seed=303, row_noise=6.0))
    assert stats["complete"] is False
    words = [u for u in stats["unexplained"] if "neighbours correlated" in u]
    assert len(words) == 1 and "along x" in words[0] and "only" in words[0]
    assert "correlated read noise" in words[0]
    assert not any("telegraph" in u for u in stats["unexplained"])


def test_telegraph_pixels_jump_and_return(tmp_path):
    stats = ramp_gap(_ramp_file(tmp_path, seed=304, telegraph=(0.01, 80.0)))
    assert stats["complete"] is False
    assert stats["odd_pixels"]["count"] >= 5
    assert any("telegraph" in u for u in stats["unexplained"]), stats["unexplained"]
    assert not any("neighbours correlated" in u for u in stats["unexplained"])


# -- naming the ramp effects (ipc_taichi.discover.ramp_search) ----------------

def _search(tmp_path, seed, **hidden):
    return discover_ramps(_ramp_file(tmp_path, seed, **hidden))


def test_null_ramp_names_nothing(tmp_path):
    report = _search(tmp_path, 311)
    assert report["missing_effects"] == [] and report["complete"] is True


def test_persistence_named_at_its_truth(tmp_path):
    # the generator's after-image: 0.002 per s of a minute's earlier charge,
    # tau 5 s; as a share of the template (SCENE x 16 s): 0.002 x 60 x 5 / 16
    report = _search(tmp_path, 312, persistence=(0.002, 5.0))
    assert report["missing_effects"] == ["persistence"]
    p = report["final_model"]["effects"]["persistence"]
    assert p["fraction"] == pytest.approx(0.0375, rel=0.15)
    assert p["tau_s"] == pytest.approx(5.0, rel=0.2)
    assert report["complete"] is True
    assert report["steps"][0]["explained_fraction"] > 0.8


def test_row_noise_named_correlated_read_noise(tmp_path):
    report = _search(tmp_path, 313, row_noise=6.0)
    assert report["missing_effects"] == ["correlated_read_noise"]
    p = report["final_model"]["effects"]["correlated_read_noise"]
    assert p["row_variance_e2"] == pytest.approx(36.0, rel=0.35)
    assert p["column_variance_e2"] < 0.3 * p["row_variance_e2"]
    assert report["complete"] is True


def test_telegraph_pixels_named(tmp_path):
    # 2 % of the pixels switch by 80 e- (about 5 sigma of an increment); with
    # 1 %, the seed-314 file holds 4 detectable ones, fewer than 5 sigma above
    # chance, and nothing is named
    report = _search(tmp_path, 314, telegraph=(0.02, 80.0))
    assert report["missing_effects"] == ["random_telegraph_noise"]
    p = report["final_model"]["effects"]["random_telegraph_noise"]
    assert 0.008 < p["fraction"] < 0.025
    assert report["complete"] is True


def test_one_way_steps_are_not_telegraph_noise(tmp_path):
    # cosmic-ray-like steps: pixels off the model, but their level never returns
    report = _search(tmp_path, 315, steps_up=(0.01, 150.0))
    assert "random_telegraph_noise" not in report["missing_effects"]
    assert "jump both ways" in report["not_named"]["random_telegraph_noise"]
    assert report["complete"] is False
    assert any(u.startswith("not named random_telegraph_noise") for u in report["unexplained"])


def test_ramp_effect_contradictions_and_limits():
    assert "not an after-image" in ramp_contradiction("persistence",
                                                      {"fraction": -0.01, "tau_s": 5.0})
    assert ramp_contradiction("persistence", {"fraction": 0.01, "tau_s": 5.0}) is None
    assert ramp_contradiction("correlated_read_noise",
                              {"row_variance_e2": -3.0, "column_variance_e2": -1.0})
    assert "decay time" in ramp_implausible("persistence", {"fraction": 0.01, "tau_s": 1e4},
                                            10.0, 16.0)
    assert "READNOIS" in ramp_implausible("correlated_read_noise",
                                          {"row_variance_e2": 1e4, "column_variance_e2": 0.0},
                                          10.0, 16.0)
    assert ramp_implausible("random_telegraph_noise", {"fraction": 0.2, "jump_e": 50.0},
                            10.0, 16.0)
    assert "negative rate" in ramp_contradiction("dark_current", {"dark_rate_e_per_s": -1.0})
    assert "depends on the light" in ramp_contradiction("dark_current",
                                                        {"dark_rate_e_per_s": 2.0}, 6.0)
    assert ramp_contradiction("dark_current", {"dark_rate_e_per_s": 2.0}, -1.0) is None
    assert "e-/s in every pixel" in ramp_implausible("dark_current",
                                                     {"dark_rate_e_per_s": 5e3}, 10.0, 16.0)


class _ToyRampRecord(RampEffect):
    """A ramp record that fits a huge evidence and judges itself out of range
    by the integration it is given: the search tries it with no other edit."""

    def fit(self, model, ramps, ln_n):
        return {"strength": 1.0}, 1e6, model, 0.75

    def contradiction(self, p, extra=None):
        return None if extra == 0.75 else f"extra {extra}"

    def implausible(self, p, readnoise=None, cov=None, duration=None):
        return f"readnoise {readnoise:g}, duration {duration:g}"


def test_a_ramp_record_is_all_the_search_needs(tmp_path, monkeypatch):
    toy = _ToyRampRecord("toy_ramp", "collection", (Param("strength", 0.0, 0.0, 1.0, 0.1),),
                         "a toy")
    monkeypatch.setitem(RAMP_EFFECTS, "toy_ramp", toy)
    path = _ramp_file(tmp_path, 315, steps_up=(0.01, 150.0))
    duration = float(read_ramps(path).ramps[0].times[-1])
    report = discover_ramps(path)
    assert report["not_named"]["toy_ramp"] == f"readnoise 10, duration {duration:g}"
    assert "toy_ramp" not in report["missing_effects"]
    assert RAMP_LIMITS == {"persistence": 0.05, "persistence_tau": 20.0, "dark_current": 1000.0,
                           "correlated_read_noise": 3.0, "bias_drift": 3.0,
                           "random_telegraph_noise": 0.05}


def test_cli_discover_reads_a_ramp_file(tmp_path, cli):
    path = _ramp_file(tmp_path, 316, row_noise=6.0)
    report = tmp_path / "report.json"
    result = cli("discover", path, "--report", str(report), "--quiet")
    assert result.returncode == 0, result.stderr
    data = json.loads(report.read_text())
    assert data["missing_effects"] == ["correlated_read_noise"] and data["complete"] is True
    assert result.stdout.startswith("complete: missing effects correlated_read_noise")


def test_benchmark_ramps_tiny_run():
    # the bench row's code on a tiny ramp (the 256x256 x 10-read row: docs)
    from ipc_taichi.discover.benchmark import benchmark_ramps

    out = benchmark_ramps(n=24, nreads=4)
    assert out["named"] == ["persistence"] and out["complete"] is True
    assert out["persistence"]["fraction"] == pytest.approx(0.03, rel=0.2)


def test_brighter_fatter_ramp_is_named_brighter_fatter(tmp_path):
    # brighter-fatter made by the ramp model itself (the frame vocabulary's
    # boundary shifts, evaluated while collecting): the lines through the
    # patches share a misfit, the lines with no light on or next to them do
    # not, so it is not read noise; it is named brighter_fatter, at its
    # deflections, and not signal-dependent IPC
    from ipc_taichi.discover.model import DetectorModel
    from ipc_taichi.discover.ramps import RampModel, RampPair

    rate = np.full((48, 48), 20.0)
    for y in range(3, 42, 8):
        for x in range(3, 42, 8):
            rate[y:y + 3, x:x + 3] = 2500.0
    times = 2.0 * np.arange(1, 11)
    bf = {"deflection_x_at_50ke": 0.04, "deflection_y_at_50ke": 0.05, "upwind": 1.0,
          "reach": 0.0}
    model = RampModel(DetectorModel("constant:0.0125", 10.0, effects={"brighter_fatter": bf}))
    reads = simulate_ramp(model, RampPair(1, rate, np.zeros((10, 48, 48)), times),
                          np.random.default_rng(317))
    path = write_ramps(str(tmp_path / "bf.fits"), [(rate, reads, 2.0)], 10.0,
                       law="constant:0.0125")
    report = discover_ramps(path)
    assert report["missing_effects"] == ["brighter_fatter"] and report["complete"] is True
    assert "light falls" in report["not_named"]["correlated_read_noise"]
    p = report["steps"][0]["params"]
    assert p["deflection_x_at_50ke"] == pytest.approx(0.04, rel=0.1)
    assert p["deflection_y_at_50ke"] == pytest.approx(0.05, rel=0.1)
    assert p["reach"] == pytest.approx(0.0, abs=0.05)


def _dark_file(tmp_path, name, scale=1.0, dark=0.0):
    """A ramp of the ramp model itself (32x32 x 6 reads of 3 s, background 30
    e-/s and two patches) whose light is ``scale`` x SCENE plus ``dark`` e-/s
    in every pixel."""
    from ipc_taichi.discover.model import DetectorModel
    from ipc_taichi.discover.ramps import RampModel, RampPair

    rate = np.full((32, 32), 30.0)
    rate[4:12, 4:12] = 800.0
    rate[18:22, 20:30] = 1500.0
    model = RampModel(DetectorModel("constant:0.0125", 10.0))
    pair = RampPair(1, rate * scale + dark, np.zeros((6, 32, 32)), 3.0 * np.arange(1, 7))
    reads = simulate_ramp(model, pair, np.random.default_rng(5))
    return write_ramps(str(tmp_path / f"{name}.fits"), [(rate, reads, 3.0)], 10.0,
                       law="constant:0.0125")


def test_dark_current_named_at_its_rate(tmp_path):
    # 1.5 e-/s in every pixel that SCENE (the light) does not hold
    report = discover_ramps(_dark_file(tmp_path, "dark", dark=1.5))
    assert report["missing_effects"] == ["dark_current"] and report["complete"] is True
    assert report["steps"][0]["params"]["dark_rate_e_per_s"] == pytest.approx(1.5, abs=0.15)


def test_a_scene_scale_error_is_not_dark_current(tmp_path):
    # 3 % more light than SCENE says: an excess rate, but one that grows with the light
    report = discover_ramps(_dark_file(tmp_path, "scale", scale=1.03))
    assert "dark_current" not in report["missing_effects"]
    assert "depends on the light" in report["not_named"]["dark_current"]
    assert report["complete"] is False

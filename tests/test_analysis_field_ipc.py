"""IPC as the field measures it (analysis.field_ipc): flat-field autocorrelation and hot pixels.

The flat-field test is also the proof that the simulator applies IPC at all:
uncoupled shot noise has no nearest-neighbour covariance; coupled by a
constant alpha it has about 2 alpha times its variance.
"""

from functools import partial

import numpy as np
import pytest

from analysis.field_ipc import (
    alpha_from_flat,
    couple_source_law,
    flat_covariance_prediction,
    hot_pixel_alpha,
    linearised_alpha,
    measure_flats,
    measure_hot_pixels,
)
from ipc_taichi.laws import get_law


def test_constant_law_flat_covariance_is_two_alpha_times_variance(cpu):
    alpha, level, rn = 0.012, 20000.0, 10.0
    (row,) = measure_flats([level], law=f"constant:{alpha}", size=384, n_frames=2,
                           read_noise=rn, seed=5)
    cov, var = flat_covariance_prediction(alpha, level, rn)
    # the exact linear prediction, within 4 standard errors of the covariance estimate
    n = 2 * 380 ** 2
    assert row["cov_nn"] == pytest.approx(cov, abs=4 * var / np.sqrt(2 * n))
    # ... which is ~2 alpha x the variance (to O(alpha): 1 - 4a over (1-4a)^2 + 4a^2)
    assert row["ratio"] == pytest.approx(cov / var, abs=4 / np.sqrt(2 * n))
    assert row["ratio"] == pytest.approx(2 * alpha, rel=0.15)
    assert row["alpha"] == pytest.approx(alpha, abs=4 * row["alpha_err"])
    assert row["alpha_x"] == pytest.approx(alpha, abs=6 * row["alpha_err"])


def test_uncoupled_flat_has_no_covariance(cpu):
    (row,) = measure_flats([20000.0], law="constant:0", size=256, n_frames=1, seed=6)
    assert abs(row["ratio"]) < 4 / np.sqrt(2 * 252 ** 2)


def test_signal_dependent_flat_sees_the_law_linearised_at_each_level(cpu):
    """For the pair-symmetric donlon2018 law the linearised coupling is alpha(S, S)."""
    law = get_law("donlon2018")
    levels = [2000.0, 15000.0, 40000.0]
    rows = measure_flats(levels, size=512, n_frames=2, read_noise=10.0, seed=7)
    for row in rows:
        s = row["level"]
        assert row["alpha_lin"] == pytest.approx(float(law.alpha(s, s)), rel=1e-6)
        assert row["alpha"] == pytest.approx(row["alpha_lin"], abs=4 * row["alpha_err"])
    # the flat does follow the law's diagonal: 1.41 % at 2000 e- down to 1.10 % at 40000 e-
    assert rows[0]["alpha"] - rows[-1]["alpha"] > 6 * rows[0]["alpha_err"]


def test_source_law_flat_sees_alpha_plus_slope_times_signal(cpu):
    """A law of the sending pixel alone, a(S): the flat measures a + S a', not a."""
    law = get_law("donlon2018")

    def a(s):
        return law.alpha(s, s)

    coupler = partial(couple_source_law, a_of_s=a)
    level = 10000.0
    slope = (a(level + 1.0) - a(level - 1.0)) / 2.0
    assert linearised_alpha(level, coupler=coupler)[0] == pytest.approx(a(level) + level * slope,
                                                                         rel=1e-6)
    (row,) = measure_flats([level], size=768, n_frames=2, read_noise=10.0, seed=8, coupler=coupler)
    assert row["alpha"] == pytest.approx(row["alpha_lin"], abs=4 * row["alpha_err"])
    assert abs(row["alpha"] - a(level)) > 4 * row["alpha_err"]
    # charge is conserved by this coupler
    frame = np.random.default_rng(0).uniform(0, 6e4, (20, 20))
    assert couple_source_law(frame, a).sum() == pytest.approx(frame.sum(), rel=1e-13)


def test_hot_pixels_measure_alpha_far_from_the_diagonal(cpu):
    law = get_law("donlon2018")
    rows = measure_hot_pixels([3000.0, 50000.0], size=192, n_per_frame=120, seed=9)
    for row in rows:
        assert row["alpha_law"] == pytest.approx(float(law.alpha(row["level"], 0.0)))
        assert row["alpha"] == pytest.approx(row["alpha_law"], abs=4 * row["alpha_err"])
    # the hot pixel sees alpha(S, 0), the flat alpha(S, S): at 50000 e- they differ by 0.3 %
    assert law.alpha(50000.0, 50000.0) - rows[1]["alpha"] > 0.002


def test_hot_pixel_alpha_arithmetic():
    frame = np.zeros((7, 7))
    frame[3, 3] = 960.0
    frame[2, 3] = frame[4, 3] = frame[3, 2] = frame[3, 4] = 10.0
    alpha, total = hot_pixel_alpha(frame + 5.0, [(3, 3)], background=5.0)
    assert total[0] == pytest.approx(1000.0)
    assert alpha[0] == pytest.approx(0.01)


def test_alpha_from_flat_inverts_the_prediction():
    rng = np.random.default_rng(1)
    noise = rng.normal(0.0, 100.0, (600, 600))
    a = 0.02
    coupled = couple_source_law(noise + 1e4, lambda s: a) - 1e4
    row = alpha_from_flat(coupled, border=0)
    assert row["alpha"] == pytest.approx(a, abs=3 / (2 * np.sqrt(2 * 600 ** 2)))
    assert row["V"] == pytest.approx(1e4, rel=0.02)


def test_alpha_from_flat_masks_nan_and_reports_each_axis_with_errors():
    """The calibrate measurement: NaN and masked junk left out, x and y apart, errors."""
    from tests.independent import ipcgen

    rng = np.random.default_rng(3)
    level = 30000.0
    frames = np.array([ipcgen.couple(rng.poisson(level, (256, 256)).astype(float), "constant")
                       for _ in range(4)])
    frames[:, 100, 100] = np.nan
    mask = np.zeros((256, 256), bool)
    mask[10:20, 30:40] = True
    frames[:, 10:20, 30:40] = -1e6
    row = alpha_from_flat(frames, read_noise=0.0, mask=mask)
    assert np.isfinite(row["alpha"])
    truth_x, truth_y = 1.08 * 0.0055, 0.92 * 0.0055
    assert row["alpha_x"] == pytest.approx(truth_x, abs=4 * row["alpha_x_err"])
    assert row["alpha_y"] == pytest.approx(truth_y, abs=4 * row["alpha_y_err"])
    assert row["alpha_x_err"] == pytest.approx(1 / (2 * np.sqrt(3 * 252 ** 2)), rel=0.3)
    assert row["terms"]["diagonal"]["value"] == pytest.approx(0.08 * 0.0055, abs=1.2e-3)


def test_alpha_from_flat_negative_covariance_is_reported_not_nan():
    rng = np.random.default_rng(2)
    noise = rng.normal(0.0, 100.0, (3, 200, 200))
    # anti-correlated neighbours along x: a negative term, measured as such
    frames = noise - 0.02 * (np.roll(noise, 1, axis=2) + np.roll(noise, -1, axis=2)) + 1e4
    row = alpha_from_flat(frames, border=2)
    assert row["alpha_x"] < -5 * row["alpha_x_err"]
    assert abs(row["alpha_y"]) < 4 * row["alpha_y_err"]

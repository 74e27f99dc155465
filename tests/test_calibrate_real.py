"""calibrate on real JWST data: a NIRSpec NRS1 CV3 ground-test dark (CRDS reference,
10 groups in ADU; tests/data/PROVENANCE.md), then decouple the same ramp with the model.

The isolated hot pixels' mean neighbour fraction, ``mean(4 neighbours - background) /
(5x5 sum - background)``, is ~0.6 % as measured; after decoupling with the calibrated
model it must be within +-0.1 % of zero; the paper's law over-corrects it to about -0.7 %.
(The model is measured and checked on the same file: this shows the measurement and the
decoupler agree, not that the model transfers to other data.)
"""

import os

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.calibrate import calibrate, hotpixels
from ipc_taichi.calibrate.inputs import read_frames
from ipc_taichi.calibrate.report import summary_lines

DARK = os.path.join(os.path.dirname(__file__), "data", "jwst_nirspec_nrs1_dark_sub512.fits")
GAIN = 1.0


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    out = tmp_path_factory.mktemp("real") / "nrs1.json"
    result = calibrate([DARK], output=str(out), gain=GAIN)
    frames = read_frames(DARK, gain=GAIN)
    return result, frames


def _residual(frames, positions, **model):
    data, mask = frames.data[0], frames.mask[0]
    clean = np.where(mask, 0.0, data)
    if model:
        data = np.array([np.asarray(ipc_taichi.decouple(f, mask=m, **model))
                         for f, m in zip(clean, mask)])
        data = np.where(mask, np.nan, data)
    ev = hotpixels.measure_events(data, positions, mask)
    frac = ev["fraction"].reshape(-1, 5, 5)
    nn = (frac[:, 1, 2] + frac[:, 3, 2] + frac[:, 2, 1] + frac[:, 2, 3]) / 4.0
    keep = ev["signal"] >= 1000.0
    v = nn[keep]
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size)), int(v.size)


def test_real_nirspec_dark_is_measured(cpu, measured):
    result, frames = measured
    report = result["report"]
    assert report["hot_pixels"]["found"] >= 12
    # DQ_DEF of this file: bit 4 is HOT, not JUMP_DET; hot pixels are not masked away
    assert frames.mask[0, -1].mean() < 0.01
    bins = [b for b in report["hot_pixels"]["bins"] if b["signal"] > 3000]
    assert bins
    for b in bins:  # the published range for this detector: 0.55-0.7 %
        nn = 0.5 * (b["x"]["value"] + b["y"]["value"])
        assert 0.0050 < nn < 0.0066
    # far below the paper's law at the same signals (1.0-1.45 %)
    model = result["model"]
    assert model.law.alpha(10000.0, 0.0) < 0.7 * ipc_taichi.laws.donlon2018().alpha(10000.0, 0.0)
    assert any("alpha(S,S) assumed" in a for a in report["fit"]["assumed"])
    # the DQ names this file's own DQ_DEF lacks are said where the run is read
    line = next(x for x in summary_lines(report, model) if x.startswith("input (dark)"))
    assert line.endswith("[DQ_DEF] defines no SATURATED, JUMP_DET, DEAD: those pixels are not "
                         "left out by name")


def test_real_nirspec_dark_decoupled_with_its_model(cpu, measured):
    result, frames = measured
    positions = hotpixels.find_hot_pixels(frames.data[0, -1], frames.mask[0, -1])
    before, err0, n = _residual(frames, positions)
    assert n >= 60 and 0.005 < before < 0.007
    after, err, _ = _residual(frames, positions, model=result["model"])
    assert abs(after) < 0.001 and err < 0.0005
    paper, _, _ = _residual(frames, positions, law="donlon2018")
    assert -0.009 < paper < -0.005  # the paper's law leaves negative neighbours


FGS = os.path.join(os.path.dirname(__file__), "data", "jwst_fgs_guider2_acq1.fits")
FGS_GAIN = 1.57  # e-/DN, GUIDER2 (tests/data/PROVENANCE.md)


def _within(a, b, k=2.0):
    return abs(a["residual"] - b["residual"]) <= k * np.hypot(a["error"], b["error"])


@pytest.mark.parametrize("path, gain", [(DARK, GAIN), (FGS, FGS_GAIN)], ids=["nirspec", "fgs"])
def test_real_held_out_residual_no_worse_than_a_constant(cpu, tmp_path, path, gain):
    """The issue's real-file check: the chosen law, fitted on half the hot pixels, leaves
    the other half's neighbours at zero within errors, and no worse than the best constant
    fitted on the same half. (Before: on the FGS ramp a 4-parameter law chosen by chi^2
    left -0.055 % +- 0.029 %, a constant +0.001 %.)"""
    result = calibrate([path], gain=gain, report_path=str(tmp_path / "r.json"))
    t = result["report"]["transfer"]
    chosen, constant, before = t["chosen"], t["constant"], t["uncorrected"]
    assert chosen["n_pixels"] >= 12
    assert abs(chosen["residual"]) <= 3.0 * chosen["error"]
    assert chosen["residual"] <= constant["residual"] + 2.0 * np.hypot(chosen["error"],
                                                                         constant["error"])
    assert _within(chosen, constant)
    assert before["residual"] > 0.0035  # ~0.4-0.6 % before decoupling
    # the IPC map across the detector: measured and tested on held-out hot pixels; 15-21
    # hot pixels cannot show one (issue 35: never a map the held-out data do not ask for)
    section = result["report"]["bond_map"]
    assert section["test"]["hot"]["n"] >= 12
    assert not section["written"] and result["model"].bonds is None
    assert section["test"]["z"] < 3.0
    if path == DARK:
        assert abs(chosen["residual"]) < 0.0003  # the issue: NIRSpec within +-0.03 %
    else:
        # 21 hot pixels x 6 integrations x 2 groups: a constant is all they support
        assert result["report"]["fit"]["chosen"] == "constant"
        assert not result["report"]["nonlinear_ipc"]["detected"]
        assert 0.0035 < result["model"].law.alpha(3000.0, 0.0) < 0.0050

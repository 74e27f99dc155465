"""Discover on ramps made by Pyxel's own detector models (issue 38 item 3):
``tests/independent/pyxelramps.py`` (pyxel, NumPy, astropy; no ipc_taichi) runs
Pyxel's CMOS pipeline with non-destructive reads, one Pyxel effect at a time,
and writes the discovery ramp format itself. What is asserted is what was
measured (docs/discover.md, "Ramps made by Pyxel"): the nulls name nothing;
Pyxel's output-node non-linearity and its correlated pink noise are named by
the vocabulary's names, and so are its dark current and the diagonal and
anisotropic terms of its IPC kernel; its trap persistence (capture during the
exposure, which no form here has) is not named ``persistence`` on a bright ramp
and leaves the verdict incomplete with words in ``unexplained``."""

import warnings

import pytest

from tests.helpers import optional

pytest.importorskip("pyxel", reason=optional("pyxel"))
from ipc_taichi.discover.ramp_search import discover_ramps  # noqa: E402
from tests.independent import pyxelramps  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::FutureWarning",
                                        "ignore::UserWarning")
SEED = 1


def _discover(tmp_path, effect, seed=SEED):
    path = str(tmp_path / f"{effect}_{seed}.fits")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pyxelramps.make(effect, seed, path)
    return discover_ramps(path)


def _floor_excess(report):
    """The baseline gap's distance above the floor, in floor scatters."""
    return (report["baseline_gap"] - report["gap_floor"]) / report["gap_floor_sigma"]


@pytest.mark.parametrize("effect", ["null", "ipc_null"])
def test_pyxel_null_ramps_name_nothing(tmp_path, effect):
    """Pyxel's plain CMOS ramp, and the same with its simple_ipc kernel
    (0.0125, the file's IPCLAW constant:0.0125; the outer ring left out):
    complete, nothing named (no geometry term on the kernel without one)."""
    report = _discover(tmp_path, effect)
    assert report["complete"], report["unexplained"]
    assert report["steps"] == [] and report["missing_effects"] == []
    assert abs(_floor_excess(report)) < 3


def test_pyxel_output_node_nonlinearity_is_classical_nonlinearity(tmp_path):
    """output_node_linearity_poly, a quadratic deficit of 4.05 % at 50 ke-:
    named classical_nonlinearity at its value, complete."""
    report = _discover(tmp_path, "nonlinearity")
    assert report["missing_effects"] == ["classical_nonlinearity"]
    assert report["steps"][0]["params"]["deficit_at_50ke"] == pytest.approx(0.0405, abs=0.003)
    assert report["complete"]
    assert report["baseline_gap"] > report["final_gap"] + 0.5


def test_pyxel_correlated_pink_noise_is_correlated_read_noise(tmp_path):
    """correlated_pink_noise_cmos (6 e-, one generator read in pixel order):
    named correlated_read_noise, more along rows than columns (the read order)."""
    report = _discover(tmp_path, "pink_noise", 3)
    assert _floor_excess(report) > 3
    step = report["steps"][0]
    assert step["effect"] == "correlated_read_noise"
    assert step["params"]["row_variance_e2"] > step["params"]["column_variance_e2"]
    assert 10.0 < step["params"]["row_variance_e2"] < 36.0
    assert step["gap_after"] < step["gap_before"]


def test_pyxel_correlated_pink_noise_slow_part_is_bias_drift(tmp_path):
    """The same at seed 1: half of what its lines share at a read is shared by
    the whole frame (the 1/f noise's slowest part, over a read of the frame),
    so bias_drift is named first, within the pink noise's 36 e-^2; then (the
    cross-read products still off their floor after it) what the rows share
    as correlated_read_noise (measured: 6.9 e-^2, then rows 9.3 and columns
    3.7 e-^2, gap 1.068 -> 1.044 -> 1.004, complete)."""
    report = _discover(tmp_path, "pink_noise")
    step = report["steps"][0]
    # the start 3 scatters above its floor (0.018, as on the null ramps)
    assert step["gap_before"] - step["floor_before"] > 3 * 0.018
    assert report["missing_effects"] == ["bias_drift", "correlated_read_noise"]
    assert report["complete"]
    assert 2.0 < step["params"]["variance_e2"] < 36.0
    rows = report["steps"][1]["params"]
    assert rows["row_variance_e2"] > rows["column_variance_e2"]  # 1/f in readout order
    assert report["steps"][1]["gap_after"] < step["gap_after"] < step["gap_before"]


@pytest.mark.slow  # about 15 s: Pyxel compiles its persistence kernel (numba) on first use
def test_pyxel_trap_persistence_is_not_named_persistence(tmp_path):
    """simple_persistence (2 % traps, 5 s), two integrations: the traps take
    charge during the first (a deficit) and give it back in the second. Our
    persistence (a release only) is refused; the verdict is incomplete."""
    report = _discover(tmp_path, "persistence")
    assert _floor_excess(report) > 10
    assert "persistence" not in report["missing_effects"]
    assert "persistence" in report["not_named"]
    assert not report["complete"]
    assert any("off the model" in line for line in report["unexplained"])


@pytest.mark.slow  # about 20 s: Pyxel's persistence kernel, and a search with a persistence grid
def test_pyxel_after_image_on_a_dark_ramp_is_persistence_but_incomplete(tmp_path):
    """simple_persistence, a bright integration then one of background only: the
    release is named persistence (measured 0.0145-0.0147 of the earlier charge,
    tau 2.8 s: Pyxel's steps of 3 s with its 5 s traps release 60 % a step),
    and the verdict stays incomplete (the capture during the bright ramp)."""
    report = _discover(tmp_path, "persistence_dark")
    step = report["steps"][0]
    assert step["effect"] == "persistence"
    assert 0.005 < step["params"]["fraction"] < 0.03
    assert 1.5 < step["params"]["tau_s"] < 5.0
    assert step["explained_fraction"] > 0.6
    assert not report["complete"] and report["unexplained"]


def test_pyxel_dark_current_is_dark_current(tmp_path):
    """simple_dark_current 20 e-/s (not in SCENE, the light's rate): named
    dark_current at its rate (measured 19.83 / 20.00 / 20.01 at seeds 1-3),
    nothing else, complete."""
    report = _discover(tmp_path, "dark_current")
    assert _floor_excess(report) > 100
    assert report["missing_effects"] == ["dark_current"] and report["complete"]
    assert report["steps"][0]["params"]["dark_rate_e_per_s"] == pytest.approx(20.0, abs=0.6)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_pyxel_diagonal_kernel_is_diagonal_ipc(tmp_path, seed):
    """simple_ipc with a diagonal term 0.002 on the stated constant 0.0125 (the
    outer ring left out: Pyxel's fill edge): named diagonal_ipc at its value
    and nothing else, complete, at every seed (it was signal_dependent_ipc
    before the geometry terms were searched on ramps)."""
    report = _discover(tmp_path, "diagonal_ipc", seed)
    assert _floor_excess(report) > 3
    assert report["missing_effects"] == ["diagonal_ipc"] and report["complete"]
    assert report["steps"][0]["params"]["alpha_diag"] == pytest.approx(0.002, abs=0.0002)
    assert report["steps"][0]["explained_fraction"] > 0.7


def test_pyxel_anisotropic_kernel_is_anisotropic_ipc(tmp_path):
    """simple_ipc with anisotropic_coupling 0.003 (0.0155 along rows, 0.0095
    along columns): anisotropic_ipc at weights 1.24 and 0.76 of the stated
    0.0125, nothing else, complete."""
    report = _discover(tmp_path, "anisotropic_ipc")
    assert report["missing_effects"] == ["anisotropic_ipc"] and report["complete"]
    p = report["steps"][0]["params"]
    assert p["weight_horizontal"] == pytest.approx(1.24, abs=0.03)
    assert p["weight_vertical"] == pytest.approx(0.76, abs=0.03)

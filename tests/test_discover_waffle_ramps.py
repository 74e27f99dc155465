"""Discover on flat ramps made by solid-waffle's flat simulator (issue 38 item 3).

``tests/independent/waffle.py`` runs solid-waffle 26.0.0's simulator unchanged
(no ipc_taichi) and writes its flats as discovery ramp files
(:func:`~tests.independent.waffle.discover_ramp_file`: the central 128x128
(48x48 with the non-linearity) of the active area, 5 reads of 3 s to 40 ke-,
SCENE the flat's rate, the stated
IPC 1 % as the starting law). What is asserted is what was measured
(docs/discover.md, "Ramps made by solid-waffle"): the null names nothing; the
simulator's quadratic non-linearity is named ``classical_nonlinearity`` at its
beta, with and without its brighter-fatter; its brighter-fatter is **not**
named on a flat: in a uniform flat it moves no mean charge, and the ramp gap
(the mean square of the whitened increments) does not see what it does to
the increments' covariance across reads, which the data show (the last
test). Seeds 4101 (none used by calibrate's tests of the same simulator)."""

import math

import numpy as np
import pytest

from tests.helpers import optional

pytest.importorskip("solid_waffle", reason=optional("solid_waffle"))
from ipc_taichi.discover.ramp_search import discover_ramps  # noqa: E402
from ipc_taichi.discover.ramps import RampModel, read_ramps, whitened  # noqa: E402
from tests.independent import waffle  # noqa: E402

SEED = 4101
NREADS = 6  # the simulator's reads; read 0 (the reset) is not in the file
# pixels kept along each axis (of the simulator's 504 active ones): the
# non-linear files are searched longest, and their effect is large
SIDE = {"ipc": 128, "ipc_bf": 128, "ipc_nl": 48, "ipc_bf_nl": 48}
_MADE = {}


def _made(tmp_path_factory, kind):
    """The ramp file of ``kind`` and discover's report on it, once a session."""
    if kind not in _MADE:
        folder = tmp_path_factory.mktemp(f"waffle_ramps_{kind}")
        made = waffle.discover_ramp_file(folder / f"{kind}.fits", kind, SEED, nreads=NREADS,
                                         side=SIDE[kind])
        _MADE[kind] = (made, discover_ramps(made["path"]))
    return _MADE[kind]


def _floor_excess(report, gap="final_gap"):
    return (report[gap] - report["gap_floor"]) / report["gap_floor_sigma"]


def test_waffle_ramp_file_holds_the_flat(tmp_path_factory):
    """The file: MEASURED in electrons with the reset removed (the reads'
    mean is the rate times their time), the cut's border masked."""
    made, _ = _made(tmp_path_factory, "ipc")
    data = read_ramps(made["path"])
    ramp = data.ramps[0]
    assert data.law == f"constant:{waffle.ALPHA}"
    assert ramp.reads.shape == (NREADS - 1, SIDE["ipc"], SIDE["ipc"])
    assert np.allclose(ramp.times, waffle.DT * np.arange(1, NREADS))
    valid = ramp.valid
    assert valid.sum() == (SIDE["ipc"] - 2 * waffle.EDGE) ** 2
    means = ramp.reads[:, valid].mean(axis=1)
    assert np.allclose(means, made["rate"] * ramp.times, rtol=2e-4)


def test_waffle_null_flat_names_nothing(tmp_path_factory):
    """IPC 1 % (stated), no brighter-fatter, no non-linearity: complete,
    nothing named."""
    _, report = _made(tmp_path_factory, "ipc")
    assert report["missing_effects"] == [] and report["complete"], report["unexplained"]
    assert abs(_floor_excess(report)) < 3


def test_waffle_nonlinearity_is_classical_nonlinearity(tmp_path_factory):
    """NL quadratic 1.5 ppm/e-: named classical_nonlinearity at beta x 50 ke-
    (0.075), alone, the gap closed to its floor."""
    made, report = _made(tmp_path_factory, "ipc_nl")
    assert report["missing_effects"] == ["classical_nonlinearity"]
    step = report["steps"][0]
    assert step["params"]["deficit_at_50ke"] == pytest.approx(
        made["truth"]["deficit_at_50ke"], abs=0.002)
    assert _floor_excess(report, "baseline_gap") > 100
    assert report["complete"] and abs(_floor_excess(report)) < 3


def test_waffle_brighter_fatter_and_nonlinearity_names_the_nonlinearity_only(
        tmp_path_factory):
    """Both on: the non-linearity named at its beta; the brighter-fatter is
    not (the flat's blind spot, below), and nothing is named in its place
    (neither signal-dependent IPC nor anything else)."""
    made, report = _made(tmp_path_factory, "ipc_bf_nl")
    assert report["missing_effects"] == ["classical_nonlinearity"]
    assert report["steps"][0]["params"]["deficit_at_50ke"] == pytest.approx(
        made["truth"]["deficit_at_50ke"], abs=0.002)
    assert report["complete"]


def test_waffle_brighter_fatter_on_a_flat_is_not_seen_by_the_ramp_gap(tmp_path_factory):
    """BFE on, NL off: nothing named and the verdict "complete", although the
    data hold the brighter-fatter: a pixel's increments fall with the charge
    it already holds (the IR kernel's centre -2.04e-6 per electron), so its
    whitened increments are anti-correlated across reads (mean product
    about ``lambda a_00`` = -0.016 per pair of reads) and their sum varies
    less than the model says (the photon-transfer curve's bend); the same
    statistics on the null flat are at zero. When the ramp gap learns the
    covariance across reads this test and the docs' table change."""
    _, report = _made(tmp_path_factory, "ipc_bf")
    assert report["missing_effects"] == [] and report["complete"]
    assert "signal_dependent_ipc" not in report["missing_effects"]
    cross = {}
    for kind in ("ipc", "ipc_bf"):
        made, _ = _made(tmp_path_factory, kind)
        data = read_ramps(made["path"])
        w, _ = whitened(RampModel(data.model()), data.ramps, 0)
        n = w.shape[0]
        pairs = [np.mean(w[i] * w[j]) for i in range(n) for j in range(i + 1, n)]
        cross[kind] = (np.mean(pairs), 1.0 / math.sqrt(len(pairs) * w.shape[1]))
    assert abs(cross["ipc"][0]) < 3 * cross["ipc"][1]
    assert cross["ipc_bf"][0] < -5 * cross["ipc_bf"][1]

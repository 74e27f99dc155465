"""Discover on flat ramps made by solid-waffle's flat simulator (issue 38 item 3).

``tests/independent/waffle.py`` runs solid-waffle 26.0.0's simulator unchanged
(no ipc_taichi) and writes its flats as discovery ramp files
(:func:`~tests.independent.waffle.discover_ramp_file`: the central 128x128
(48x48 with the non-linearity) of the active area, 5 reads of 3 s to 40 ke-,
SCENE the flat's rate, the stated
IPC 1 % as the starting law). What is asserted is what was measured
(docs/discover.md, "Ramps made by solid-waffle"): the null names nothing; the
simulator's quadratic non-linearity is named ``classical_nonlinearity`` at its
beta, with and without its brighter-fatter; its brighter-fatter, which in a
uniform flat moves no mean charge, is seen by the gap's cross-read products
(a pixel's whitened increments at two reads) and named from them on a flat
large enough for its three parameters (256x256 x 10 reads, slow), seen but
not named on the 128x128 x 5-read file. Seeds 4101 and 4501 (none used by
calibrate's tests of the same simulator)."""


import numpy as np
import pytest

from tests.helpers import optional

pytest.importorskip("solid_waffle", reason=optional("solid_waffle"))
from ipc_taichi.discover.ramp_search import discover_ramps  # noqa: E402
from ipc_taichi.discover.ramps import read_ramps  # noqa: E402
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


def _cross_z(report, name="self"):
    """A baseline cross-read product's departure from its floor, in floor scatters."""
    base = report["baseline"]
    m, s = base["cross_read_floor"][name]
    return (base["cross_read"][name] - m) / s


def test_waffle_brighter_fatter_on_a_small_flat_is_seen_not_named(tmp_path_factory):
    """BFE on, NL off, 128x128 x 5 reads: the gap's mean square stays at its
    floor (in a uniform flat the kernel moves no mean charge), but its
    cross-read part sees it: a pixel's increments fall with the charge it
    already holds (the IR kernel's centre -2.04e-6 per electron), so its
    whitened increments at two reads multiply to about ``I dt a_00`` =
    -0.016 on average, 4-5 floor scatters (the null flat: within 3).
    Incomplete, said in words; not named: these 15376 pixels give
    ``brighter_fatter``'s three parameters too little (delta BIC under 25),
    and nothing is named in its place (never ``signal_dependent_ipc``)."""
    _, report = _made(tmp_path_factory, "ipc_bf")
    _, null = _made(tmp_path_factory, "ipc")
    assert abs(_cross_z(null)) < 3
    assert _cross_z(report) < -4
    assert abs(_floor_excess(report, "baseline_gap")) < 3
    assert report["missing_effects"] == [] and not report["complete"]
    assert any("correlated across reads" in line for line in report["unexplained"])


@pytest.mark.slow
def test_waffle_brighter_fatter_on_a_flat_is_named_from_the_cross_read_products(
        tmp_path_factory):
    """BFE on, NL off, 256x256 x 10 reads (seed 4501): ``brighter_fatter``
    named alone from the cross-read products (the mean cannot see it), the
    gap then complete; its kernel's centre the simulator's -2.04e-6 within 3
    of its errors (the fit's covariance; measured -1.77e-6 +- 0.16e-6,
    docs/discover.md)."""
    folder = tmp_path_factory.mktemp("waffle_ramps_bf_large")
    made = waffle.discover_ramp_file(folder / "ipc_bf_256.fits", "ipc_bf", 4501, nreads=11,
                                     side=256)
    report = discover_ramps(made["path"])
    assert report["missing_effects"] == ["brighter_fatter"] and report["complete"]
    assert _cross_z(report) < -5
    section = report["steps"][0]["brighter_fatter"]
    centre, error = section["kernel"][2][2], section["kernel_error"][2][2]
    truth = made["truth"]["bf_kernel"][2][2]
    assert error < 0.2 * abs(truth)
    assert abs(centre - truth) < 3 * error

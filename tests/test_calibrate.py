"""calibrate: the pieces (hot pixels, flats, reference files, law fit) and bad input."""

import json

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.calibrate import calibrate, flats, hotpixels, lawfit, reffiles
from ipc_taichi.errors import IPCInputError
from ipc_taichi.model import CouplingModel
from tests.helpers import loop_couple, optional, write_sci
from tests.independent import ipcgen

# ---- hot pixels ----------------------------------------------------------------------

def test_hot_pixel_fraction_is_exact_without_noise():
    """One coupling step: the fraction of each offset is w(d) alpha(S, B) exactly."""
    truth = np.full((64, 64), 5.0)
    truth[20, 30] = 20000.0
    truth[40, 12] = 8000.0
    measured = ipcgen.couple(truth, "falling")
    pos = hotpixels.find_hot_pixels(measured)
    assert sorted(map(tuple, pos)) == [(20, 30), (40, 12)]
    ev = hotpixels.measure_events(measured, pos)
    for k in range(2):
        y, x = pos[ev["event"][k]]
        s = truth[y, x]
        a = ipcgen.hidden_alpha("falling")(s, 5.0)
        frac = ev["fraction"][k].reshape(5, 5)
        assert frac[2, 3] == pytest.approx(ipcgen.WEIGHTS[(0, 1)] * a, rel=1e-9)
        assert frac[1, 2] == pytest.approx(ipcgen.WEIGHTS[(-1, 0)] * a, rel=1e-9)
        assert frac[1, 1] == pytest.approx(ipcgen.WEIGHTS[(-1, -1)] * a, rel=1e-9)
        assert frac[2, 0] == pytest.approx(ipcgen.WEIGHTS[(0, -2)] * a, rel=1e-9)
        assert ev["signal"][k] == pytest.approx(s - 5.0, rel=1e-9)


def test_hot_pixels_pairs_masked_and_edges_are_refused():
    frame = np.zeros((64, 64))
    frame[10, 10] = 1e4  # isolated
    frame[30, 30] = frame[30, 31] = 1e4  # a pair: not isolated
    frame[50, 20] = 1e4
    mask = np.zeros_like(frame, bool)
    mask[51, 21] = True  # DQ next to it
    frame[1, 40] = 1e4  # too near the edge for the background ring
    pos = hotpixels.find_hot_pixels(frame, mask)
    assert [tuple(p) for p in pos] == [(10, 10)]


def test_summary_bins_errors_from_scatter(rng):
    n = 400
    ev = {"signal": np.full(n, 3000.0), "background": np.zeros(n),
          "fraction": np.zeros((n, 25)), "event": np.arange(n), "group": np.zeros(n, int)}
    ev["fraction"][:, 13] = 0.006 + 0.001 * rng.standard_normal(n)  # (0, +1)
    ev["fraction"][:, 11] = 0.006 + 0.001 * rng.standard_normal(n)  # (0, -1)
    (row,) = hotpixels.summarise_events(ev)
    assert row["x"]["value"] == pytest.approx(0.006, abs=4 * 0.001 / np.sqrt(2 * n))
    assert row["x"]["error"] == pytest.approx(0.001 / np.sqrt(2 * n), rel=0.2)
    assert row["y"]["value"] == 0.0


# ---- flats ---------------------------------------------------------------------------

def test_kernel_relation_is_exact_for_a_known_kernel():
    k = (0.012, 0.009, 0.001, 0.0004, 0.0002)
    V, rn = 30000.0, 10.0
    cov = {}
    for lag in flats.LAGS:
        c = V * flats.kernel_autocorrelation(k, lag) + (rn ** 2 if lag == (0, 0) else 0.0)
        cov[f"{lag[0]},{lag[1]}"] = {"cov": c, "error": 1.0}
    solved = flats.solve_kernel(cov, rn)
    assert solved["V"] == pytest.approx(V, rel=1e-8)
    for name, value in zip(flats.TERMS, k):
        assert solved["terms"][name]["value"] == pytest.approx(value, abs=1e-10)
    # the first-order rule is off by a few percent at alpha ~ 1 %: the exact relation is needed
    assert cov["0,1"]["cov"] / (2 * V) != pytest.approx(k[0], rel=0.03)


def test_flat_covariance_handles_nan_and_masks(rng):
    frames = rng.normal(1000.0, 30.0, (4, 96, 96))
    frames[:, 10, 10] = np.nan
    mask = np.zeros((96, 96), bool)
    mask[50:60, 50:60] = True
    frames[:, 50:60, 50:60] = 1e9  # junk under the mask
    cov = flats.flat_covariances(frames, mask)
    assert np.isfinite(cov["0,0"]["cov"])
    assert cov["0,0"]["cov"] == pytest.approx(900.0, rel=0.05)
    assert abs(cov["0,1"]["cov"]) < 5 * cov["0,1"]["error"]


def test_saturated_flat_is_reported_not_measured(rng):
    frames = np.full((4, 64, 64), 65000.0) + rng.normal(0, 10.0, (4, 64, 64))
    row = flats.measure_level(frames, read_noise=10.0)
    assert row["terms"] is None and "saturated" in row["problem"]


# ---- reference files -----------------------------------------------------------------

def test_jwst_ipc_reference_is_inverted(tmp_path):
    forward = np.array([[0.0005, 0.006, 0.0005], [0.0065, 0.972, 0.0065],
                        [0.0005, 0.006, 0.0005]])
    inverse = reffiles.invert_kernel(forward, size=64)
    assert inverse[1, 1] > 1  # what the JWST file holds
    hdu = fits.PrimaryHDU()
    hdu.header["REFTYPE"] = "IPC"
    hdu.header["TELESCOP"] = "JWST"
    path = tmp_path / "jwst_ipc.fits"
    fits.HDUList([hdu, fits.ImageHDU(inverse, name="SCI")]).writeto(path)
    law, geometry, info = reffiles.read_reference(str(path))
    assert info["kind"].startswith("jwst_ipc")
    alpha = law.alpha(0.0, 0.0)
    # the 3x3 cut of the inverse's inverse: exact to O(alpha^2)
    assert alpha == pytest.approx(0.00625, rel=0.02)
    assert geometry.weight(0, 1) * alpha == pytest.approx(0.0065, rel=0.03)
    assert geometry.weight(1, 0) * alpha == pytest.approx(0.006, rel=0.03)


def test_roman_ipc_reference_is_forward(tmp_path):
    asdf = pytest.importorskip("asdf", reason=optional("asdf"))
    kernel = np.array([[0.0021, 0.0156, 0.0021], [0.0138, 0.9328, 0.0138],
                       [0.0021, 0.0156, 0.0021]])
    path = tmp_path / "roman_ipc.asdf"
    asdf.AsdfFile({"roman": {"meta": {"reftype": "IPC"}, "data": kernel}}).write_to(path)
    law, geometry, info = reffiles.read_reference(str(path))
    alpha = law.alpha(0.0, 0.0)
    assert alpha == pytest.approx(0.0147)
    assert geometry.weight(1, 0) * alpha == pytest.approx(0.0156)
    assert geometry.weight(1, 1) * alpha == pytest.approx(0.0021)


def test_unknown_reference_kind_is_refused_in_one_line(tmp_path):
    path = tmp_path / "what.fits"
    h = fits.PrimaryHDU(np.eye(3))
    h.header["REFTYPE"] = "DARK"
    h.writeto(path)
    with pytest.raises(IPCInputError, match=r"what.fits: not an IPC reference file") as e:
        reffiles.read_reference(str(path))
    assert "\n" not in str(e.value)


# ---- the law fit ---------------------------------------------------------------------

def test_law_fit_only_hot_pixels_says_what_was_assumed():
    rows = []
    for s in np.geomspace(1000.0, 40000.0, 8):
        a = 0.006 - 0.0003 * np.log10(s / 1000.0)
        rows.append({"signal": s, "background": 0.0, "n": 100,
                     **{k: {"value": w * a, "error": 2e-5} for k, w in
                        (("x", 1.1), ("y", 0.9), ("diagonal", 0.05), ("second_x", 0.0),
                         ("second_y", 0.0))}})
    geometry, law, fit = lawfit.fit_law(rows, [])
    assert geometry.weight(0, 1) == pytest.approx(1.1, rel=1e-6)
    assert law.alpha(3000.0, 0.0) == pytest.approx(0.006 - 0.0003 * np.log10(3), rel=2e-3)
    assert any("alpha(S,S) assumed" in a for a in fit["assumed"])
    # symmetric, as charge conservation needs
    assert law.alpha(2000.0, 9000.0) == pytest.approx(law.alpha(9000.0, 2000.0))


# ---- the workflow and bad input -------------------------------------------------------

def test_calibrate_python_and_model_file(cpu, tmp_path, small_dark):
    out = tmp_path / "model.json"
    res = calibrate([small_dark], output=str(out), gain=2.0, report_path=str(tmp_path / "r.json"))
    model, doc = CouplingModel.load(out, with_document=True)
    assert doc["provenance"]["darks"][0].endswith("dark.fits[SCI]")
    assert doc["fit"]["assumed"]  # no flats: the other cross-section is assumed
    assert model.geometry.weight(0, 1) * model.law.alpha(1e4, 0.0) == pytest.approx(
        1.08 * 0.0055, rel=0.03)
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["hot_pixels"]["found"] == 8
    assert res["model"].describe() == model.describe()
    with pytest.raises(IPCInputError, match="exists"):
        calibrate([small_dark], output=str(out), gain=2.0)


def test_calibrate_cli(cpu, cli, tmp_path, small_dark):
    out = tmp_path / "m.json"
    r = cli("calibrate", "--darks", small_dark, "--gain", "2", "-o", str(out))
    code, err = r.returncode, r.stderr
    assert code == 0, err
    assert "wrote" in err and CouplingModel.load(out)
    # DN without a gain: one line naming the file
    r = cli("calibrate", "--darks", small_dark, "-o", str(tmp_path / "n.json"))
    code, err = r.returncode, r.stderr
    assert len(err.strip().splitlines()) == 1
    assert code == 2 and "dark.fits[SCI]" in err and "gain" in err
    assert not (tmp_path / "n.json").exists()


def test_darks_without_hot_pixels_and_one_flat_level(cpu, tmp_path, rng):
    dark = write_sci(tmp_path / "d.fits", rng.normal(0, 5.0, (3, 256, 256)))
    with pytest.raises(IPCInputError, match="no isolated hot pixel"):
        calibrate([dark], output=str(tmp_path / "m.json"))
    assert not (tmp_path / "m.json").exists()
    level = 20000.0
    frames = np.array([ipcgen.couple(rng.poisson(level, (256, 256)).astype(float), "constant")
                       for _ in range(6)])
    flat = write_sci(tmp_path / "f.fits", frames)
    res = calibrate([dark], [flat], output=str(tmp_path / "m.json"), read_noise=0.0)
    nm = res["report"]["not_measured"]
    assert any("no isolated hot pixel" in s for s in nm)
    assert any("one level only" in s for s in nm)
    # 5 x 252^2 noise products: each term's standard error is ~1/(2 sqrt(N)) = 4e-4
    assert res["model"].law.alpha(level, level) == pytest.approx(0.0055, abs=0.0013)


def test_darks_and_flats_of_different_shapes_are_each_measured(cpu, tmp_path, small_dark, rng):
    """A full-frame dark beside a subarray flat is one detector's data: each input is
    measured on its own frame (the report records every input's shape)."""
    frames = np.array([ipcgen.couple(rng.poisson(5000.0, (64, 64)).astype(float), "constant")
                       for _ in range(4)])
    # in DN like the dark: the gain given is for every input, and a gain given for
    # data in electrons is refused (the product plan's rule)
    flat = write_sci(tmp_path / "f.fits", frames / 2.0, bunit="DN")
    res = calibrate([small_dark], [flat], gain=2.0, read_noise=0.0)
    shapes = {item["role"]: item["shape"][-2:] for item in res["report"]["inputs"]}
    assert shapes == {"dark": [96, 96], "flat": [64, 64]}
    assert res["report"]["hot_pixels"]["found"] == 8
    assert [bool(r.get("terms")) for r in res["report"]["flats"]["levels"]] == [True]


def test_calibrate_cli_report_and_figures(cpu, cli, tmp_path, small_dark):
    out, rep, figs = tmp_path / "m.json", tmp_path / "r.json", tmp_path / "figs"
    r = cli("calibrate", "--darks", small_dark, "--gain", "2", "-o", str(out), "--report",
            str(rep), "--figures", str(figs), "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    report = json.loads(rep.read_text())
    assert report["fit"]["chosen"] in report["fit"]["forms"]
    assert all(abs(p["pull"]) < 10 for p in report["fit"]["points"])
    # darks only: the law, its map, the held-out stamps, the IPC map across the detector
    # (measured and tested, whether written or not) and one figure per direction (no
    # brighter-fatter kernel, no flat-ramp covariances: not measured, not drawn)
    assert sorted(p.name for p in figs.iterdir()) == sorted(
        [f"calibrate_{d}.png" for d in hotpixels.DIRECTIONS]
        + ["calibrate_law.png", "calibrate_map.png", "calibrate_stamp.png",
           "calibrate_bond_map.png"])
    # the model file decouples through the command line's --model
    frame = tmp_path / "frame.fits"
    write_sci(frame, np.full((32, 32), 1000.0))
    r = cli("decouple", str(frame), str(tmp_path / "out.fits"), "--model", str(out))
    assert r.returncode == 0, r.stderr


def test_saturated_flat_file_is_reported_and_the_rest_used(cpu, tmp_path, small_dark):
    rng = np.random.default_rng(8)
    good = np.array([ipcgen.couple(rng.poisson(5000.0, (96, 96)).astype(float), "constant")
                     for _ in range(4)])
    flat = write_sci(tmp_path / "f5k.fits", good / 2.0, bunit="DN")
    sat = np.full((4, 96, 96), 32000.0)  # clipped at full well: no shot noise left
    dq = np.full((96, 96), 2, np.uint32)  # SATURATED on half of them
    dq[:, :40] = 0
    saturated = write_sci(tmp_path / "fsat.fits", sat, bunit="DN", extra=[("DQ", dq)])
    res = calibrate([small_dark], [flat, saturated], gain=2.0, read_noise=0.0)
    nm = res["report"]["not_measured"]
    assert any("fsat.fits[SCI]" in s and "saturated" in s for s in nm)
    levels = res["report"]["flats"]["levels"]
    assert [bool(r.get("terms")) for r in levels] == [True, False]


def test_reference_alone_and_unknown_reference_in_the_cli(cpu, cli, tmp_path):
    forward = np.array([[0.0, 0.006, 0.0], [0.007, 0.974, 0.007], [0.0, 0.006, 0.0]])
    hdu = fits.PrimaryHDU()
    hdu.header["REFTYPE"] = "IPC"
    hdu.header["TELESCOP"] = "JWST"
    ref = tmp_path / "jwst_ipc.fits"
    fits.HDUList([hdu, fits.ImageHDU(reffiles.invert_kernel(forward), name="SCI")]).writeto(ref)
    out = tmp_path / "m.json"
    r = cli("calibrate", "--reference", str(ref), "-o", str(out))
    assert r.returncode == 0, r.stderr
    model, doc = CouplingModel.load(out, with_document=True)
    assert model.geometry.weight(0, 1) * model.law.alpha(0.0, 0.0) == pytest.approx(0.007,
                                                                                    rel=0.02)
    assert doc["fit"]["chosen"] == "reference file"
    other = tmp_path / "flat_ref.fits"
    h = fits.PrimaryHDU(np.ones((3, 3)))
    h.header["REFTYPE"] = "FLAT"
    h.writeto(other)
    r = cli("calibrate", "--reference", str(other), "-o", str(tmp_path / "n.json"))
    assert r.returncode == 2
    assert "flat_ref.fits: not an IPC reference file of a known kind" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "n.json").exists()


def test_independent_generator_couples_like_a_pixel_loop():
    """The blind generator's vectorised coupling against a plain loop over pixels and offsets."""
    rng = np.random.default_rng(0)
    s = rng.uniform(0, 6e4, (9, 11))
    out = loop_couple(s, ipcgen.LAWS["rising"], ipcgen.WEIGHTS)
    assert np.abs(ipcgen.couple(s, "rising") - out).max() < 1e-9


def test_roman_asdf_ramp_darks(cpu, tmp_path):
    rdm = pytest.importorskip("roman_datamodels.datamodels", reason=optional("roman_datamodels"))
    rng = np.random.default_rng(5)
    shape = (96, 96)
    truth = np.full((3,) + shape, 2.0)
    for k, (y, x) in enumerate([(20, 20), (20, 60), (60, 20), (60, 60), (40, 40), (75, 75)]):
        truth[:, y, x] = np.array([1, 2, 3]) * (4000.0 + 3000.0 * k)
    ramp = np.array([ipcgen.couple(t, "constant") for t in truth]) + rng.normal(0, 3.0,
                                                                                 truth.shape)
    model = rdm.RampModel.create_fake_data(shape=(3,) + shape)
    model.data = (ramp / 2.0).astype(np.float32)
    model.pixeldq = np.zeros(shape, dtype=np.uint32)
    model.groupdq = np.zeros((3,) + shape, dtype=np.uint8)
    src = tmp_path / "dark.asdf"
    model.save(src)
    res = calibrate([str(src)], gain=2.0, refpix=0)
    assert res["report"]["hot_pixels"]["found"] == 6
    got = res["model"].geometry.weight(1, 0) * res["model"].law.alpha(1e4, 0.0)
    assert got == pytest.approx(0.92 * 0.0055, rel=0.05)

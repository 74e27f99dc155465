"""What the products say (issue 27): the summary line of each run, unphysical
pixels masked and counted, and the exact lines of the errors users meet first."""

import errno
import os
import re
import subprocess
import sys
import tempfile

import numpy as np
import pytest
from astropy.io import fits

import ipc_taichi.cluster
from ipc_taichi.fitsio import HISTORY_WIDTH, history_lines
from ipc_taichi.model import CouplingModel
from ipc_taichi.products.conventions import PHYSICAL_RANGE
from ipc_taichi.reference import couple_reference
from tests.helpers import LAW

SUMMARY = re.compile(
    r"^ipc-taichi: (de)?coupled \S+ -> \S+: law donlon2018, edge (zero|isolated), "
    r"(\d+ iterations, (converged|NOT converged|fixed count \(--tol 0\)), )?"
    r"\d+ HDUs? changed( \(\d+ frames\))?(, \d+ unphysical pixels? masked)?, \d+\.\d s$")


def _image(tmp_path, rng, name="img.fits", shape=(20, 22)):
    path = tmp_path / name
    fits.writeto(path, couple_reference(rng.uniform(0, 5000, shape)))
    return path


# --- item 6: a run you can see ------------------------------------------------------------


def test_decouple_and_couple_say_one_summary_line(cli, tmp_path, rng):
    src = _image(tmp_path, rng)
    out = tmp_path / "out.fits"
    r = cli("decouple", src, out)
    assert r.returncode == 0
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and SUMMARY.match(lines[0]), r.stderr
    h = fits.getheader(out)
    assert f"{h['IPCITER']} iterations, converged" in lines[0]
    assert "1 HDU changed" in lines[0] and f"{src} -> {out}" in lines[0]
    r = cli("couple", src, tmp_path / "c.fits")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 0 and len(lines) == 1 and SUMMARY.match(lines[0]), r.stderr
    assert lines[0].startswith("ipc-taichi: coupled") and "iterations" not in lines[0]


def test_quiet_says_nothing_on_success(cli, tmp_path, rng):
    src = _image(tmp_path, rng)
    for command in ("decouple", "couple"):
        r = cli(command, src, tmp_path / f"{command}.fits", "--quiet")
        assert r.returncode == 0 and r.stderr == ""


def test_summary_names_the_model_file_and_the_frames(cli, tmp_path, rng):
    model = tmp_path / "det.json"
    CouplingModel.resolve("constant:0.01").save(model)
    cube = tmp_path / "cube.fits"
    fits.writeto(cube, couple_reference(rng.uniform(0, 5000, (16, 18)))[None].repeat(3, 0))
    r = cli("decouple", cube, tmp_path / "o.fits", "--model", model, "--tol", 0,
            "--max-iter", 4)
    line = r.stderr.strip()
    assert r.returncode == 0 and len(line.splitlines()) == 1
    assert "model det.json (law constant:0.01)" in line
    assert "4 iterations, fixed count (--tol 0)" in line and "1 HDU changed (3 frames)" in line


def test_output_dir_says_a_line_per_file(cli, tmp_path, rng):
    src = _image(tmp_path, rng)
    r = cli("decouple", src, "-o", tmp_path / "out")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 0 and len(lines) == 2, r.stderr
    assert SUMMARY.match(lines[0].replace(str(tmp_path) + os.sep, "")), lines[0]
    assert lines[1] == f"decoupled 1 files into {tmp_path / 'out'}"


def test_the_command_line_starts_without_heavy_imports():
    code = ("import sys, ipc_taichi.cli; print(sorted(m for m in ('taichi', 'dask', "
            "'distributed', 'matplotlib', 'astropy') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stdout + r.stderr


# --- item 3: bad pixels are bad -----------------------------------------------------------


def _with_garbage(tmp_path, rng, values, flag=False):
    """A SCI (+DQ) product whose pixels at (7, 8) and (12, 3) hold ``values``."""
    data = couple_reference(rng.uniform(0, 5000, (20, 20)))
    dq = np.zeros(data.shape, dtype=np.uint32)
    for (y, x), v in zip(((7, 8), (12, 3)), values):
        data[y, x] = v
        dq[y, x] = 1 if flag else 0
    path = tmp_path / ("flagged.fits" if flag else "garbage.fits")
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(data, name="SCI"),
                  fits.ImageHDU(dq, name="DQ")]).writeto(path)
    return path


def test_unphysical_pixels_are_masked_counted_and_said(cli, tmp_path):
    rng = np.random.default_rng(3)
    garbage = _with_garbage(tmp_path, rng, (1e30, np.inf))
    rng = np.random.default_rng(3)
    flagged = _with_garbage(tmp_path, rng, (1e30, np.inf), flag=True)
    a, b = tmp_path / "a.fits", tmp_path / "b.fits"
    r = cli("decouple", garbage, a, *LAW)
    assert r.returncode == 0
    warning = [w for w in r.stderr.splitlines() if "warning" in w]
    assert len(warning) == 1 and "2 unflagged pixel(s)" in warning[0]
    assert "masked: they keep their values and neither give nor take charge" in warning[0]
    assert "spread" not in warning[0] and "give their charge" not in warning[0]
    assert "2 unphysical pixels masked" in r.stderr
    assert cli("decouple", flagged, b, *LAW, "--dq-bits", "DO_NOT_USE").returncode == 0
    got = fits.getdata(a, "SCI")
    # masked exactly as the DQ flag masks them: the same science, bit for bit
    np.testing.assert_array_equal(got, fits.getdata(b, "SCI"))
    assert got[7, 8] == 1e30 and got[12, 3] == np.inf
    assert np.isfinite(np.delete(got.ravel(), [7 * 20 + 8, 12 * 20 + 3])).all()
    assert np.abs(got[7, 9]) < 1e4
    assert fits.getheader(a)["IPCNBAD"] == 2 and fits.getheader(a, "SCI")["IPCNBAD"] == 2
    assert fits.getheader(b)["IPCNBAD"] == 0


def test_tiled_run_masks_and_counts_the_same(cli, tmp_path, rng):
    src = _with_garbage(tmp_path, rng, (-5e6, 3e7))
    a, b = tmp_path / "a.fits", tmp_path / "b.fits"
    assert cli("decouple", src, a, *LAW).returncode == 0
    r = cli("decouple", src, b, *LAW, "--tile", 8)
    assert r.returncode == 0 and "2 unflagged pixel(s)" in r.stderr and "y=7, x=8" in r.stderr
    np.testing.assert_allclose(fits.getdata(b, "SCI"), fits.getdata(a, "SCI"), rtol=1e-9)
    assert fits.getheader(b)["IPCNBAD"] == fits.getheader(a)["IPCNBAD"] == 2


def test_keep_unphysical_is_the_old_behaviour_and_says_so(cli, tmp_path, rng):
    src = _with_garbage(tmp_path, rng, (1e30, np.inf))
    out = tmp_path / "k.fits"
    r = cli("decouple", src, out, *LAW, "--keep-unphysical")
    assert r.returncode == 0
    warning = [w for w in r.stderr.splitlines() if "warning" in w]
    assert len(warning) == 1
    assert "the 1 finite one(s) give their charge to their neighbours" in warning[0]
    assert "the 1 infinite one(s) are masked" in warning[0]
    got = fits.getdata(out, "SCI")
    assert np.abs(got[7, 9]) > 1e20  # spread, as asked
    assert got[12, 3] == np.inf  # infinite: kept as it was
    assert fits.getheader(out)["IPCNBAD"] == 1


def test_the_range_is_the_documented_one():
    assert PHYSICAL_RANGE == (-2e4, 1e6)


# --- item 5: every message right ---------------------------------------------------------


def test_a_gain_that_is_neither_number_nor_file(cli, tmp_path, rng):
    src = _image(tmp_path, rng)
    r = cli("decouple", src, tmp_path / "o.fits", *LAW, "--bunit", "DN", "--gain", "abc")
    assert r.returncode == 2
    assert r.stderr.strip() == ("ipc-taichi: error: --gain abc: neither a number nor a "
                                "readable gain file (no such file)")
    text = tmp_path / "gain.txt"
    text.write_text("2.0\n")
    r = cli("decouple", src, tmp_path / "o.fits", *LAW, "--bunit", "DN", "--gain", text)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert f"--gain {text}: neither a number nor a readable gain file (not a readable FITS" \
        in r.stderr
    assert not (tmp_path / "o.fits").exists()


def test_an_unwritable_directory_names_the_output(cli, tmp_path, rng, monkeypatch):
    src = _image(tmp_path, rng)
    out = tmp_path / "out.fits"

    def read_only(prefix="", suffix="", dir=None, **_):
        name = os.path.join(dir, f"{prefix}wmlqyh8_o30{suffix}")
        raise OSError(errno.EROFS, "Read-only file system", name)

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    r = cli("decouple", src, out, *LAW)
    assert r.returncode == 2
    assert r.stderr.strip() == \
        f"ipc-taichi: error: {out}: cannot be written (Read-only file system)"
    assert ".tmp-" not in r.stderr and not out.exists()


def test_history_cards_are_whole(cli, tmp_path, rng):
    """Each HISTORY card under 72 characters (astropy cuts longer ones at a fixed
    column, inside numbers); the units line reads as a sentence."""
    h = fits.Header()
    for key, value in dict(TELESCOP="LBT-DXU", INSTRUME="LUCI2", BUNIT="DN/s", GAIN=2.5,
                           EXPTIME=815.0, NDIT=10).items():
        h[key] = value
    src = tmp_path / "luci2.fits"
    fits.writeto(src, rng.uniform(0, 10, (16, 16)), header=h)
    geometry = "horizontal=1,vertical=0.9,diagonal=0.1,second=0.02"
    out = tmp_path / "o.fits"
    r = cli("decouple", src, out, *LAW, "--geometry", geometry)
    assert r.returncode == 0, r.stderr
    cards = [str(c) for c in fits.getheader(out)["HISTORY"]]
    assert all(len(c) <= HISTORY_WIDTH for c in cards)
    text = " ".join(c.strip() for c in cards)
    assert "with divided" not in text
    assert ("DN/s -> electrons (gain 2.5 e-/DN; integration time 815 s; divided by 10 "
            "coadded exposures)") in text
    described = CouplingModel.resolve("donlon2018", geometry).describe()
    for number in set(re.findall(r"\d+(?:\.\d+)?", described)):
        assert any(re.search(rf"(?<![\d.]){re.escape(number)}(?![\d.])", c) for c in cards), \
            number


def test_history_lines_cut_between_words():
    text = "a " * 10 + "0.277 / 815 s " + "word " * 20 + "x" * 90
    lines = history_lines(text, width=30)
    assert all(len(line) <= 30 for line in lines)
    assert all(not re.search(r"\d$", line) or line.endswith(("0.277", "815")) for line in lines)
    assert "".join(line.strip() for line in lines).replace(" ", "") == text.replace(" ", "")


@pytest.mark.parametrize("keys", [dict(TELESCOP="LBT-DXU", INSTRUME="LUCI2"),
                                  dict(INSTRUME="LUCI2"), dict(TELESCOP="Keck")])
def test_any_observatory_needs_a_chosen_law(cli, tmp_path, rng, keys):
    h = fits.Header()
    for key, value in keys.items():
        h[key] = value
    src = tmp_path / "ground.fits"
    fits.writeto(src, rng.uniform(0, 5000, (12, 12)), header=h)
    out = tmp_path / "o.fits"
    r = cli("decouple", src, out)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "is not this detector's coupling" in r.stderr and "--model FILE" in r.stderr
    assert "--law" in r.stderr and not out.exists()
    assert cli("decouple", src, out, *LAW).returncode == 0


def test_paths_sent_to_workers_are_absolute(cli, tmp_path, rng, monkeypatch):
    """Workers of a cluster have their own working directory: the inputs, the
    outputs and a gain file go to them as absolute paths."""
    for k in range(2):
        _image(tmp_path, rng, f"in{k}.fits")
    fits.writeto(tmp_path / "gain.fits", np.full((20, 22), 2.0))
    sent = {}

    def fake_files(pairs, options, client, progress=None):
        sent.update(pairs=pairs, options=options)
        results = []
        for src, dst in pairs:
            res = ipc_taichi.cluster.FileResult(
                input=src, output=dst, ok=True, iterations=3, converged=True, frames=1,
                hdus=["x"], law="donlon2018", edge="zero", masked_unphysical=0, seconds=0.1)
            progress(res)
            results.append(res)
        return results

    monkeypatch.setattr(ipc_taichi.cluster, "local_client", lambda *a, **k: None)
    monkeypatch.setattr(ipc_taichi.cluster, "close_client", lambda client: None)
    monkeypatch.setattr(ipc_taichi.cluster, "decouple_files", fake_files)
    monkeypatch.chdir(tmp_path)
    r = cli("decouple", "in0.fits", "in1.fits", "-o", "out", *LAW, "--bunit", "DN",
            "--gain", "gain.fits")
    assert r.returncode == 0, r.stderr
    assert [p for pair in sent["pairs"] for p in pair] == [
        str(tmp_path / "in0.fits"), str(tmp_path / "out" / "in0_decoupled.fits"),
        str(tmp_path / "in1.fits"), str(tmp_path / "out" / "in1_decoupled.fits")]
    assert sent["options"]["options"].gain == str(tmp_path / "gain.fits")
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 3 and lines[2] == "decoupled 2 files into out"
    for k in range(2):  # said with the names as given
        assert lines[k].startswith(f"ipc-taichi: decoupled in{k}.fits -> "
                                   f"{os.path.join('out', f'in{k}_decoupled.fits')}: law")

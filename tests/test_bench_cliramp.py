"""The bench row of a Roman-like ramp through the command line, run small:
its file, its I/O-only copy, and the row's structure and agreement."""

import os

import numpy as np
from astropy.io import fits

from ipc_taichi.bench.cliramp import (
    BORDER,
    TARGET_ASTROPY,
    TARGET_RATIO,
    copy_through_cli_io,
    cpu_description,
    measure_cliramp,
    write_ramp_fits,
)
from ipc_taichi.bench.render import render_section


def test_ramp_file_is_roman_like(cpu, tmp_path):
    path = tmp_path / "ramp.fits"
    write_ramp_fits(path, size=32, groups=3)
    with fits.open(path) as hdul:
        assert hdul[0].header["TELESCOP"] == "ROMAN" and hdul[0].header["INSTRUME"] == "WFI"
        sci = hdul["SCI"]
        assert sci.header["BUNIT"] == "electrons" and sci.data.dtype == np.dtype(">f4")
        cube = sci.data.astype(np.float64)
    assert cube.shape == (3, 32, 32)
    inner = cube[:, BORDER:-BORDER, BORDER:-BORDER]
    # charge accumulates up the ramp: every science pixel at least its sky, more each resultant
    assert np.all(np.diff(inner.sum(axis=(1, 2))) > 0) and inner[0].min() > 10
    # the border holds read noise only: no charge, no stars
    border = cube.copy()
    border[:, BORDER:-BORDER, BORDER:-BORDER] = 0
    assert np.abs(border).max() < 40 and abs(border.mean()) < 1


def test_io_copy_is_the_file_again(cpu, tmp_path):
    src, dst = tmp_path / "ramp.fits", tmp_path / "copy.fits"
    write_ramp_fits(src, size=16, groups=2)
    copy_through_cli_io(str(src), str(dst))
    with fits.open(src) as a, fits.open(dst) as b:
        assert np.array_equal(a["SCI"].data, b["SCI"].data)
        assert b[0].header["TELESCOP"] == "ROMAN" and b["SCI"].header["BUNIT"] == "electrons"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["copy.fits", "ramp.fits"]


def test_small_row_agrees_within_tolerance(cpu, tmp_path):
    row = measure_cliramp(size=64, groups=4, repeats=1, workdir=str(tmp_path))
    assert list(tmp_path.iterdir()) == []  # its files are removed
    assert [r["run"][:3] for r in row["rows"]] == ["(a)", "(b)", "(c)", "(d)"]
    assert "--refpix 4" in row["rows"][1]["run"]  # 64x64 is no Roman full frame
    assert all(len(t) == 1 and t[0] > 0 for t in row["times_s"].values())
    assert all(len(t) == 1 and t[0] > 0 for t in row["cpu_s"].values())
    a, b = (np.median(row["times_s"][k]) for k in "ab")
    assert row["ratio"] == b / a and row["met"] == (row["ratio"] <= TARGET_RATIO)
    d = np.median(row["times_s"]["d"])
    assert row["ratio_astropy"] == b / d and row["met_astropy"] == (b / d <= TARGET_ASTROPY)
    assert row["cpu"] == cpu_description() and "(" in row["cpu"]
    assert len(row["max_diff"]) == len(row["tolerance"]) == 4
    # warm starts change the answer (groups after the first) but within tol x max|S|
    assert row["within_tolerance"]
    assert all(d <= s for d, s in zip(row["max_diff"], row["tolerance"]))
    assert row["max_diff"][0] == 0.0  # the first group has no previous answer: from scratch
    assert all(0 < s < 1 for s in row["tolerance"])  # tol 1e-5 x a few 10^4 e- at most
    assert all(isinstance(r["most iterations of a group"], int) for r in row["rows"][1:3])
    text = render_section(row)
    assert text.startswith("## A Roman-like ramp through the CLI: 64x64 x 4 f32")
    assert "(target <= 3x: " in text and "within tol x max|S|" in text
    assert "(target <= 1.5x: " in text and row["cpu"] in text
    # the CLI's default: $IPC_TAICHI_PRECISION when set, else the file's own (auto: f32)
    assert row["precision"] == (os.environ.get("IPC_TAICHI_PRECISION") or "f32")
    assert row["precision_warm"] == row["precision"]

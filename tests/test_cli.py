"""The ipc-taichi command line, run as a user would (subprocess)."""

import os

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.products.options import product_precision
from ipc_taichi.reference import couple_reference, decouple_reference
from tests.helpers import run_cli


@pytest.fixture
def truth(rng):
    return rng.uniform(0, 60000, (40, 48))


def test_round_trip_and_header(tmp_path, truth):
    src = tmp_path / "truth.fits"
    hdr = fits.Header()
    hdr["OBSERVER"] = "test"
    fits.PrimaryHDU(truth.astype(">f8"), header=hdr).writeto(src)  # big-endian on disk
    coupled, decoupled = tmp_path / "coupled.fits", tmp_path / "decoupled.fits"
    r = run_cli("couple", src, coupled, "--arch", "cpu")
    assert r.returncode == 0, r.stderr
    m = fits.getdata(coupled)
    np.testing.assert_allclose(m, couple_reference(truth), rtol=1e-9)
    r = run_cli("decouple", coupled, decoupled)
    assert r.returncode == 0, r.stderr
    with fits.open(decoupled) as hdul:
        h = hdul[0].header
        d = hdul[0].data
    ref, iterations, converged, _ = decouple_reference(m)
    np.testing.assert_allclose(d, ref, rtol=1e-9)
    assert np.abs(d - truth).max() < 0.05
    assert h["OBSERVER"] == "test"
    assert h["IPCOP"] == "decouple" and h["IPCLAW"] == "donlon2018"
    assert h["IPCITER"] == iterations and h["IPCCONV"] is True and converged
    assert h["IPCARCH"] == "cpu" and h["IPCEDGE"] == "zero"
    assert any("decouple" in str(line) for line in h["HISTORY"])


def test_refuses_to_overwrite(cli, tmp_path, truth):
    src, out = tmp_path / "in.fits", tmp_path / "out.fits"
    fits.writeto(src, truth)
    out.write_bytes(b"precious")
    r = cli("couple", src, out)
    assert r.returncode == 2
    assert "exists" in r.stderr and "--overwrite" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert out.read_bytes() == b"precious"
    # two positional names: --overwrite replaces OUT only if ipc-taichi wrote it
    r = cli("couple", src, out, "--overwrite")
    assert r.returncode == 2 and "not written by ipc-taichi" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert out.read_bytes() == b"precious"
    r = cli("couple", src, "--output", out, "--overwrite")  # named explicitly
    assert r.returncode == 0, r.stderr
    r = cli("couple", src, out, "--overwrite")  # now ours: may be replaced
    assert r.returncode == 0, r.stderr
    assert fits.getdata(out).shape == truth.shape
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".tmp-")]


@pytest.mark.parametrize("hdu, message", [("3", "no such HDU"), ("SCI", "no such HDU"),
                                          ("TAB", "not an image"), ("0", "no data")])
def test_bad_hdu(cli, tmp_path, truth, hdu, message):
    src = tmp_path / "in.fits"
    table = fits.BinTableHDU.from_columns([fits.Column(name="a", format="D", array=[1.0])],
                                          name="TAB")
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(truth, name="IMG"), table]).writeto(src)
    r = cli("decouple", src, tmp_path / "out.fits", "--hdu", hdu)
    assert r.returncode == 2
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and message in line and "in.fits" in line
    assert not (tmp_path / "out.fits").exists()


def test_extension_and_integer_input(cli, tmp_path, rng):
    truth = rng.integers(0, 60000, (20, 30)).astype(np.uint16)  # stored with BZERO
    src = tmp_path / "in.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(truth, name="SCI")]).writeto(src)
    out = tmp_path / "out.fits"
    r = cli("couple", src, out, "--hdu", "SCI", "--law", "constant:0.01", "--edge", "isolated")
    assert r.returncode == 0, r.stderr
    with fits.open(out) as hdul:
        assert [h.name for h in hdul] == ["PRIMARY", "SCI"]  # the product is kept
        assert "BZERO" not in hdul["SCI"].header and hdul["SCI"].header["BITPIX"] == -64
        assert hdul[0].header["IPCOP"] == "couple" and "S_IPC" not in hdul[0].header
        data = hdul["SCI"].data
    np.testing.assert_allclose(data, couple_reference(truth.astype(float), 0.01, None, "isolated"),
                               rtol=1e-12)
    assert data.sum() == pytest.approx(truth.sum(dtype=float), rel=1e-12)


def test_cube_and_nan(cli, tmp_path, rng):
    cube = rng.uniform(0, 60000, (3, 16, 16))
    cube[1, 4, 4] = np.nan
    src, out = tmp_path / "cube.fits", tmp_path / "out.fits"
    fits.writeto(src, cube)
    assert cli("couple", src, out).returncode == 0
    back = tmp_path / "back.fits"
    r = cli("decouple", out, back)
    assert r.returncode == 0, r.stderr
    d = fits.getdata(back)
    assert np.isnan(d[1, 4, 4]) and np.isfinite(np.delete(d.ravel(), 16 * 16 + 4 * 16 + 4)).all()
    assert np.nanmax(np.abs(d - cube)) < 0.05


@pytest.mark.parametrize("args, message", [
    (["--law", "bogus"], "unknown coupling law"),
    (["--law", "constant:0.3"], "too strong"),
    (["--geometry", "diag=1"], "NAME=VALUE"),
])
def test_bad_model_options(cli, tmp_path, truth, args, message):
    src = tmp_path / "in.fits"
    fits.writeto(src, truth)
    r = cli("decouple", src, tmp_path / "out.fits", *args)
    assert r.returncode == 2 and message in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_not_fits_and_missing(cli, tmp_path):
    bad = tmp_path / "bad.fits"
    bad.write_text("not a fits file")
    r = cli("decouple", bad, tmp_path / "out.fits")
    assert r.returncode == 2 and "bad.fits" in r.stderr
    r = cli("decouple", tmp_path / "missing.fits", tmp_path / "out.fits")
    assert r.returncode == 2 and "no such file" in r.stderr


def test_help_documents_options(cli):
    r = cli("decouple", "--help")
    assert r.returncode == 0
    for option in ("--hdu", "--law", "--max-iter", "--tol", "--edge", "--arch", "--precision",
                   "--overwrite", "--geometry"):
        assert option in r.stdout


def test_demo_prints_worked_example():
    r = run_cli("demo", "--size", "128")
    assert r.returncode == 0, r.stderr
    for number in ("9618.94", "9983.31", "9999.13", "9999.95", "stopping rule"):
        assert number in r.stdout
    assert "[Taichi]" not in r.stdout


def test_no_library_module_imports_the_command_line():
    """The command line sits on top: nothing below it imports ``ipc_taichi.cli``."""
    import ast
    import pathlib

    import ipc_taichi

    root = pathlib.Path(ipc_taichi.__file__).parent
    offenders = []
    for path in root.rglob("*.py"):
        rel = path.relative_to(root)
        if rel.parts[0] == "cli":
            continue
        package = ["ipc_taichi", *rel.parts[:-1]]
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = package[:len(package) - node.level + 1] if node.level else []
                module = ".".join(base + ([node.module] if node.module else []))
                names = [module] + [f"{module}.{a.name}" for a in node.names]
            if any(n == "ipc_taichi.cli" or n.startswith("ipc_taichi.cli.") for n in names):
                offenders.append(str(rel))
    assert offenders == []
    assert (root / "cli" / "options.py").exists()


def test_precision_follows_the_file_by_default(cli, tmp_path, rng, monkeypatch):
    """Without ``--precision`` or ``$IPC_TAICHI_PRECISION`` a float32 file is
    decoupled in f32 and a float64 one in f64 (``auto``); the environment,
    when set, is the default instead; ``--precision`` wins over both."""
    frame = rng.uniform(100.0, 5e4, (24, 24))
    paths = {}
    for kind in ("f32", "f64"):
        paths[kind] = tmp_path / f"{kind}.fits"
        data = frame.astype(np.float32 if kind == "f32" else np.float64)
        fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(data, name="SCI")]).writeto(paths[kind])

    def ran(src, *args):
        out = tmp_path / "out.fits"
        r = cli("decouple", src, "--output", out, "--overwrite", "--law", "constant:0.01",
                "--quiet", *args)
        assert r.returncode == 0, r.stderr
        return fits.getheader(out)["IPCPREC"]

    try:
        monkeypatch.delenv("IPC_TAICHI_PRECISION", raising=False)
        assert ran(paths["f32"]) == "f32" and ran(paths["f64"]) == "f64"
        assert ran(paths["f32"], "--precision", "f64") == "f64"
        assert ran(paths["f32"]) == "f32"
        monkeypatch.setenv("IPC_TAICHI_PRECISION", "f64")
        assert ran(paths["f64"], "--precision", "auto") == "f64"
        assert ran(paths["f32"], "--precision", "auto") == "f32"
    finally:
        import ipc_taichi

        ipc_taichi.init("cpu", "f64")
    # the environment, when set, is the default (a fresh process's runtime reads it)
    assert product_precision(None) is None and product_precision("f32") == "f32"
    monkeypatch.delenv("IPC_TAICHI_PRECISION")
    assert product_precision(None) == "auto"

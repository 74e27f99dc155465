"""Pipeline IPC reference files (JWST ``ipc`` 2-D/4-D, Roman IPC, IPC4D) read into a
model with its map and written from one (ipc_taichi.refformats, ipc_taichi.refkernels).

The conventions are checked against the pipelines' own code: jwst 3.0.0's
``ipc_corr.ipc_convolve`` (imported) and romanimpreprocess's ``ipc_fwd`` (its
documented formula, written as a pixel loop here)."""

import json

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.bondmap import BondMap
from ipc_taichi.errors import IPCInputError
from ipc_taichi.geometry import Geometry
from ipc_taichi.model import CouplingModel
from ipc_taichi.reference import couple_reference
from ipc_taichi.refformats import read_model, write_reference
from ipc_taichi.refkernels import (
    invert_kernels,
    rows_from_scatter,
    scatter_from_rows,
    scatter_kernels,
)

asdf = pytest.importorskip("asdf")
ipc_corr = pytest.importorskip("jwst.ipc.ipc_corr")

GEOMETRY = Geometry({(0, 1): 1.0, (0, -1): 1.0, (1, 0): 0.9, (-1, 0): 0.9,
                     (1, 1): 0.1, (1, -1): 0.1, (-1, 1): 0.1, (-1, -1): 0.1})


def hidden_map(shape, geometry=GEOMETRY):
    """A +-12 % gradient across x and a disc 40 % weaker (issue 35's lab map)."""
    ny, nx = shape
    y, x = np.mgrid[:ny, :nx]
    one = 1 + 0.24 * (x / nx - 0.5) - 0.4 * ((y - ny / 2) ** 2 + (x - nx / 2) ** 2 < (ny / 5) ** 2)
    return BondMap.full(geometry, one)


def map_model(law="constant:0.0125", shape=(40, 48), edge="zero", geometry=GEOMETRY):
    return CouplingModel.resolve(law, geometry, edge, bonds=hidden_map(shape, geometry))


def coupling(model, signal=0.0):
    """alpha w(u) b for every half-stencil bond: what a model's map means."""
    a = model.law.alpha(signal, signal)
    return np.stack([a * w * model.bonds.values[k]
                     for k, (_, (w, _)) in enumerate(model.geometry.half_stencil())])


def inside(model):
    """The bonds whose two ends are in the frame (those a kernel file can say)."""
    ny, nx = model.bonds.shape
    y, x = np.mgrid[:ny, :nx]
    return np.stack([(y + dy < ny) & (x + dx >= 0) & (x + dx < nx)
                     for dy, dx in model.bonds.offsets])


# ---- the conventions, against the pipelines' code ------------------------------------

def test_jwst_4d_kernel_sits_at_the_destination_pixel():
    """ipc_convolve with a kernel at one pixel only changes that pixel, from
    the values at q - d (kernel axes first, y before x)."""
    k = np.zeros((3, 3, 9, 11))
    k[:, :, 4, 6] = np.arange(1.0, 10.0).reshape(3, 3)
    frame = np.arange(99.0).reshape(9, 11)
    out = frame.copy()
    ipc_corr.ipc_convolve(out, k, ipc_corr.NumRefPixels(0, 0, 0, 0))
    changed = np.argwhere(out != 0)
    assert changed.tolist() == [[4, 6]]
    expected = sum(k[1 + dy, 1 + dx, 4, 6] * frame[4 - dy, 6 - dx]
                   for dy in (-1, 0, 1) for dx in (-1, 0, 1))
    assert out[4, 6] == expected


SECOND = Geometry({(0, 1): 1, (0, -1): 1, (1, 0): 1, (-1, 0): 1,
                   (0, 2): 0.1, (0, -2): 0.1, (2, 0): 0.1, (-2, 0): 0.1})


@pytest.mark.parametrize("edge,geometry", [("zero", GEOMETRY), ("isolated", GEOMETRY),
                                           ("zero", SECOND)])
def test_forward_rows_through_ipc_convolve_are_the_model(edge, geometry):
    """The model's forward rows (3x3, or 5x5 for a geometry reaching two
    pixels), applied by the pipeline's own convolution, are the model's
    coupling (constant law): the row convention is the pipeline's."""
    model = map_model(edge=edge, geometry=geometry)
    rng = np.random.default_rng(0)
    charge = rng.uniform(0, 3e4, model.bonds.shape)
    rows = rows_from_scatter(scatter_kernels(model, pad=geometry.reach))
    out = charge.copy()
    ipc_corr.ipc_convolve(out, rows, ipc_corr.NumRefPixels(0, 0, 0, 0))
    assert np.abs(out - couple_reference(charge, model=model)).max() < 1e-9 * charge.max()


def test_ipc4d_kernel_sits_at_the_source_pixel():
    """romanimpreprocess ipc_fwd: out[y,x] = sum_d in[y-dy,x-dx] K[1+dy,1+dx,y-dy,x-dx],
    as a pixel loop, is the model's coupling for the scatter kernels."""
    model = map_model(shape=(12, 14))
    k = scatter_kernels(model)
    rng = np.random.default_rng(1)
    charge = rng.uniform(0, 3e4, model.bonds.shape)
    out = np.zeros_like(charge)
    ny, nx = charge.shape
    for y in range(ny):
        for x in range(nx):
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    if 0 <= y - dy < ny and 0 <= x - dx < nx:
                        out[y, x] += charge[y - dy, x - dx] * k[1 + dy, 1 + dx, y - dy, x - dx]
    assert np.abs(out - couple_reference(charge, model=model)).max() < 1e-9 * charge.max()


# ---- export -> read ------------------------------------------------------------------

@pytest.mark.parametrize("fmt", ["jwst", "roman", "ipc4d"])
@pytest.mark.parametrize("superpixel", [False, True])
def test_the_kept_model_comes_back_exactly(tmp_path, fmt, superpixel):
    shape = (40, 48)
    if superpixel:
        coarse = 1 + 0.1 * np.random.default_rng(2).standard_normal((5, 6))
        bonds = BondMap.superpixels(GEOMETRY, coarse, (8, 8), shape)
    else:
        bonds = hidden_map(shape)
    model = CouplingModel.resolve("donlon2018", GEOMETRY, "isolated", bonds=bonds)
    path = tmp_path / ("ref.fits" if fmt == "jwst" else "ref.asdf")
    done = write_reference(model, path, fmt, signal=20000.0)
    assert done["alpha"] == model.law.alpha(20000.0, 20000.0)
    back, info = read_model(path)
    assert back == model and back.bonds == model.bonds
    assert (back.bonds.coarse is not None) == superpixel
    assert "kept" in info["kind"] and info["signal"] == 20000.0


@pytest.mark.parametrize("geometry", [GEOMETRY, SECOND])
def test_jwst_4d_read_from_its_kernels_within_the_rule(tmp_path, geometry):
    """Without the kept model, the map comes back from the inverse kernels to
    the rule's error: the cut of the inverse, ~alpha^2 relative (measured 14
    alpha^2 at this map's 40 % step, 0.2 % at alpha = 1.25 %; float32 file)."""
    r = geometry.reach
    for alpha in (0.006, 0.0125):
        model = map_model(f"constant:{alpha}", geometry=geometry)
        path = tmp_path / f"ref{alpha}.fits"
        write_reference(model, path, "jwst")
        back, info = read_model(path, kept=False)
        assert back.bonds is not None and back.law.alpha(0.0, 0.0) == info["alpha"]
        assert np.median(back.bonds.values) == pytest.approx(1.0, abs=1e-12)
        ratio = coupling(back) / coupling(model)
        assert np.abs(ratio - 1)[inside(model)].max() < 20 * alpha ** 2
        # the pipeline's inverse kernels themselves: centre above 1, neighbours negative
        with fits.open(path) as hdul:
            sci = hdul["SCI"].data
            assert sci.dtype.kind == "f" and sci.dtype.itemsize == 4
            assert sci.shape == (2 * r + 1, 2 * r + 1, 40, 48)
            assert (sci[r, r] > 1).all() and (sci[r, r + 1] < 0).all()
            assert json.loads(bytes(hdul["IPCMODEL"].data).decode())["signal_e"] == 10000.0


def test_ipc4d_read_from_its_kernels(tmp_path):
    model = map_model(shape=(40, 48), geometry=Geometry.terms())
    path = tmp_path / "ipc4d.asdf"
    write_reference(model, path, "ipc4d")
    back, info = read_model(path, kept=False)
    ratio = coupling(back) / coupling(model)
    assert np.abs(ratio - 1)[inside(model)].max() < 1e-5  # float32 kernels
    assert info["map"]["rule_error_max"] < 1e-5  # a bond map's two ends agree


def test_roman_2d_is_the_law_at_the_stated_signal(tmp_path):
    model = map_model("donlon2018")
    path = tmp_path / "roman.asdf"
    write_reference(model, path, "roman", signal=5000.0)
    back, _ = read_model(path, kept=False)
    assert back.bonds is None
    a = back.law.alpha(0.0, 0.0)  # the mean of the four nearest entries
    assert a * back.geometry.weight(0, 1) == pytest.approx(model.law.alpha(5000.0, 5000.0),
                                                           rel=1e-6)
    assert a * back.geometry.weight(1, 0) == pytest.approx(0.9 * model.law.alpha(5000.0, 5000.0),
                                                           rel=1e-6)


def test_a_uniform_4d_file_gives_no_map(tmp_path):
    uniform = CouplingModel.resolve("constant:0.01", GEOMETRY, "zero")
    path = tmp_path / "u.asdf"
    write_reference(uniform, path, "ipc4d", shape=(16, 20))
    back, info = read_model(path, kept=False)
    assert back.bonds is None and info["map"] is None
    assert back.law.alpha(0.0, 0.0) * back.geometry.weight(0, 1) == pytest.approx(0.01, rel=1e-6)
    # the JWST 4-D file of one kernel everywhere (as a CRDS file may hold it)
    inverse = invert_kernels(GEOMETRY.kernel(0.01)).astype(np.float32)
    ref = tmp_path / "u.fits"
    primary = fits.PrimaryHDU()
    primary.header["REFTYPE"], primary.header["TELESCOP"] = "IPC", "JWST"
    data = np.ascontiguousarray(np.broadcast_to(inverse[:, :, None, None], (3, 3, 16, 20)))
    fits.HDUList([primary, fits.ImageHDU(data, name="SCI")]).writeto(ref)
    back, info = read_model(ref)
    assert back.bonds is None and "same kernel" in info["kind"]
    coupled = back.law.alpha(0.0, 0.0) * back.geometry.weight(0, 1)
    assert coupled == pytest.approx(0.01, rel=20 * 0.01 ** 2)  # the inverse's cut


def test_romanimpreprocess_fixture_structure_is_read(tmp_path):
    """Their test fixture's structure: ``{"roman": {"data": K, "dq": ...}}``, no meta,
    with the kernels leaving the frame zeroed; a weaker patch is found."""
    n = 24
    k = np.zeros((3, 3, n, n), dtype=np.float32)
    k[0, 1] = k[2, 1] = 0.015
    k[1, 0] = k[1, 2] = 0.013
    k[0, 0] = k[2, 2] = k[0, 2] = k[2, 0] = 0.002
    k[:, :, 8:16, 8:16] *= 0.6  # every kernel of the patch: its bonds out weaker too
    k[0, :, 0, :] = 0.0
    k[:, 0, :, 0] = 0.0
    k[-1, :, -1, :] = 0.0
    k[:, -1, :, -1] = 0.0
    k[1, 1] = 1.0 - (k.sum(axis=(0, 1)) - k[1, 1])
    path = tmp_path / "roman_wfi_ipc4d.asdf"
    asdf.AsdfFile({"roman": {"data": k, "dq": np.zeros((n, n), np.uint32)}}).write_to(path)
    model, info = read_model(path)
    assert "ipc4d" in info["kind"] and model.bonds is not None
    v = model.bonds.values[model.bonds.offsets.index((1, 0))]
    assert v[11, 11] == pytest.approx(0.6 * v[2, 2], rel=1e-5)   # inside the patch
    assert v[8, 3] == pytest.approx(v[2, 2], rel=1e-5)           # outside it


def test_files_of_other_kinds_are_refused_in_one_line(tmp_path):
    path = tmp_path / "gain.asdf"
    asdf.AsdfFile({"roman": {"meta": {"reftype": "GAIN"}, "data": np.ones((4, 4))}}).write_to(path)
    with pytest.raises(IPCInputError, match="gain.asdf: not an IPC reference") as e:
        read_model(path)
    assert "\n" not in str(e.value)
    wide = CouplingModel.resolve("constant:0.005", {(0, 2): 1, (0, -2): 1, (0, 1): 1,
                                                    (0, -1): 1})
    with pytest.raises(IPCInputError, match="IPC4D file holds 3x3"):
        write_reference(wide, tmp_path / "w.asdf", "ipc4d", shape=(8, 8))
    assert not (tmp_path / "w.asdf").exists()


def test_scatter_and_rows_are_one_array_reindexed():
    model = map_model(shape=(10, 12))
    padded = scatter_kernels(model, pad=1)
    rows = rows_from_scatter(padded)
    back = scatter_from_rows(rows)
    known = np.isfinite(back)
    assert np.array_equal(back[known], padded[:, :, 1:-1, 1:-1][known])
    assert known[:, :, 1:-1, 1:-1].all()


# ---- the command line ----------------------------------------------------------------

def test_export_reference_then_calibrate_reference(cli, tmp_path):
    """export-reference writes each format; calibrate --reference of the JWST 4-D
    file writes the model with its map (kept: exactly the model exported)."""
    model = map_model("donlon2018", shape=(32, 36))
    src = tmp_path / "model.json"
    model.save(src)
    for fmt, name in (("jwst", "ipc.fits"), ("roman", "ipc.asdf"), ("ipc4d", "ipc4d.asdf")):
        r = cli("export-reference", src, "--format", fmt, "-o", tmp_path / name,
                "--signal", "3000")
        assert r.returncode == 0, r.stderr
        assert f"wrote {tmp_path / name} ({fmt}" in r.stderr and "S = 3000 e-" in r.stderr
    r = cli("export-reference", src, "--format", "jwst", "-o", tmp_path / "ipc.fits")
    assert r.returncode == 2 and "exists (use --overwrite" in r.stderr
    out = tmp_path / "from_ref.json"
    r = cli("calibrate", "--reference", tmp_path / "ipc.fits", "-o", out)
    assert r.returncode == 0, r.stderr
    back, doc = CouplingModel.load(out, with_document=True)
    assert back == model and (tmp_path / "from_ref.bonds.npz").exists()
    assert doc["fit"]["chosen"] == "reference file"


def test_calibrate_reference_of_a_4d_file_without_our_model(cli, tmp_path):
    """A 4-D JWST file as CRDS holds it (no kept model): calibrate writes the
    constant law and the map its kernels stand for."""
    model = map_model("constant:0.008", shape=(32, 36), geometry=Geometry.terms())
    written = tmp_path / "ours.fits"
    write_reference(model, written, "jwst")
    ref = tmp_path / "crds_like.fits"
    with fits.open(written) as hdul:
        fits.HDUList([hdul[0].copy(), hdul["SCI"].copy()]).writeto(ref)
    out = tmp_path / "m.json"
    r = cli("calibrate", "--reference", ref, "-o", out, "--report", tmp_path / "r.json")
    assert r.returncode == 0, r.stderr
    back = CouplingModel.load(out)
    assert back.bonds is not None
    ratio = coupling(back) / coupling(model)
    assert np.abs(ratio - 1)[inside(model)].max() < 20 * 0.008 ** 2
    report = json.loads((tmp_path / "r.json").read_text())
    assert "4-D" in report["reference"]["kind"] and report["reference"]["map"]["max"] > 1.05


@pytest.mark.parametrize("border", ["zero", "delta"])
def test_jwst_4d_with_reference_pixel_kernels(tmp_path, border):
    """A 4-D file whose reference-pixel kernels are all zero (no inverse: unknown)
    or the identity (no coupling): the science pixels' map is read to the rule's
    error all the same, and the law is the science pixels' typical coupling."""
    alpha, n = 0.01, 40
    model = map_model(f"constant:{alpha}", shape=(n, n), geometry=Geometry.terms())
    written = tmp_path / "ours.fits"
    write_reference(model, written, "jwst")
    with fits.open(written) as hdul:
        primary, sci = hdul[0].copy(), np.array(hdul["SCI"].data)
    ref = np.ones((n, n), dtype=bool)
    ref[4:-4, 4:-4] = False
    sci[:, :, ref] = 0.0
    if border == "delta":
        sci[1, 1, ref] = 1.0
    path = tmp_path / f"{border}.fits"
    fits.HDUList([primary, fits.ImageHDU(sci, name="SCI")]).writeto(path)
    back, info = read_model(path)
    assert np.isfinite(back.bonds.values).all()
    ratio = coupling(back) / coupling(model)
    science = np.zeros_like(ratio, dtype=bool)
    science[:, 5:-6, 5:-6] = True  # both ends of every bond in the science region
    assert np.abs(ratio - 1)[science].max() < 20 * alpha ** 2
    if border == "delta":  # a bond to an uncoupled pixel: its two ends disagree, said
        assert info["map"]["rule_error_max"] > 0.3


def test_a_damaged_kept_model_is_named(tmp_path):
    model = map_model(shape=(8, 10))
    path = tmp_path / "ref.fits"
    write_reference(model, path, "jwst")
    with fits.open(path, mode="update") as hdul:
        hdul["IPCMODEL"].data[:5] = 0
    with pytest.raises(IPCInputError, match=r"ref.fits\[IPCMODEL\]: not the JSON"):
        read_model(path)
    back, _ = read_model(path, kept=False)  # the kernels are still read
    assert back.bonds.shape == (8, 10)

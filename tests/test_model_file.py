"""The coupling-model file: round trip, refusals, and --model on the command line."""

import json

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi import IPCInputError, couple, decouple
from ipc_taichi.geometry import Geometry
from ipc_taichi.laws import TabulatedLaw, constant, donlon2018
from ipc_taichi.model import DEFAULT_EDGE, DEFAULT_LAW, CouplingModel
from ipc_taichi.reference import couple_reference, decouple_reference
from ipc_taichi.tiling import decouple_tiled


def _anisotropic():
    return CouplingModel.resolve(constant(0.006), Geometry.terms(1.0, 0.8, 0.1, 0.02), "isolated")


@pytest.mark.parametrize("make", [
    _anisotropic,
    lambda: CouplingModel.resolve(donlon2018()),
    lambda: CouplingModel.resolve(TabulatedLaw.from_callable(
        lambda s, n: 0.005 + 1e-8 * (s + n), (0.0, 60000.0), n=9, name="rising")),
])
def test_round_trip_keeps_law_geometry_edge(tmp_path, make):
    model = make()
    path = model.save(tmp_path / "m.json", provenance={"gain": np.float32(2.5)},
                      fit={"chi2": np.array([1.0, 2.0])})
    back, doc = CouplingModel.load(path, with_document=True)
    assert back.geometry == model.geometry and back.edge == model.edge
    s = np.array([0.0, 1e3, 3e4, 6e4])
    np.testing.assert_array_equal(back.law.alpha(s[:, None], s), model.law.alpha(s[:, None], s))
    assert doc["provenance"] == {"gain": 2.5} and doc["fit"] == {"chi2": [1.0, 2.0]}


def test_save_is_atomic_and_refuses_overwrite(tmp_path):
    path = tmp_path / "m.json"
    _anisotropic().save(path)
    with pytest.raises(IPCInputError, match="exists"):
        _anisotropic().save(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


@pytest.mark.parametrize("content, words", [
    ("not json", "not a JSON"),
    (json.dumps({"format": "other"}), "not an ipc_taichi coupling-model file"),
    (json.dumps({"format": "ipc_taichi.coupling_model", "version": 99}), "newer"),
    (json.dumps({"format": "ipc_taichi.coupling_model", "version": 1, "units": "DN",
                 "law": {}}), "electrons"),
    (json.dumps({"format": "ipc_taichi.coupling_model", "version": 1,
                 "law": {"kind": "parametric", "amp_diff": 0, "scale_diff": 1, "amp_level": 0,
                         "scale_level": 1, "floor": 0.2}, "geometry": [[0, 1, 1], [0, -1, 1],
                                                                       [1, 0, 1], [-1, 0, 1]]}),
     "too strong"),
    (json.dumps({"format": "ipc_taichi.coupling_model", "version": 1,
                 "law": {"kind": "spline"}, "geometry": []}), "unknown law kind"),
])
def test_bad_files_give_one_line_naming_the_file(tmp_path, content, words):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(IPCInputError) as err:
        CouplingModel.load(path)
    assert str(path) in str(err.value) and words in str(err.value)
    assert "\n" not in str(err.value)


def test_decouple_takes_a_model_path(tmp_path):
    model = _anisotropic()
    path = model.save(tmp_path / "m.json")
    truth = np.random.default_rng(1).uniform(0, 5e4, (24, 20))
    measured = couple(truth, model=model)
    np.testing.assert_array_equal(decouple(measured, model=str(path)),
                                  decouple(measured, model=model))


def test_cli_model_option(cli, tmp_path):
    model = _anisotropic()
    mpath = model.save(tmp_path / "m.json")
    truth = np.random.default_rng(2).uniform(0, 5e4, (16, 16))
    src = tmp_path / "in.fits"
    fits.PrimaryHDU(couple(truth, model=model)).writeto(src)
    run = cli("decouple", str(src), str(tmp_path / "out.fits"), "--model", str(mpath))
    assert run.returncode == 0
    out = fits.getdata(tmp_path / "out.fits")
    np.testing.assert_allclose(out, truth, rtol=0, atol=1e-6 * truth.max())
    # the model file and --law together are refused before any work
    assert cli("decouple", str(src), str(tmp_path / "o2.fits"), "--model", str(mpath),
               "--law", "constant:0.01").returncode == 2
    assert not (tmp_path / "o2.fits").exists()


# ---- one way to resolve a model: CouplingModel.resolve, used by every entry point ----

_ENTRY_POINTS = {
    "couple": lambda frame, **kw: couple(frame, **kw),
    "decouple": lambda frame, **kw: decouple(frame, **kw),
    "decouple_tiled": lambda frame, **kw: decouple_tiled(frame, tile=8, **kw),
    "couple_reference": lambda frame, **kw: couple_reference(frame, **kw),
    "decouple_reference": lambda frame, **kw: decouple_reference(frame, **kw)[0],
}


@pytest.mark.parametrize("entry", sorted(_ENTRY_POINTS))
@pytest.mark.parametrize("extra", [{"law": "donlon2018"}, {"law": "constant:0.01"},
                                   {"geometry": "horizontal=1"}, {"edge": "zero"},
                                   {"edge": "isolated"}])
def test_model_with_law_geometry_or_edge_is_refused_everywhere(cpu, tmp_path, entry, extra):
    """Even the paper's law or edge, given beside ``model=``, is refused: the
    caller meant one of the two and we cannot know which."""
    model = _anisotropic()
    frame = np.full((12, 12), 1000.0)
    for given in (model, model.save(tmp_path / "m.json")):
        with pytest.raises(IPCInputError, match="not both") as err:
            _ENTRY_POINTS[entry](frame, model=given, **extra)
        assert f"{next(iter(extra))}=" in str(err.value)


@pytest.mark.parametrize("entry", sorted(_ENTRY_POINTS))
def test_every_entry_point_takes_a_model_or_its_path(cpu, tmp_path, entry):
    model = _anisotropic()
    path = model.save(tmp_path / "m.json")
    frame = np.random.default_rng(5).uniform(0, 5e4, (20, 18))
    run = _ENTRY_POINTS[entry]
    by_model, by_path = run(frame, model=model), run(frame, model=str(path))
    by_values = run(frame, law=model.law, geometry=model.geometry, edge=model.edge)
    np.testing.assert_array_equal(by_model, by_path)
    np.testing.assert_array_equal(by_model, by_values)
    # the anisotropic isolated model is not the default: the answer must differ
    assert not np.array_equal(by_model, run(frame))


def test_resolve_defaults_are_the_papers():
    default = CouplingModel.resolve()
    assert default.law == donlon2018()
    assert default.geometry.weights == Geometry.nearest().weights
    assert (default.edge, DEFAULT_EDGE, DEFAULT_LAW) == ("zero", "zero", "donlon2018")
    model = _anisotropic()
    assert CouplingModel.resolve(model) is model  # a model given as the law is the model
    with pytest.raises(IPCInputError, match="once"):
        CouplingModel.resolve(model, model=model)
    with pytest.raises(IPCInputError, match="CouplingModel or a model file path"):
        CouplingModel.resolve(model=3.5)


def test_sections_round_trip_and_decouple_says_it_removed_ipc_only(cpu, tmp_path):
    """Version 2: the brighter-fatter kernel and the non-linearity ride beside the law as
    named sections; decouple uses the law alone and says so in the product."""
    kernel = np.zeros((5, 5))
    kernel[2, 1] = kernel[2, 3] = 3.7e-7
    kernel[1, 2] = kernel[3, 2] = 4.1e-7
    kernel[2, 2] = -kernel.sum()
    sections = {"brighter_fatter": {"kernel": kernel, "units": "1/electron"},
                "classical_nonlinearity": {"beta": 1.5e-6, "form": "M = Q - beta Q^2"}}
    path = _anisotropic().save(tmp_path / "m.json", sections=sections)
    back, doc = CouplingModel.load(path, with_document=True)
    assert doc["version"] == 3
    assert doc["brighter_fatter"]["kernel"][2][1] == pytest.approx(3.7e-7)
    assert doc["classical_nonlinearity"]["beta"] == pytest.approx(1.5e-6)
    with pytest.raises(IPCInputError, match="unknown model-file section"):
        _anisotropic().save(tmp_path / "n.json", sections={"flat_field": {}})
    frame = np.full((24, 24), 100.0)
    frame[12, 12] = 30000.0
    src = tmp_path / "in.fits"
    hdu = fits.ImageHDU(frame.astype(np.float32), name="SCI")
    hdu.header["BUNIT"] = "electron"
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(src)
    from ipc_taichi.products import decouple_file

    decouple_file(str(src), str(tmp_path / "out.fits"), model=str(path))
    with fits.open(tmp_path / "out.fits") as out:
        assert out[0].header["IPCREMOV"] == "IPC only"
        assert any("brighter-fatter, non-linearity not corrected" in str(h)
                   for h in out[0].header["HISTORY"])
        # the law alone was removed: the same as decoupling with the model directly
        np.testing.assert_allclose(out["SCI"].data, decouple(frame, model=back), rtol=1e-6)

"""A lab's measured brighter-fatter kernel seeds discovery, and discover's
brighter-fatter is reported as that kernel (``ipc_taichi.brighterfatter``):
one model of the effect in ``calibrate``'s model file and in ``discover``."""

import json

import numpy as np
import pytest

from ipc_taichi.brighterfatter import kernel_from_deflection, kernel_plausibility
from ipc_taichi.discover import DetectorModel
from ipc_taichi.discover.effects import nonlinearity
from ipc_taichi.discover.model import effects_from_document
from ipc_taichi.model import CouplingModel

TRUTH = {"deflection_x_at_50ke": 0.03, "deflection_y_at_50ke": 0.04, "reach": 0.1,
         "upwind": 1.0}


def _model_file(path, **sections):
    """A coupling-model file (the paper's law) with calibrate's measured sections."""
    doc = CouplingModel.resolve("donlon2018").to_dict()
    doc.update(sections)
    with open(path, "w") as fh:
        json.dump(doc, fh)
    return str(path)


def _bf_section(kernel):
    return {"kernel": kernel.tolist(), "kernel_error": (0.05 * np.abs(kernel) + 1e-9).tolist(),
            "units": "1/electron",
            "convention": "pixel area 1 + sum_d a(d) Q(p+d); a[2+dy][2+dx]"}


def test_sections_become_effects():
    kernel = kernel_from_deflection(0.03, 0.04, 0.1)
    doc = {"brighter_fatter": _bf_section(kernel),
           "classical_nonlinearity": {"beta": 6e-7, "error": 1e-8, "form": "M = Q - beta Q^2"}}
    effects, notes = effects_from_document(doc)
    assert effects["brighter_fatter"] == pytest.approx(TRUTH, rel=1e-6)
    assert effects["classical_nonlinearity"] == {"deficit_at_50ke": pytest.approx(0.03),
                                                 "cubic_term": 0.0}
    assert notes["brighter_fatter"]["unrepresented"] < 1e-6
    start = DetectorModel.from_coupling(CouplingModel.resolve("donlon2018"), 12.0, document=doc)
    assert set(start.effects) == {"brighter_fatter", "classical_nonlinearity"}
    # discover's non-linearity is calibrate's M = Q - beta Q^2
    q = np.array([1000.0, 20000.0, 60000.0])
    np.testing.assert_allclose(nonlinearity(q, **effects["classical_nonlinearity"]),
                               q - 6e-7 * q * q, rtol=1e-12)
    assert effects_from_document({}) == ({}, {})
    with pytest.raises(Exception, match="brighter_fatter.kernel must be a 5x5"):
        effects_from_document({"brighter_fatter": {"kernel": [[0.0] * 4] * 4}}, "m.json")


def test_a_labs_kernel_seeds_discovery_and_discover_reports_the_kernel(tmp_path, cli):
    # frames made with a model file's brighter-fatter kernel; discover --model
    # starts with that effect at the converted deflections: nothing missing.
    # Without the file, discover names brighter_fatter and reports it as a
    # kernel a lab compares with its own.
    kernel = kernel_from_deflection(**TRUTH)
    model_file = _model_file(tmp_path / "coupling.json", brighter_fatter=_bf_section(kernel))
    lab = str(tmp_path / "lab.fits")
    made = cli("simulate-lab", lab, "--size", "64", "--pairs", "2", "--seed", "4",
               "--model", model_file)
    assert made.returncode == 0, made.stderr
    out = str(tmp_path / "seeded.json")
    done = cli("discover", lab, "--model", model_file, "--report", out, "--quiet")
    assert done.returncode == 0, done.stderr
    with open(out) as fh:
        report = json.load(fh)
    assert report["missing_effects"] == [] and report["complete"] is True
    assert "brighter_fatter(deflection_x_at_50ke=0.03" in report["starting_model"]
    seeded = report["seeded_from_model_file"]["brighter_fatter"]
    assert seeded["params"] == pytest.approx(TRUTH, rel=1e-6)
    assert report["brighter_fatter"]["source"].endswith("(not refitted)")
    np.testing.assert_allclose(report["brighter_fatter"]["kernel"], kernel, rtol=1e-6,
                               atol=1e-15)

    out = str(tmp_path / "blind.json")
    done = cli("discover", lab, "--report", out, "--quiet")
    assert done.returncode == 0, done.stderr
    with open(out) as fh:
        report = json.load(fh)
    assert report["missing_effects"] == ["brighter_fatter"]
    found = report["brighter_fatter"]
    assert found["source"] == "fitted" and found["units"] == "1/electron"
    a, err = np.array(found["kernel"]), np.array(found["kernel_error"])
    assert kernel_plausibility(a, err) is None
    # every term is the lab's within 3 errors (measured: within 5 % of the
    # centre term's, -1.266e-6 for -1.26e-6), and the centre within 10 %
    assert np.all(np.abs(a - kernel) <= 3 * err + 1e-15)
    assert a[2, 2] == pytest.approx(kernel[2, 2], rel=0.1)

    bad = _model_file(tmp_path / "bad.json", brighter_fatter={"kernel": [[0.0] * 4] * 4})
    done = cli("discover", lab, "--model", bad)
    assert done.returncode == 2 and "brighter_fatter.kernel must be a 5x5" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1

"""The stpipe Step on a JWST ramp model built with stdatamodels (offline)."""

import os
import subprocess
import sys

import numpy as np
import pytest

from ipc_taichi.reference import couple_reference
from tests.helpers import CPU_ENV, optional

pytest.importorskip("jwst", reason=optional("jwst"))  # the whole file: the Step is jwst's
datamodels = pytest.importorskip("stdatamodels.jwst.datamodels", reason=optional("stdatamodels"))
RampModel, SuperBiasModel = datamodels.RampModel, datamodels.SuperBiasModel
from ipc_taichi.products.jwst_step import Detector1TaichiPipeline, IPCTaichiStep  # noqa: E402

GAIN, BORDER = 2.0, 4
DO_NOT_USE, REFERENCE_PIXEL = 1, 2 ** 31
ENV = dict(CPU_ENV, CRDS_SERVER_URL="", CRDS_PATH=os.devnull)


def _ramp(rng, shape=(32, 36), bias=None):
    """(1, 3) groups in DN; truth and the model."""
    rate_e = np.zeros(shape)
    rate_e[BORDER:-BORDER, BORDER:-BORDER] = rng.uniform(0, 20000,
                                                         (shape[0] - 8, shape[1] - 8))
    truth = np.stack([rate_e * (g + 1) / GAIN for g in range(3)])[np.newaxis]
    data = np.zeros((1, 3) + shape)
    for g in range(3):
        data[0, g, BORDER:-BORDER, BORDER:-BORDER] = couple_reference(
            rate_e[BORDER:-BORDER, BORDER:-BORDER] * (g + 1)) / GAIN
    model = RampModel((1, 3) + shape)
    pixeldq = np.zeros(shape, dtype=np.uint32)
    pixeldq[:BORDER] = pixeldq[-BORDER:] = REFERENCE_PIXEL
    pixeldq[:, :BORDER] = pixeldq[:, -BORDER:] = REFERENCE_PIXEL
    model.pixeldq = pixeldq
    model.data = (data if bias is None else data + bias).astype(np.float32)
    model.meta.filename = "jw01_ramp.fits"
    model.meta.cal_step.superbias = "SKIPPED" if bias is not None else "COMPLETE"
    return model, truth


def test_step_on_ramp_model(rng):
    model, truth = _ramp(rng)
    before = model.data.copy()
    result = IPCTaichiStep(gain=GAIN, law="donlon2018").run(model)
    assert result.meta.cal_step.ipc == "COMPLETE"
    np.testing.assert_array_equal(result.pixeldq, model.pixeldq)
    got = np.asarray(result.data, dtype=float)
    assert result.data.dtype == np.float32
    ref = (model.pixeldq & REFERENCE_PIXEL) != 0
    for g in range(3):
        assert (result.data[0, g][ref] == before[0, g][ref]).all()
        err = np.abs(got[0, g] - truth[0, g])[~ref]
        assert err.max() <= 2e-5 * truth[0, g].max()
        assert np.abs(before[0, g] - truth[0, g])[~ref].max() > 100 * 2e-5 * truth[0, g].max()


def test_step_in_the_ipc_slot_with_superbias(tmp_path, rng):
    """Before the superbias step the groups hold the bias: the step subtracts
    the given superbias, corrects, and adds it back."""
    shape = (32, 36)
    bias = rng.uniform(10000, 12000, shape)
    model, truth = _ramp(rng, shape, bias=bias)
    sb = SuperBiasModel(data=bias.astype(np.float32))
    sb_path = tmp_path / "superbias.fits"
    sb.save(sb_path)
    result = IPCTaichiStep(gain=GAIN, law="donlon2018", superbias=str(sb_path)).run(model)
    got = np.asarray(result.data, dtype=float) - bias
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    for g in range(3):
        # + 2e-3: float32 holds bias + signal (up to ~4e4 DN) to ~2e-3 DN
        assert np.abs(got[0, g] - truth[0, g])[inner].max() <= 2e-5 * truth[0, g].max() + 2e-3
    assert (result.data[0, :, :BORDER] == model.data[0, :, :BORDER]).all()  # reference rows
    with pytest.raises(ValueError, match="superbias"):  # the bias is not collected charge
        IPCTaichiStep(gain=GAIN, law="donlon2018").run(model)


def test_pipeline_swaps_the_ipc_step():
    pipe = Detector1TaichiPipeline()
    assert isinstance(pipe.ipc, IPCTaichiStep)
    assert type(pipe.superbias).__name__ == "SuperBiasStep"


def test_strun(tmp_path, rng):
    """``strun ipc_taichi RAMP --gain=G --law=L`` offline: no CRDS parameter
    lookup (the step has no parameter reference file), no extra flag."""
    model, truth = _ramp(rng)
    src = tmp_path / "jw01_ramp.fits"
    model.save(src)
    r = subprocess.run(
        [os.path.join(os.path.dirname(sys.executable), "strun"),
         "ipc_taichi", str(src), "--gain=2.0", "--law=donlon2018",
         f"--output_dir={tmp_path}"],
        capture_output=True, text=True, env=ENV, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    outs = [p for p in os.listdir(tmp_path) if p.endswith(".fits") and p != "jw01_ramp.fits"]
    assert outs, os.listdir(tmp_path)
    with RampModel(str(tmp_path / outs[0])) as out:
        assert out.meta.cal_step.ipc == "COMPLETE"
        got = np.asarray(out.data, dtype=float)
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    assert np.abs(got[0, 2] - truth[0, 2])[inner].max() <= 2e-5 * truth[0, 2].max()


def test_entry_point_names_the_classes():
    import importlib

    from stpipe import Pipeline

    from ipc_taichi.products.stpipe_entry import get_steps

    for name, alias, is_pipeline in get_steps():
        module, _, cls = name.rpartition(".")
        step = getattr(importlib.import_module(module), cls)
        assert step.class_alias == alias
        assert issubclass(step, Pipeline) == is_pipeline


def test_step_needs_a_chosen_law_and_takes_a_model_file(tmp_path, rng):
    """No silent paper's law on a JWST ramp; ``model=`` a coupling-model file;
    ``.call()`` works offline (no CRDS parameter lookup)."""
    from ipc_taichi.model import CouplingModel

    model, truth = _ramp(rng)
    with pytest.raises(ValueError, match="calibrate"):
        IPCTaichiStep(gain=GAIN).run(model)
    path = tmp_path / "det.json"
    CouplingModel.resolve("donlon2018").save(path)
    src = tmp_path / "jw01_ramp.fits"
    model.save(src)
    result = IPCTaichiStep.call(str(src), gain=GAIN, model=str(path))
    assert result.meta.cal_step.ipc == "COMPLETE"
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    got = np.asarray(result.data, dtype=float)
    assert np.abs(got[0, 2] - truth[0, 2])[inner].max() <= 2e-5 * truth[0, 2].max()


def test_step_records_non_convergence(rng):
    model, _ = _ramp(rng)
    result = IPCTaichiStep(gain=GAIN, law="donlon2018", max_iter=1).run(model)
    assert result.meta.cal_step.ipc == "FAILED"


def test_step_keeps_the_reference_border_without_flags(rng):
    """A subarray at the detector's corner (SUBSTRT1 = SUBSTRT2 = 1) whose
    PIXELDQ lacks REFERENCE_PIXEL flags: its 4 reference rows and columns are
    found from the subarray keywords and never changed."""
    model, _ = _ramp(rng)
    model.pixeldq = np.zeros(model.pixeldq.shape, dtype=np.uint32)
    model.meta.instrument.name = "NIRCAM"
    model.meta.subarray.name = "SUB32"
    model.meta.subarray.xstart, model.meta.subarray.ystart = 1, 1
    model.data[:, :, :BORDER] = 500.0  # reference pixels hold anything
    model.data[:, :, :, :BORDER] = 500.0
    before = np.array(model.data)
    result = IPCTaichiStep(gain=GAIN, law="donlon2018").run(model)
    got = np.asarray(result.data)
    assert (got[:, :, :BORDER] == before[:, :, :BORDER]).all()
    assert (got[:, :, :, :BORDER] == before[:, :, :, :BORDER]).all()
    assert (got[:, :, BORDER:, BORDER:] != before[:, :, BORDER:, BORDER:]).any()

"""Our Step after ``refpix`` in the stock ``calwebb_detector1``, as a post-hook (offline).

The stock pipeline runs with the ``ipc`` step skipped, ``superbias`` given a local
(zero) reference file and ``refpix`` run (its reference files "N/A": not needed for
a non-IRS2 ramp). The one CRDS question left, the context *name* the pipeline records
at its end, is answered offline by a monkeypatch."""

import os
import subprocess
import sys

import numpy as np
import pytest

from tests.helpers import CPU_ENV, optional

pytest.importorskip("jwst", reason=optional("jwst"))
datamodels = pytest.importorskip("stdatamodels.jwst.datamodels", reason=optional("stdatamodels"))
from jwst.group_scale import GroupScaleStep  # noqa: E402
from jwst.pipeline import Detector1Pipeline  # noqa: E402

from ipc_taichi.products.jwst_hooks import configured_step  # noqa: E402
from ipc_taichi.products.jwst_step import IPCTaichiStep  # noqa: E402
from tests.test_products_jwst import GAIN, _ramp  # noqa: E402

OFFLINE = dict(STPIPE_DISABLE_CRDS_STEPPARS="true", CRDS_SERVER_URL="", CRDS_PATH=os.devnull)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HOOK_MODULE = ("from ipc_taichi.products.jwst_hooks import configured_step\n"
               "NRCA1 = configured_step('NRCA1', law='donlon2018', gain=2.0)\n")


@pytest.fixture
def offline(monkeypatch):
    for key, value in OFFLINE.items():
        monkeypatch.setenv(key, value)
    import jwst.stpipe.core as core

    monkeypatch.setattr(core.crds_client, "get_context_used", lambda obs: "jwst_offline.pmap")
    monkeypatch.setattr(core.crds_client, "get_svn_version", lambda: "offline")


def _files(tmp_path, rng, offset=0.0):
    """A bias-free NIRCam subarray ramp at the detector corner (its reference
    pixels flagged) plus ``offset`` DN everywhere, and a zero superbias."""
    model, _ = _ramp(rng)
    model.data = model.data + np.float32(offset)
    model.meta.instrument.name, model.meta.instrument.detector = "NIRCAM", "NRCA1"
    model.meta.exposure.type = "NRC_IMAGE"
    sub = model.meta.subarray
    sub.name, sub.xstart, sub.ystart = "SUB32", 1, 1
    sub.ysize, sub.xsize = model.data.shape[-2:]
    sub.fastaxis, sub.slowaxis = 1, 2
    ramp = tmp_path / "jw01_ramp.fits"
    model.save(ramp)
    sb = datamodels.SuperBiasModel(data=np.zeros(model.data.shape[-2:], np.float32))
    sb.meta.instrument.name, sb.meta.instrument.detector = "NIRCAM", "NRCA1"
    sb.meta.subarray.name, sb.meta.subarray.xstart, sb.meta.subarray.ystart = "SUB32", 1, 1
    sb.meta.subarray.ysize, sb.meta.subarray.xsize = model.data.shape[-2:]
    sb.save(tmp_path / "superbias.fits")
    return str(ramp), str(tmp_path / "superbias.fits")


def _steps(superbias, hooks=None):
    steps = {name: {"skip": True} for name in Detector1Pipeline.step_defs}
    steps["superbias"] = {"override_superbias": superbias}
    steps["refpix"] = {"override_refpix": "N/A", "override_sirskernel": "N/A"}
    if hooks is not None:
        steps["refpix"]["post_hooks"] = hooks
    return steps


@pytest.mark.slow
def test_stock_detector1_with_our_step_after_refpix(tmp_path, rng, offline, monkeypatch):
    ramp, superbias = _files(tmp_path, rng, offset=7.0)
    after_refpix = Detector1Pipeline.call(ramp, steps=_steps(superbias))
    assert after_refpix.meta.cal_step.refpix == "COMPLETE"
    assert after_refpix.meta.cal_step.superbias == "COMPLETE"
    assert after_refpix.meta.cal_step.ipc == "SKIPPED"
    with datamodels.RampModel(ramp) as raw:  # refpix took the 7 DN off
        assert not np.array_equal(raw.data, after_refpix.data)
    direct = IPCTaichiStep.call(after_refpix.copy(), gain=GAIN, law="donlon2018")
    assert direct.meta.cal_step.ipc == "COMPLETE"
    assert not np.array_equal(direct.data, after_refpix.data)
    # the hook as the command line and a parameter file give it: a string naming a
    # configured subclass (a Step instance: test_hook_on_a_step_without_reference_files)
    (tmp_path / "det_hooks.py").write_text(HOOK_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    for hook in ("det_hooks.NRCA1",):
        result = Detector1Pipeline.call(ramp, steps=_steps(superbias, [hook]))
        assert result.meta.cal_step.ipc == "COMPLETE"
        assert result.meta.cal_step.refpix == "COMPLETE"
        assert result.data.dtype == direct.data.dtype
        assert np.array_equal(result.data, direct.data)  # bit for bit
        np.testing.assert_array_equal(result.pixeldq, direct.pixeldq)
        np.testing.assert_array_equal(result.groupdq, direct.groupdq)
        keys = lambda m: {c[0]: c[1] for c in m.extra_fits.PRIMARY.header if c[0] != "IPCDATE"}
        assert keys(result) == keys(direct) and keys(result)["IPCOP"] == "decouple"


def test_hook_on_a_step_without_reference_files(tmp_path, rng, offline):
    ramp, _ = _files(tmp_path, rng)
    direct = IPCTaichiStep.call(ramp, gain=GAIN, law="donlon2018")
    result = GroupScaleStep.call(ramp, post_hooks=[IPCTaichiStep(gain=GAIN, law="donlon2018")])
    assert result.meta.cal_step.ipc == "COMPLETE"
    assert np.array_equal(result.data, direct.data)


def test_dotted_arguments_make_a_shell_command():
    """stpipe 1.1 splits a hook string at its last dot: the pitfall docs/products.md names."""
    from stpipe._subproc import SystemCall

    dotted = GroupScaleStep(post_hooks=[
        "ipc_taichi.products.jwst_step.IPCTaichiStep(gain=2.0, law='donlon2018')"])
    assert isinstance(dotted._post_hooks[0], SystemCall)
    no_dot = GroupScaleStep(post_hooks=[
        "ipc_taichi.products.jwst_step.IPCTaichiStep(gain=2, law='donlon2018')"])
    hook, = no_dot._post_hooks
    assert isinstance(hook, IPCTaichiStep) and hook.gain == 2 and hook.law == "donlon2018"


def test_configured_step():
    cls = configured_step("Det", law="constant:0.01", gain=2.5)
    assert issubclass(cls, IPCTaichiStep) and cls.__module__ == __name__
    step = cls()
    assert (step.law, step.gain, step.model) == ("constant:0.01", 2.5, None)
    assert cls(gain=3.0).gain == 3.0  # given parameters win
    with pytest.raises(ValueError, match="unknown parameter.*gian"):
        configured_step("Bad", gian=2.0)


PARFILE = """#ASDF 1.0.0
#ASDF_STANDARD 1.5.0
%YAML 1.1
%TAG ! tag:stsci.edu:asdf/
--- !core/asdf-1.1.0
class: jwst.group_scale.group_scale_step.GroupScaleStep
name: group_scale
parameters:
  post_hooks: [det_hooks.NRCA1]
...
"""


@pytest.mark.slow
def test_strun_forms(tmp_path, rng):
    """``strun`` with the hook in a parameter file (its module beside the file, found
    without $PYTHONPATH) and on the command line (``--post_hooks=module.Class,``: the
    trailing comma makes a list of one)."""
    ramp, _ = _files(tmp_path, rng)
    direct = IPCTaichiStep.call(ramp, gain=GAIN, law="donlon2018")
    pars = tmp_path / "pars"
    pars.mkdir()
    (pars / "det_hooks.py").write_text(HOOK_MODULE)
    (pars / "group_scale_ipc.asdf").write_text(PARFILE)
    strun = os.path.join(os.path.dirname(sys.executable), "strun")
    env = dict(CPU_ENV, **OFFLINE, PYTHONPATH=ROOT)
    runs = {"parfile": [str(pars / "group_scale_ipc.asdf"), ramp],
            "cmdline": ["jwst.group_scale.GroupScaleStep", ramp, "--post_hooks=det_hooks.NRCA1,"]}
    for name, args in runs.items():
        out = tmp_path / f"{name}.fits"
        extra = {"cmdline": {"PYTHONPATH": ROOT + os.pathsep + str(pars)}}.get(name, {})
        r = subprocess.run([strun, *args, f"--output_file={out}"], capture_output=True,
                           text=True, env=dict(env, **extra), timeout=300, cwd=tmp_path)
        assert r.returncode == 0, r.stderr[-2000:]
        written = [p for p in os.listdir(tmp_path) if p.startswith(name)]
        assert len(written) == 1, os.listdir(tmp_path)
        with datamodels.RampModel(str(tmp_path / written[0])) as got:
            assert got.meta.cal_step.ipc == "COMPLETE"
            assert np.array_equal(got.data, direct.data)

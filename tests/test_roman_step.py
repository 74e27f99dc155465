"""The Roman step (``strun roman_ipc_taichi``): the science of ``ipc-taichi decouple``, bit
for bit, on the same ASDF ramp; as a post-hook of another step (offline)."""

import os
import subprocess
import sys

import numpy as np
import pytest

from ipc_taichi.reference import couple_reference
from tests.helpers import CPU_ENV, optional

rdm = pytest.importorskip("roman_datamodels.datamodels", reason=optional("roman_datamodels"))
pytest.importorskip("stpipe", reason=optional("stpipe"))
from stpipe import Step  # noqa: E402

from ipc_taichi.products.roman_step import (  # noqa: E402
    RomanIPCTaichiStep,
    roman_configured_step,
)

GAIN = 2.0
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OFFLINE = dict(STPIPE_DISABLE_CRDS_STEPPARS="true", CRDS_SERVER_URL="", CRDS_PATH=os.devnull)
ARRAYS = ("data", "err", "var_poisson", "var_rnoise")


def _ramp_file(tmp_path, rng, shape=(24, 20)):
    """A RampModel (resultants in DN, bias removed) with a 4-pixel reference border."""
    rate = np.zeros(shape)
    rate[4:-4, 4:-4] = rng.uniform(0, 20000, (shape[0] - 8, shape[1] - 8))
    groups = np.zeros((3,) + shape)
    for k in range(3):
        groups[k, 4:-4, 4:-4] = couple_reference(rate[4:-4, 4:-4] * (k + 1)) / GAIN
    model = rdm.RampModel.create_fake_data(shape=(3,) + shape)
    model.data = groups.astype(np.float32)
    model.pixeldq = np.zeros(shape, dtype=np.uint32)
    model.groupdq = np.zeros((3,) + shape, dtype=np.uint8)
    model.meta.filename = "ramp.asdf"
    path = tmp_path / "ramp.asdf"
    model.save(path)
    return path


def _same_science(a, b):
    for name in ARRAYS:
        if name in a and a[name] is not None:
            x, y = np.asarray(a[name]), np.asarray(b[name])
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), name


def _record(model):
    rec = dict(model.meta.ipc_taichi)
    return {k: v for k, v in rec.items() if k not in ("arch",)}


def test_step_call_equals_the_command_line(cli, tmp_path, rng, monkeypatch):
    for key, value in OFFLINE.items():
        monkeypatch.setenv(key, value)
    src = _ramp_file(tmp_path, rng)
    out = tmp_path / "cli.asdf"
    r = cli("decouple", src, out, "--law", "donlon2018", "--gain", GAIN, "--refpix", 4)
    assert r.returncode == 0, r.stderr
    result = RomanIPCTaichiStep.call(str(src), law="donlon2018", gain=GAIN, refpix=4)
    with rdm.open(out) as by_cli, rdm.open(src) as raw:
        _same_science(by_cli, result)
        assert not np.array_equal(np.asarray(raw.data), np.asarray(result.data))
        assert result.meta.cal_step["ipc"] == "COMPLETE"
        assert _record(result) == _record(by_cli)
        assert result.meta.ipc_taichi["operation"] == "decouple"
    # as a post-hook of another Roman step (romancal's refpix in roman_elp)
    hooked = _Passthrough.call(str(src), post_hooks=[
        RomanIPCTaichiStep(law="donlon2018", gain=GAIN, refpix=4)])
    _same_science(result, hooked)
    # the configured subclass a command line names; the paper's law is never a default
    configured = roman_configured_step("WFI01", law="donlon2018", gain=GAIN, refpix=4)
    _same_science(result, configured.call(str(src)))
    with pytest.raises(ValueError, match="model=FILE"):
        RomanIPCTaichiStep.call(str(src), gain=GAIN)


class _Passthrough(Step):
    """A Roman step that changes nothing (a stand-in for romancal's refpix)."""

    spec = "output_ext = string(default='.asdf')"

    @classmethod
    def _datamodels_open(cls, init, **kwargs):
        return rdm.open(init, **kwargs)

    @classmethod
    def get_config_from_reference(cls, dataset, disable=None, crds_observatory=None):
        return cls._empty_config()

    def process(self, step_input):
        return self.open_model(step_input)


@pytest.mark.slow
def test_strun_roman_ipc_taichi_equals_decouple(cli, tmp_path, rng):
    """``strun roman_ipc_taichi`` (found through the stpipe entry point) and
    ``ipc-taichi decouple`` on the same ASDF ramp: the same science, bit for bit."""
    src = _ramp_file(tmp_path, rng)
    out = tmp_path / "cli.asdf"
    assert cli("decouple", src, out, "--law", "donlon2018", "--gain", GAIN).returncode == 0
    strun = os.path.join(os.path.dirname(sys.executable), "strun")
    r = subprocess.run([strun, "roman_ipc_taichi", str(src), "--law=donlon2018",
                        f"--gain={GAIN}", f"--output_file={tmp_path / 'st.asdf'}"],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path,
                       env=dict(CPU_ENV, **OFFLINE, PYTHONPATH=ROOT))
    assert r.returncode == 0, r.stderr[-2000:]
    written = [p for p in os.listdir(tmp_path) if p.startswith("st")]
    assert len(written) == 1, os.listdir(tmp_path)
    with rdm.open(out) as a, rdm.open(tmp_path / written[0]) as b:
        _same_science(a, b)
        assert b.meta.cal_step["ipc"] == "COMPLETE"
        assert _record(a) == _record(b)

"""Tests run Taichi on the CPU arch in f64 unless marked ``gpu``."""

import os
from types import SimpleNamespace

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.cli import main
from ipc_taichi.datasets import worked_example
from ipc_taichi.gpus import cuda_present
from tests.helpers import optional

os.environ.setdefault("IPC_TAICHI_ARCH", "cpu")
os.environ.setdefault("IPC_TAICHI_PRECISION", "f64")


def pytest_collection_modifyitems(config, items):
    if cuda_present():
        return
    skip = pytest.mark.skip(reason="needs a CUDA GPU")
    for item in items:
        if "gpu" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def cli(capsys):
    """``ipc-taichi ARGS`` in this process (Taichi starts once per test
    process): returns ``returncode``, ``stdout``, ``stderr``."""
    def run(*args):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # --help, argparse usage errors
            code = exc.code
        out = capsys.readouterr()
        return SimpleNamespace(returncode=code, stderr=out.err, stdout=out.out)

    return run


@pytest.fixture(autouse=True)
def _precision_restored():
    """A test that switches the runtime to f32 does not leave it there: a chosen
    precision sticks until changed (``ipc_taichi.init``), and the suite runs in f64."""
    yield
    from ipc_taichi import runtime

    info = runtime.current()
    if info is not None and info.precision != "f64" and info.arch == "cpu":
        ipc_taichi.init("cpu", "f64")


@pytest.fixture
def cpu():
    """The CPU/f64 runtime the tests assume."""
    return ipc_taichi.init("cpu", "f64")


@pytest.fixture
def torch():
    """PyTorch, or the test is skipped with the reason (an optional dependency:
    the Python 3.12/3.13 lanes install none)."""
    return pytest.importorskip("torch", reason=optional("torch"))


@pytest.fixture()
def small_dark(tmp_path):
    """Hot pixels in a 3-group dark ramp (DN, gain 2), coupled by the independent
    generator's constant law (tests of calibrate's workflow and its refusals)."""
    from tests.helpers import write_sci
    from tests.independent import ipcgen

    rng = np.random.default_rng(4)
    truth = np.full((3, 96, 96), 2.0)
    pos = [(20, 20), (20, 60), (60, 20), (60, 60), (40, 40), (75, 75), (15, 80), (80, 15)]
    for g in range(3):
        for k, (y, x) in enumerate(pos):
            truth[g, y, x] = (g + 1) * (3000.0 + 2000.0 * k)
    ramp = np.array([ipcgen.couple(t, "constant") for t in truth])
    ramp += rng.normal(0, 3.0, ramp.shape)
    return write_sci(tmp_path / "dark.fits", ramp[None] / 2.0, bunit="DN")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def worked_truth():
    return worked_example()


@pytest.fixture(scope="session")
def psf():
    """The JWST-like F405N optical PSF of the analysis studies (poppy, imported
    only by the tests that need it)."""
    from analysis.psf import optical_psf

    return optical_psf()


@pytest.fixture(scope="session")
def epsf_truth(psf):
    """Its IPC-free effective PSF (photutils ImagePSF)."""
    from analysis.psf import effective_psf

    return effective_psf(psf, 1.0, stage="truth")

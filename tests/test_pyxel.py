"""The Pyxel models (ipc_taichi.pyxel): against Pyxel's own simple_ipc and against couple,
read by read, and the example YAML run as ``pyxel run`` runs it."""

import os
import subprocess
import sys

import numpy as np
import pytest

import ipc_taichi
from tests.helpers import CPU_ENV, optional

pyxel = pytest.importorskip("pyxel", reason=optional("pyxel"))
from pyxel.detectors import (  # noqa: E402
    CMOS,
    CMOSCharacteristics,
    CMOSGeometry,
    Environment,
    Mask,
)
from pyxel.detectors.charge_to_volt_settings import ChargeToVoltSettings  # noqa: E402
from pyxel.models.charge_measurement import simple_ipc  # noqa: E402

from ipc_taichi.pyxel import decouple_ipc, nonlinear_ipc, science_region  # noqa: E402

# Pyxel 3.0.2's own deprecations (its bucket classes, their __array__), not ours to fix
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:pyxel.*",
                                        "ignore:This class will be removed:DeprecationWarning",
                                        "ignore:__array__ implementation doesn't accept a copy"
                                        ":DeprecationWarning")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLE = os.path.join(ROOT, "docs", "examples", "pyxel_nonlinear_ipc.yaml")
CVF = 3.0e-6  # V/e-


def _detector(shape=(20, 24), reference=None):
    det = CMOS(geometry=CMOSGeometry(row=shape[0], col=shape[1], reference_pixels=reference),
               environment=Environment(temperature=40.0),
               characteristics=CMOSCharacteristics(charge_to_volt=ChargeToVoltSettings(
                   value=CVF)))
    det.empty()
    return det


def test_constant_law_is_simple_ipc_away_from_the_edge(rng, cpu):
    det = _detector()
    det.pixel.array = rng.uniform(1e3, 5e4, (20, 24))
    simple_ipc(det, coupling=0.01)
    theirs = np.array(det.signal.array)
    nonlinear_ipc(det, law="constant:0.01", reference_pixels=0)
    ours = np.array(det.signal.array)
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_allclose(ours[inner], theirs[inner], rtol=1e-12)
    # the edge rules differ: Pyxel fills beyond the frame with the mean charge, ours
    # ("zero") with zero-signal pixels, so the outermost ring loses ~alpha * mean per side
    ring = np.ones(ours.shape, dtype=bool)
    ring[inner] = False
    mean = np.mean(det.pixel.array)
    assert np.allclose((theirs - ours)[0, 1:-1], 0.01 * mean * CVF, rtol=1e-9)
    assert np.all(np.abs(theirs - ours)[ring] > 0.5 * 0.01 * mean * CVF)


def test_donlon_law_is_couple_and_reference_border_alone(rng, cpu):
    border = Mask(row=[0, 1, 18, 19], col=[0, 1, 22, 23])
    det = _detector(reference=border)
    charge = rng.uniform(0, 60000, (20, 24))
    det.pixel.array = charge
    nonlinear_ipc(det)  # the paper's law, reference pixels from the detector
    got = np.array(det.signal.array)
    inner = (slice(2, 18), slice(2, 22))
    expect = ipc_taichi.couple(charge[inner], law="donlon2018", edge="zero") * CVF
    np.testing.assert_array_equal(got[inner], expect)
    ref = np.ones(charge.shape, dtype=bool)
    ref[inner] = False
    np.testing.assert_array_equal(got[ref], charge[ref] * CVF)
    # the same border given as a number
    nonlinear_ipc(det, reference_pixels=2)
    np.testing.assert_array_equal(det.signal.array, got)


def test_reference_pixels_must_form_a_border():
    assert science_region((10, 12), 3) == (slice(3, 7), slice(3, 9))
    assert science_region((10, 12), Mask(row=[0, 9], col=[0, 1, 11])) == \
        (slice(1, 9), slice(2, 11))
    with pytest.raises(ValueError, match="do not form a border"):
        science_region((10, 12), Mask(row=[0, 5], col=[0]))
    with pytest.raises(ValueError, match="reference_pixels=6"):
        science_region((10, 12), 6)


def test_exposure_every_read_is_couple_of_its_charge(tmp_path, cpu):
    """The example configuration, non-destructive reads: each read's signal is
    ``couple`` of the charge accumulated at that read (the reference border alone),
    and decouple_ipc gives that charge back."""
    cfg = pyxel.load(EXAMPLE)
    cfg.running_mode.outputs = None  # in memory only
    result = pyxel.run_mode(mode=cfg.running_mode, detector=cfg.detector,
                            pipeline=cfg.pipeline)
    bucket = result["/bucket"]
    pixel, signal = np.asarray(bucket["pixel"]), np.asarray(bucket["signal"])
    assert pixel.shape == (5, 64, 64)
    assert np.all(np.diff(pixel[:, 32, 32]) > 0)  # accumulated read after read
    inner = (slice(4, 60), slice(4, 60))
    for t in range(5):
        expect = ipc_taichi.couple(pixel[t][inner], law="donlon2018", edge="zero") * CVF
        np.testing.assert_array_equal(signal[t][inner], expect)
        border = np.ones((64, 64), dtype=bool)
        border[inner] = False
        np.testing.assert_array_equal(signal[t][border], pixel[t][border] * CVF)
    back = result["/data/decouple_ipc"]
    charge = np.asarray(back["charge"])
    assert bool(np.all(back["converged"]))
    for t in range(5):
        scale = np.abs(pixel[t]).max()
        assert np.abs(charge[t] - pixel[t]).max() <= 1e-4 * scale
        # and the coupling was there to remove: the square's edge moved by far more
        assert np.abs(signal[t] / CVF - pixel[t]).max() > 100 * 1e-4 * scale


@pytest.mark.slow
def test_pyxel_run_the_example(tmp_path):
    """``pyxel run docs/examples/pyxel_nonlinear_ipc.yaml`` exits 0 and writes its outputs."""
    exe = os.path.join(os.path.dirname(sys.executable), "pyxel")
    env = dict(CPU_ENV, PYTHONPATH=ROOT)
    r = subprocess.run([exe, "run", EXAMPLE], capture_output=True, text=True, cwd=tmp_path,
                       env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    runs = os.listdir(tmp_path / "pyxel_output")
    assert len(runs) == 1
    written = set(os.listdir(tmp_path / "pyxel_output" / runs[0]))
    assert {"detector_image.fits", "detector_signal.npy"} <= written
    signal = np.load(tmp_path / "pyxel_output" / runs[0] / "detector_signal.npy")
    assert signal.shape[-2:] == (64, 64) and np.isfinite(signal).all()


def test_decouple_ipc_alone(rng, cpu):
    det = _detector()
    det.set_readout(times=[10.0])
    truth = rng.uniform(0, 60000, (20, 24))
    det.signal.array = ipc_taichi.couple(truth) * CVF
    decouple_ipc(det, reference_pixels=0)
    got = np.asarray(det.data["/decouple_ipc"]["charge"])[0]
    assert np.abs(got - truth).max() <= 1e-4 * truth.max()

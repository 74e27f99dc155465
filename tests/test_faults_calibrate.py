"""Issue 37's faults of ``ipc-taichi calibrate``: each fixed with a test that
failed at a53f084.

Bad inputs end in one line naming the file or the option, exit 2, no model
written (a one-level flat without IPC, a noiseless flat, ``--figures FILE``
checked before the work); the console gives alpha and the geometry weights
with their errors, and says "non-linear IPC: DETECTED" only where the
held-out transfer check supports it.
"""

import numpy as np
import pytest

from ipc_taichi.calibrate import calibrate, workflow
from tests.helpers import write_sci


def _one_line(r, tmp_path, *words):
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and "Traceback" not in line, line
    for w in words:
        assert w in line, line
    assert not (tmp_path / "m.json").exists()
    return line


def test_a_one_level_flat_without_ipc_is_refused_in_one_line(cpu, cli, tmp_path):
    rng = np.random.default_rng(5)
    flat = write_sci(tmp_path / "flat.fits", rng.poisson(20000.0, (6, 48, 48)).astype(float))
    r = cli("calibrate", "--flats", flat, "-o", tmp_path / "m.json", "--read-noise", "0")
    _one_line(r, tmp_path, "no interpixel coupling measured")


def test_flat_ramps_without_ipc_are_refused_in_one_line(cpu, cli, tmp_path):
    rng = np.random.default_rng(6)
    ramps = np.cumsum(rng.poisson(1000.0, (3, 4, 48, 48)).astype(float), axis=1)
    flat = write_sci(tmp_path / "ramps.fits", ramps)
    r = cli("calibrate", "--flats", flat, "-o", tmp_path / "m.json", "--read-noise", "0")
    _one_line(r, tmp_path, "no interpixel coupling measured")


@pytest.mark.parametrize("integrations", [1, 3])
def test_a_noiseless_flat_ramp_is_refused_naming_the_file(cpu, cli, tmp_path, integrations):
    ramp = np.stack([np.full((48, 48), 1000.0 * (g + 1)) for g in range(5)])
    flat = write_sci(tmp_path / "flat.fits", np.repeat(ramp[None], integrations, axis=0))
    r = cli("calibrate", "--flats", flat, "-o", tmp_path / "m.json", "--read-noise", "0")
    _one_line(r, tmp_path, "flat.fits[SCI]", "no shot noise")


@pytest.mark.parametrize("where", ["file", "under a file"])
def test_figures_that_cannot_be_a_folder_are_refused_before_the_work(cli, tmp_path,
                                                                    small_dark, monkeypatch,
                                                                    where):
    def work(*args, **kwargs):
        raise AssertionError("the inputs were read")

    monkeypatch.setattr(workflow, "read_frames", work)
    taken = tmp_path / "figs.png"
    taken.write_bytes(b"x")
    folder = taken if where == "file" else taken / "figs"
    r = cli("calibrate", "--darks", small_dark, "--gain", "2", "-o", tmp_path / "m.json",
            "--figures", folder)
    _one_line(r, tmp_path, f"--figures {folder}")
    assert taken.read_bytes() == b"x"


def test_the_console_gives_alpha_and_the_weights_with_their_errors(cpu, cli, tmp_path,
                                                                   small_dark):
    r = cli("calibrate", "--darks", small_dark, "--gain", "2", "-o", tmp_path / "m.json")
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    alpha = next(x for x in lines if x.startswith("calibrate: alpha"))
    value, error = (float(v) for v in alpha.split(": ")[-1].removesuffix(" %").split(" +- "))
    assert value == pytest.approx(0.55, abs=0.02) and 0 < error < 0.05 * value
    weights = next(x for x in lines if x.startswith("calibrate: geometry weights"))
    for axis in ("x", "y", "diagonal", "second_x", "second_y"):
        assert f" {axis} " in weights
    assert weights.count(" +- ") == 5


def _richer_choice(monkeypatch):
    """The law choice made to prefer a signal-dependent form by 3 standard
    errors (what a handful of hot pixels in two folds can give)."""
    real = workflow.lawfit.choose_law

    def choose(*args, **kwargs):
        geometry, law, fit = real(*args, **kwargs)
        richer = next(name for name in fit["forms"] if name.startswith("smooth"))
        choice = dict(fit["law_choice"], chosen=richer, constant_fits_as_well=False,
                      margin_against_constant={richer: 3.0})
        return geometry, law, dict(fit, chosen=richer, law_choice=choice)

    monkeypatch.setattr(workflow.lawfit, "choose_law", choose)


@pytest.mark.parametrize("constant_residual, detected", [(0.0001, False), (0.01, True)])
def test_nonlinear_ipc_is_detected_only_where_the_transfer_check_supports_it(
        cpu, tmp_path, small_dark, monkeypatch, constant_residual, detected):
    from ipc_taichi.calibrate.report import summary_lines

    _richer_choice(monkeypatch)

    def transfer(integrations, events, bins, flat_rows, chosen, **floors):
        one = {"error": 0.0002, "n_pixels": 8, "stamp": None}
        return {"form": chosen, "chosen": dict(one, residual=0.0001),
                "constant": dict(one, residual=constant_residual),
                "uncorrected": dict(one, residual=0.0055)}

    monkeypatch.setattr(workflow.transfer, "held_out_residuals", transfer)
    res = calibrate([small_dark], gain=2.0)
    assert res["report"]["nonlinear_ipc"]["detected"] is detected
    line = next(x for x in summary_lines(res["report"], res["model"])
                if x.startswith("non-linear IPC"))
    assert line.startswith("non-linear IPC: DETECTED" if detected else
                           "non-linear IPC: not detected"), line
    if not detected:
        assert "not confirmed" in line and "best constant corrects as well" in line

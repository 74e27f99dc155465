"""Ways not to lose work: signals, non-convergence, bad options, overwrites,
scaled integer storage, empty frames."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.gpus import cuda_present
from ipc_taichi.reference import couple_reference
from tests.helpers import CPU_ENV as ENV


def _start(*args):
    return subprocess.Popen([sys.executable, "-m", "ipc_taichi.cli", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)


def _written_temporary(directory):
    for name in os.listdir(directory):
        try:
            if name.startswith(".tmp-") and os.path.getsize(directory / name) >= 2880:
                return True
        except OSError:  # removed between the listing and the size
            pass
    return False


@pytest.mark.parametrize("sig, code, delay", [
    (signal.SIGTERM, 143, 0.02),  # early: Taichi may be compiling (it swallows exceptions)
    (signal.SIGINT, 130, 0.05), (signal.SIGTERM, 143, 0.3)])
def test_signal_mid_run_leaves_nothing(tmp_path, rng, sig, code, delay):
    src = tmp_path / "in.fits"
    fits.writeto(src, couple_reference(rng.uniform(0, 60000, (384, 384))))
    out = tmp_path / "out"
    out.mkdir()
    proc = _start("decouple", src, out / "big.fits", "--tile", 24, "--tol", 0, "--max-iter", 20)
    try:
        # the writer's own file: a name reserved by mkstemp is removed at once and
        # created again by the writer, so wait for one that holds a FITS header
        deadline = time.time() + 120
        while not _written_temporary(out) and proc.poll() is None and time.time() < deadline:
            time.sleep(0.02)
        assert proc.poll() is None, proc.communicate()[1]  # still running, its temporary file there
        assert [p.startswith(".tmp-") for p in os.listdir(out)] == [True]
        time.sleep(delay)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:  # a failed assertion must not leave the run behind
            proc.kill()
            proc.communicate()
    assert proc.returncode == code, err
    assert os.listdir(out) == []
    assert len(err.strip().splitlines()) == 1 and "removed" in err


def test_swallowed_interrupt_does_not_commit(tmp_path):
    """A library that swallows the KeyboardInterrupt of a signal (Taichi's
    kernel compiler has bare ``except:``) cannot make the output appear."""
    from ipc_taichi.fitsio import atomic_output
    from ipc_taichi.interrupts import clear_stop, request_stop

    target = tmp_path / "out.fits"
    request_stop(KeyboardInterrupt())
    try:
        with pytest.raises(KeyboardInterrupt):
            with atomic_output(str(target)) as tmp:
                fits.writeto(tmp, np.zeros((2, 2)))
                try:  # what the library does with the signal's exception
                    raise KeyboardInterrupt
                except BaseException:
                    pass
    finally:
        clear_stop()
    assert os.listdir(tmp_path) == []


def test_not_converged_exits_nonzero(cli, tmp_path, rng):
    src, out = tmp_path / "in.fits", tmp_path / "out.fits"
    fits.writeto(src, couple_reference(rng.uniform(0, 60000, (20, 24))))
    r = cli("decouple", "--law", "donlon2018", src, out, "--max-iter", 2)
    assert r.returncode == 3
    assert "in.fits" in r.stderr and "IPCCONV = F" in r.stderr
    h = fits.getheader(out)
    assert h["IPCCONV"] is False and h["IPCITER"] == 2
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "fixed.fits",
            "--max-iter", 2, "--tol", 0)
    assert r.returncode == 0, r.stderr  # a fixed count asked for is not a failure


def test_workers_below_one_fail_at_once(cli, tmp_path, rng):
    paths = []
    for k in range(2):
        paths.append(tmp_path / f"in{k}.fits")
        fits.writeto(paths[-1], rng.uniform(0, 1, (8, 8)))
    t0 = time.perf_counter()
    r = cli("decouple", "--law", "donlon2018", *paths, "-o", tmp_path, "--workers", -1)
    assert r.returncode == 2 and "--workers -1" in r.stderr
    assert time.perf_counter() - t0 < 5
    assert sorted(os.listdir(tmp_path)) == ["in0.fits", "in1.fits"]


def test_two_inputs_and_overwrite(cli, tmp_path, rng):
    """``decouple *.fits --overwrite`` matching exactly two inputs: the second
    input is not replaced by the decoupled first."""
    a, b = tmp_path / "a.fits", tmp_path / "b.fits"
    fits.writeto(a, rng.uniform(0, 60000, (12, 12)))
    fits.writeto(b, rng.uniform(0, 60000, (12, 12)))
    before = b.read_bytes()
    r = cli("decouple", "--law", "donlon2018", a, b, "--overwrite")
    assert r.returncode == 2 and "not written by ipc-taichi" in r.stderr and "--output" in r.stderr
    assert b.read_bytes() == before
    r = cli("decouple", "--law", "donlon2018", a, "--output", a, "--overwrite")
    assert r.returncode == 2 and "is the input" in r.stderr


def test_tile_on_scaled_integer_data(cli, tmp_path, rng):
    """uint16 stored as int16 + BZERO (raw H2RG storage): --tile works and
    equals the whole-frame result."""
    counts = np.round(couple_reference(rng.uniform(0, 60000, (40, 44)))).astype(np.uint16)
    src = tmp_path / "raw.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(counts, name="SCI")]).writeto(src)
    assert fits.getheader(src, 1)["BZERO"] == 32768
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "whole.fits")
    assert r.returncode == 0, r.stderr
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "tiled.fits", "--tile", 16)
    assert r.returncode == 0, r.stderr
    whole = fits.getdata(tmp_path / "whole.fits", "SCI")
    tiled = fits.getdata(tmp_path / "tiled.fits", "SCI")
    assert whole.dtype.itemsize == 8
    assert np.abs(tiled - whole).max() <= 1e-12 * whole.max()
    assert np.abs(whole - counts).max() > 100  # it was decoupled


def test_all_nan_frame_is_an_error(cli, tmp_path):
    src = tmp_path / "nan.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.full((8, 8), np.nan),
                                                   name="SCI")]).writeto(src)
    for extra in ([], ["--tile", 4]):
        r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits", *extra)
        assert r.returncode == 2
        assert "nan.fits[SCI]" in r.stderr and "no finite" in r.stderr
        assert sorted(os.listdir(tmp_path)) == ["nan.fits"]


def test_raw_integer_ramp_refused(cli, tmp_path):
    src = tmp_path / "jw_uncal.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.zeros((1, 2, 8, 8), np.uint16),
                                                   name="SCI")]).writeto(src)
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits")
    assert r.returncode == 2 and "subtract the bias" in r.stderr and "[SCI]" in r.stderr


def test_quiet_silences_the_cuda_notice(tmp_path, rng):
    src = tmp_path / "in.fits"
    fits.writeto(src, rng.uniform(0, 1, (8, 8)))
    env = dict(ENV, IPC_TAICHI_ARCH="auto")
    run = [sys.executable, "-m", "ipc_taichi.cli", "couple", src]
    r = subprocess.run(run + [tmp_path / "a.fits"], capture_output=True, text=True, env=env)
    assert r.returncode == 0
    if not cuda_present():
        assert "CUDA not available" in r.stderr
    r = subprocess.run(run + [tmp_path / "b.fits", "--quiet"], capture_output=True, text=True,
                       env=env)
    assert r.returncode == 0 and r.stderr == ""


def test_correcting_twice_warns(cli, tmp_path, rng):
    src, once, twice = (tmp_path / f"{n}.fits" for n in ("in", "once", "twice"))
    fits.writeto(src, couple_reference(rng.uniform(0, 60000, (16, 16))))
    assert cli("decouple", "--law", "donlon2018", src, once).returncode == 0
    assert fits.getheader(once)["S_IPC"] == "COMPLETE"
    r = cli("decouple", "--law", "donlon2018", once, twice)
    assert r.returncode == 0
    assert r.stderr.count("warning") == 1 and "already corrected" in r.stderr
    assert "once.fits" in r.stderr


@pytest.mark.parametrize("args, message", [
    (["--gain", "2", "--bunit", "electron"], "a gain was given"),
    (["--output-dtype", "float32", "--output", "x.fits.gz"], "uncompressed"),
])
def test_option_mistakes(cli, tmp_path, rng, args, message):
    src = tmp_path / "in.fits"
    fits.writeto(src, rng.uniform(0, 1, (8, 8)))
    args = [str(tmp_path / a) if a.endswith(".gz") else a for a in args]
    if "--output" not in args:
        args = [tmp_path / "out.fits"] + args
    r = cli("decouple", "--law", "donlon2018", src, *args)
    assert r.returncode == 2 and message in r.stderr and len(r.stderr.splitlines()) == 1
    assert sorted(os.listdir(tmp_path)) == ["in.fits"]


def test_bad_header_card_reported_once(cli, tmp_path):
    """A non-standard card is fixed by astropy; the user is told once."""
    src, out = tmp_path / "in.fits", tmp_path / "out.fits"
    fits.writeto(src, np.full((8, 8), 100.0))
    raw = bytearray(src.read_bytes())
    end = raw.find(b"END" + b" " * 77)
    raw[end:end + 160] = (b"ODDCARD = 1.0.0 / not a number".ljust(80)
                          + b"END".ljust(80))
    src.write_bytes(bytes(raw))
    r = cli("decouple", "--law", "donlon2018", src, out)
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("Card 'ODDCARD' is not FITS standard") == 1


def test_many_outputs_named_by_kind():
    from ipc_taichi.cli.frames import output_name

    assert output_name("a/x_rate.fits.gz", "o", "_ipc") == os.path.join("o", "x_rate_ipc.fits")
    assert output_name("a/r_cal.asdf", "o", "_ipc") == os.path.join("o", "r_cal_ipc.asdf")

"""``calibrate`` on a full Roman-size set, in a fresh process: time and peak memory.

The set is made on disk as a detector writes it: uint16 DN FITS ramps (BZERO
32768, ``BUNIT = 'DN'``, a ``GAIN`` keyword, a bias in every read, which
calibrate removes by subtracting each ramp's first read), one dark ramp with
hot pixels and ``nflats`` flat ramps of one illumination rising to ~40 ke-.
Each read is coupled by the project's :func:`ipc_taichi.couple` (a constant
nearest-neighbour alpha); the collected charge is Poisson to the normal
approximation (``rate + sqrt(rate) N(0, 1)``, fast at ~2 ke- a group); the
read noise is Gaussian. Files are written read by read, so the generator
holds a few frames, not a cube.

``ipc-taichi calibrate`` then runs on the set in a fresh process; its wall
time and peak resident memory (``ru_maxrss`` of that child, from
``os.wait4``) are recorded, as are the generator's. Run as
``python -m ipc_taichi.bench.calfull SIZE [SIZE ...]`` (its rows go to
``bench/calibrate_full.json``, its section into ``bench/RESULTS.md``;
``--render ROWS.jsonl ...`` renders rows measured apart, e.g. by
:func:`measure_on` on a set made once). The set (``(nflats x groups +
dark_groups) x SIZE^2 x 2`` bytes: 5.7 GB at 4096) is deleted after each size.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from ..coupling import couple
from ..model import CouplingModel
from .render import render_section

__all__ = ["write_ramp", "dark_reads", "flat_reads", "make_set", "measure_full", "measure_on",
           "calibrate_full_section", "GAIN", "BIAS", "ALPHA", "FLAT_LEVEL"]

GAIN = 1.8
"""e-/DN written in the files' GAIN keyword."""

BIAS = 10000.0
"""DN: the mean bias of every read (each pixel's own within +-300 DN)."""

ALPHA = 0.006
"""The constant nearest-neighbour coupling made into every read."""

FLAT_LEVEL = 40000.0
"""e-: the flats' charge at their last read."""

READ_NOISE = 12.0
"""e- per read."""


def write_ramp(path, reads, shape, gain=GAIN):
    """Write one ramp (1, ngroups, ny, nx) as uint16 DN (int16 + BZERO 32768)
    from ``reads`` (an iterable of (ny, nx) DN frames), read by read, to a
    temporary file renamed at the end."""
    from astropy.io import fits

    ngroups, ny, nx = shape
    head = fits.Header([("XTENSION", "IMAGE"), ("BITPIX", 16), ("NAXIS", 4), ("NAXIS1", nx),
                        ("NAXIS2", ny), ("NAXIS3", ngroups), ("NAXIS4", 1), ("PCOUNT", 0),
                        ("GCOUNT", 1), ("EXTNAME", "SCI"), ("BSCALE", 1), ("BZERO", 32768),
                        ("BUNIT", "DN"), ("GAIN", gain, "e-/DN")])
    tmp = f"{path}.part"
    written = 0
    with open(tmp, "wb") as f:
        f.write(fits.PrimaryHDU().header.tostring().encode("ascii"))
        f.write(head.tostring().encode("ascii"))
        for frame in reads:
            dn = np.clip(np.rint(frame), 0, 65535) - 32768
            f.write(dn.astype(">i2").tobytes())
            written += 1
        if written != ngroups:
            raise ValueError(f"{path}: {written} reads written, {ngroups} declared")
        f.write(b"\0" * (-(2 * ngroups * ny * nx) % 2880))
    os.replace(tmp, path)


def _read_out(charge, bias, rng, gain):
    """One read [DN]: the charge coupled, plus read noise, over the gain, plus bias."""
    noise = rng.standard_normal(charge.shape, dtype=np.float32) * np.float32(READ_NOISE)
    return (np.asarray(couple(charge, law=ALPHA)) + noise) / gain + bias


def _bias(size, rng):
    return BIAS + rng.uniform(-300.0, 300.0, (size, size)).astype(np.float32)


def dark_reads(size, groups, seed=0, n_hot=None, gain=GAIN):
    """The reads [DN] of a dark ramp: a dark current of 0.5 e- a group and
    hot pixels (one per 4000 pixels) collecting 2-60 ke- over the ramp."""
    rng = np.random.default_rng(seed)
    n_hot = size * size // 4000 if n_hot is None else n_hot
    rate = np.full((size, size), 0.5)
    y, x = rng.integers(8, size - 8, n_hot), rng.integers(8, size - 8, n_hot)
    rate[y, x] = np.exp(rng.uniform(np.log(2000.0), np.log(60000.0), n_hot)) / groups
    bias = _bias(size, rng)
    charge = np.zeros((size, size))
    for g in range(groups):
        charge += rng.poisson(rate) if g else 0.0
        yield _read_out(charge, bias, rng, gain)


def flat_reads(size, groups, seed=1, gain=GAIN, level=FLAT_LEVEL):
    """The reads [DN] of a flat ramp rising to ``level`` e- at its last read
    (one group's charge at the first), through a 1 % response map (the same
    for every flat: a fixed pattern)."""
    response = 1.0 + 0.01 * np.random.default_rng(12345).standard_normal((size, size))
    rng = np.random.default_rng(seed)
    rate = response * (level / groups)
    bias = _bias(size, rng)
    charge = np.zeros((size, size))
    for _ in range(groups):
        charge += rate + np.sqrt(rate) * rng.standard_normal((size, size), dtype=np.float32)
        yield _read_out(charge, bias, rng, gain)


def make_set(folder, size, nflats=8, groups=20, dark_groups=10):
    """Write ``dark.fits`` and ``flat_1.fits`` .. ``flat_<nflats>.fits`` in
    ``folder``; returns (dark path, flat paths)."""
    dark = os.path.join(folder, "dark.fits")
    write_ramp(dark, dark_reads(size, dark_groups), (dark_groups, size, size))
    flats = []
    for k in range(nflats):
        flats.append(os.path.join(folder, f"flat_{k + 1}.fits"))
        write_ramp(flats[-1], flat_reads(size, groups, seed=100 + k), (groups, size, size))
    return dark, flats


RSS_LIMIT = 7.5e9
"""Bytes: a child whose resident memory passes this is stopped (the machine is
shared; the must-show is a peak under 8 GB)."""


def _rss(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _child(args, env=None):
    """Run ``args``; (seconds, peak RSS bytes of that child, return code, stderr
    tail). Stopped (SIGKILL, said in the tail) past :data:`RSS_LIMIT`."""
    start = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    stopped = []

    def watch():
        while proc.returncode is None:
            if _rss(proc.pid) > RSS_LIMIT:
                stopped.append(True)
                os.kill(proc.pid, signal.SIGKILL)
                return
            time.sleep(0.5)

    threading.Thread(target=watch, daemon=True).start()
    err = proc.stderr.read().decode(errors="replace")
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if stopped:
        err += f"\nstopped: resident memory passed {RSS_LIMIT / 1e9:g} GB"
    return time.perf_counter() - start, usage.ru_maxrss * 1024, proc.returncode, err[-2000:]


def measure_full(size, nflats=8, groups=20, dark_groups=10, parent=None):
    """Make the set (in a fresh process), run ``ipc-taichi calibrate`` on it (in
    another), delete it; the row of numbers."""
    folder = tempfile.mkdtemp(prefix="calfull_", dir=parent)
    try:
        made = _child([sys.executable, "-m", "ipc_taichi.bench.calfull", "--make", folder,
                       str(size), str(nflats), str(groups), str(dark_groups)], _env())
        if made[2]:
            raise RuntimeError(f"making the set failed: {made[3]}")
        row = measure_on(folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return {**row, "make_s": made[0], "make_peak_gb": made[1] / 1e9}


def _env():
    return dict(os.environ, IPC_TAICHI_ARCH=os.environ.get("IPC_TAICHI_ARCH", "cpu"))


def measure_on(folder):
    """``ipc-taichi calibrate`` in a fresh process on the set in ``folder``
    (:func:`make_set`'s files): the row of numbers (no ``make_*``)."""
    from astropy.io import fits

    names = sorted(n for n in os.listdir(folder) if n.endswith(".fits"))
    disk = sum(os.path.getsize(os.path.join(folder, n)) for n in names)
    flats = [os.path.join(folder, n) for n in names if n.startswith("flat_")]
    dark = os.path.join(folder, "dark.fits")
    shapes = [fits.getheader(p, "SCI") for p in (dark, flats[0])]
    size, groups, dark_groups = shapes[1]["NAXIS1"], shapes[1]["NAXIS3"], shapes[0]["NAXIS3"]
    model = os.path.join(folder, "model.json")
    report = os.path.join(folder, "report.json")
    load = os.getloadavg()[0]
    run = _child([sys.executable, "-m", "ipc_taichi.cli", "calibrate", "--darks", dark,
                  "--flats", *flats, "-o", model, "--report", report, "--overwrite"], _env())
    if run[2]:
        raise RuntimeError(f"calibrate failed: {run[3]}")
    with open(report) as f:
        rep = json.load(f)
    return {"size": int(size), "flats": f"{len(flats)} x {groups} x {size}^2",
            "dark": f"{dark_groups} x {size}^2", "set_gb": disk / 1e9,
            "calibrate_s": run[0], "calibrate_peak_gb": run[1] / 1e9, "load_before": load,
            "chosen": rep.get("fit", {}).get("chosen"), "alpha_x": _alpha_x(model),
            "gain": rep.get("gain", {}).get("measured"),
            "read_noise": rep.get("provenance", {}).get("read_noise_e"),
            "bf_sigma": rep.get("brighter_fatter", {}).get("significance"),
            "bf_detected": rep.get("brighter_fatter", {}).get("detected")}


def _alpha_x(model_path):
    """The written model's nearest-neighbour coupling along x at 10 ke- next to
    an empty pixel (made: :data:`ALPHA`)."""
    model = CouplingModel.load(model_path)
    return float(model.geometry.weight(0, 1) * model.law.alpha(1e4, 0.0))


def calibrate_full_section(rows, cpu, load):
    """The RESULTS.md section (:func:`ipc_taichi.bench.render.render_section`)."""
    return {"title": "Calibrate on a Roman-size set (fresh process, peak RSS)",
            "rows": [{"set": f"dark {r['dark']} + flats {r['flats']}",
                      "on disk": f"{r['set_gb']:.2f} GB",
                      "load": (f"{r['load_before']:.0f}" if r.get("load_before") else "-"),
                      "calibrate": f"{r['calibrate_s']:.0f} s",
                      "peak RSS": f"{r['calibrate_peak_gb']:.2f} GB",
                      "making the set": f"{r['make_s']:.0f} s, {r['make_peak_gb']:.2f} GB",
                      "gain measured": (f"{r['gain']:.4g} e-/DN" if r.get("gain") else "-"),
                      "brighter-fatter": (f"{r['bf_sigma']:.1f} sigma" if r.get("bf_sigma")
                                          is not None else "-"),
                      "law": r.get("chosen") or "-",
                      "alpha_x(10 ke-, 0)": (f"{r['alpha_x']:.5f}" if r.get("alpha_x")
                                             else "-")} for r in rows],
            "notes": [f"CPU: {cpu} (2 cores, shared with other sessions); `load`: the load "
                      "average (1 min) when each calibrate started, so the times are upper "
                      f"bounds ({load} when this section was written).",
                      "`python -m ipc_taichi.bench.calfull SIZE ...` (ipc_taichi.bench.calfull): "
                      "uint16 DN ramps (GAIN 1.8 e-/DN, bias in every read), a constant "
                      f"alpha {ALPHA:g} made into every read, flats to ~40 ke-; `ipc-taichi "
                      "calibrate --darks ... --flats ... -o ... --report ...` in a fresh "
                      "process, its peak RSS from os.wait4. Flats whose float64 charge "
                      "together exceeds ipc_taichi.calibrate.stream.STREAM_BYTES (1 GiB) are "
                      "read by row strips; the dark is read whole."]
            + [f"{r['size']}^2: making the set measured by {r['make_note']}." for r in rows
               if r.get("make_note")] + [r["note"] for r in rows if r.get("note")]}


def _cpu():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def main(argv):
    if argv[:1] == ["--make"]:
        folder, size, nflats, groups, dark_groups = argv[1], *map(int, argv[2:6])
        make_set(folder, size, nflats, groups, dark_groups)
        return 0
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    rows = []
    if argv[:1] == ["--render"]:  # rows measured apart (JSON lines files), to RESULTS.md
        for path in argv[1:]:
            with open(path) as f:
                rows += [json.loads(line) for line in f if line.startswith("{")]
        argv = []
    for size in map(int, argv):
        rows.append(measure_full(size))
        print(json.dumps(rows[-1]), flush=True)
    _save(calibrate_full_section(rows, _cpu(), load), rows)
    return 0


MARK = ("<!-- calibrate_full -->", "<!-- /calibrate_full -->")
"""The section's bounds in RESULTS.md (replaced on each run)."""


def _save(section, rows, directory="bench"):
    """The rows to ``calibrate_full.json``; the section into ``RESULTS.md``
    between :data:`MARK` (appended the first time); both written atomically."""
    path = os.path.join(directory, "RESULTS.md")
    with open(path) as f:
        text = f.read()
    block = f"{MARK[0]}\n{render_section(section)}\n{MARK[1]}\n"
    if MARK[0] in text and MARK[1] in text:
        head, rest = text.split(MARK[0], 1)
        text = head + block + rest.split(MARK[1], 1)[1].lstrip("\n")
    else:
        text = text.rstrip("\n") + "\n\n" + block
    for name, content in (("RESULTS.md", text),
                          ("calibrate_full.json", json.dumps({"section": section, "rows": rows},
                                                             indent=1))):
        tmp = os.path.join(directory, f".{name}.part")
        with open(tmp, "w") as f:
            f.write(content)
        os.replace(tmp, os.path.join(directory, name))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

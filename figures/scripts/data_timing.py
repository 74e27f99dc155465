"""Experiment 70: how long decoupling takes here, beside the paper's timings (its section 3.1).

Times :func:`ipc_taichi.decouple` (law donlon2018, 4 nearest neighbours, the
paper's stopping rule) on uniform 0..60000 frames of 512x512 and 2048x2048 on
the Taichi arch the environment selects (IPC_TAICHI_ARCH; the CPU in CI), the
best of a few warm runs after one run that compiles the kernels, and the
round trip of the 2048x2048 result through a FITS file (write + read), the
paper's I/O being a CSV file. Timings depend on the machine and its load: the
numbers are those of the run that wrote the file.
Writes data/70_timing.npz and data/70_timing.results.md.
"""

import os
import tempfile
import time

import numpy as np
from _common import save_npz, write_results
from astropy.io import fits

import ipc_taichi
from ipc_taichi.datasets import uniform_frame

SIZES = (512, 2048)
REPEATS = 3
PAPER = {512: "GPU (GTX 960M) ~2 s, under 10 s with I/O; serial Python ~30 min; "
              "GNU parallel ~8 min",
         2048: "~6 min in all, > 80 % of it writing a CSV file"}


def best_time(fn, repeats=REPEATS):
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main():
    seconds, io = {}, {}
    for n in SIZES:
        frame = ipc_taichi.couple(uniform_frame(n, seed=2018))
        ipc_taichi.decouple(frame)  # compiles the kernels
        seconds[n] = best_time(lambda frame=frame: ipc_taichi.decouple(frame))
    result = ipc_taichi.decouple(frame)
    rt = ipc_taichi.runtime.current()
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "decoupled.fits")

        def round_trip():
            fits.PrimaryHDU(result).writeto(path, overwrite=True)
            with fits.open(path, memmap=False) as hdul:
                assert hdul[0].data.shape == result.shape

        io[2048] = best_time(round_trip)
    save_npz("70_timing", sizes=np.array(SIZES), seconds=np.array([seconds[n] for n in SIZES]),
             fits_round_trip_2048=np.array(io[2048]), cpus=np.array(os.cpu_count() or 0))
    rows = "\n".join(f"| {n}x{n} | {PAPER[n]} | {seconds[n]:.3g} s |" for n in SIZES)
    write_results("70_timing", f"""
## Timings: the paper's beside ours (paper section 3.1)

Data: `data/70_timing.npz` (`figures/scripts/data_timing.py`). `ipc_taichi.decouple`,
law `donlon2018`, 4 nearest neighbours, the paper's stopping rule, precision
`{rt.precision}`, Taichi arch `{rt.arch}` on a machine with \
{os.cpu_count()} CPU cores (shared; timings vary with its load);
the best of {REPEATS} warm runs, after a first run that compiles the kernels.

| frame | paper | ours: decouple |
|---|---|---|
{rows}

The 2048x2048 result written to a FITS file and read back: {io[2048]:.3g} s (the paper wrote
CSV). The machines differ (the paper: a GTX 960M laptop GPU), so this compares orders of
magnitude only; GPU timings of this code are in `docs/performance.md`.
""")


if __name__ == "__main__":
    main()

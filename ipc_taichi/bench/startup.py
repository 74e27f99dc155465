"""The start-up rows of ``make bench``: what a user waits for before any work.

``ipc-taichi --help`` and ``ipc-taichi decouple IN OUT`` of a 64 x 64 frame, each
run as a user runs them, in a fresh process, ``repeats`` times; the median wall
time (and the spread) beside the targets of issue 27 (under 1 s and under 2 s
on this 2-core machine). One decouple runs untimed first, so that Taichi's
offline cache (:mod:`ipc_taichi.runtime`) holds the kernels, as it does on any
machine after the first run. The summary row checks what a run says: the
decouple prints exactly one line on stderr, its summary (law, iterations,
convergence, HDUs, time), and ``--quiet`` none.
"""

import os
import statistics
import subprocess
import sys
import tempfile
import time

from astropy.io import fits

from ..datasets import uniform_frame
from ..reference import couple_reference

__all__ = ["measure_startup", "STARTUP_SIZE", "TARGETS_S"]

STARTUP_SIZE = 64
#: command -> the issue's target wall time, seconds
TARGETS_S = {"help": 1.0, "decouple": 2.0}


def _run(args):
    """``ipc-taichi ARGS`` in a fresh process: ``(wall seconds, process)``."""
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "ipc_taichi.cli", *args], capture_output=True,
                          text=True, env=dict(os.environ, ENABLE_TAICHI_HEADER_PRINT="False"))
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"ipc-taichi {' '.join(args)}: exit {proc.returncode}: {tail}")
    return seconds, proc


def _row(command, what, times):
    median = statistics.median(times)
    return {"command": command, "what": what, "median [s]": median, "min [s]": min(times),
            "max [s]": max(times), "target [s]": TARGETS_S[what],
            "met": "yes" if median < TARGETS_S[what] else "no"}


def measure_startup(repeats=5, size=STARTUP_SIZE):
    """Time ``--help`` and a ``size`` x ``size`` decouple in fresh processes.

    Returns a section for :func:`ipc_taichi.bench.render.render_section`:
    ``{"title", "rows", "notes"}``; the rows hold the median, min and max of
    ``repeats`` wall times [s], the target and whether the median meets it,
    and a row for the summary line. The arch is ``$IPC_TAICHI_ARCH`` (default
    ``auto``).
    """
    load = os.getloadavg()
    helps, decouples = [], []
    with tempfile.TemporaryDirectory(prefix="ipc-startup-") as work:
        src, dst = os.path.join(work, "in.fits"), os.path.join(work, "out.fits")
        fits.writeto(src, couple_reference(uniform_frame(size)))
        decouple = ["decouple", src, "--output", dst, "--overwrite"]
        _, proc = _run(decouple)  # untimed: the offline cache now holds the kernels
        said = proc.stderr.strip().splitlines()
        quiet = _run(decouple + ["--quiet"])[1].stderr.strip().splitlines()
        for _ in range(repeats):
            helps.append(_run(["--help"])[0])
            decouples.append(_run(decouple)[0])
    arch = os.environ.get("IPC_TAICHI_ARCH") or "auto"
    rows = [_row("ipc-taichi --help", "help", helps),
            _row(f"ipc-taichi decouple ({size}x{size}, arch {arch})", "decouple", decouples)]
    summaries = [line for line in said if line.startswith("ipc-taichi: decoupled ")]
    others = [line for line in said if line not in summaries]
    summary_ok = len(summaries) == 1 and not quiet
    notes = [f"Wall time of a fresh `python -m ipc_taichi.cli` process (what the `ipc-taichi` "
             f"script runs), median of {repeats}; load average at start "
             f"{', '.join(f'{v:.2f}' for v in load)} on {os.cpu_count()} cores.",
             f"Summary line: {len(summaries)} on stderr"
             + (f", `{summaries[0].replace(work, '$TMP')}`" if summaries else "")
             + (f"; besides it: {'; '.join(others)}" if others else "")
             + f"; with --quiet {len(quiet)} lines"
             + ("" if summary_ok else " - NOT one summary line")]
    return {"title": "Start-up (issue 27: --help under 1 s, a 64x64 decouple under 2 s)",
            "rows": rows, "notes": notes, "summary_line_ok": summary_ok}

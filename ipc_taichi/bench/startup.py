"""The start-up rows of ``make bench``: what a user waits for before any work.

Each command is run as a user runs it, in a fresh process, ``repeats`` times,
the runs interleaved (help, then per size: the fresh Python, the decouple; and
again), so that a load that comes and goes falls on all of them alike:

- ``ipc-taichi --help``;
- per frame size (64 x 64, and 2048 x 2048 by default), a fresh Python that
  imports NumPy and ``astropy.io.fits`` and reads the file (what any tool that
  reads it pays: the baseline), and ``ipc-taichi decouple IN OUT`` of it.

The median wall time, its spread and the median CPU time (user + system) of
each, and each decouple's ratio to the fresh Python of its size (the median of
the interleaved pairs' ratios), beside the targets: ``--help`` under 1 s
(issue 27), a 64 x 64 decouple under 1 s and at most 2x its fresh Python
(issue 39). One decouple per size runs untimed first, so that Taichi's offline
cache (:mod:`ipc_taichi.runtime`) holds the kernels, as it does on any machine
after the first run, and the file is in the page cache. The summary row checks
what a run says: the decouple prints exactly one line on stderr, its summary
(law, iterations, convergence, HDUs, time), and ``--quiet`` none.

Every process reads its modules' bytecode, as from an installed package
(pip compiles it at install time; an editable install writes it on first
import): with ``bytecode`` (the default) the children get a bytecode cache in
the bench's temporary directory (``PYTHONPYCACHEPREFIX``), filled by the
untimed runs, and ``PYTHONDONTWRITEBYTECODE`` is dropped for them; where it is
set (as on the machines of issue 39's figures) each process would otherwise
compile this package's sixty modules from source (0.07-0.09 s CPU). The
notes say which.
"""

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from astropy.io import fits

from ..datasets import uniform_frame
from ..reference import couple_reference

__all__ = ["measure_startup", "run_fresh", "fresh_env", "STARTUP_SIZE", "STARTUP_SIZES",
           "TARGETS_S", "TARGET_RATIO", "FRESH_PYTHON"]

STARTUP_SIZE = 64  # the frame of the targets
STARTUP_SIZES = (STARTUP_SIZE, 2048)
#: command -> the issues' target wall time, seconds (the decouple's: at STARTUP_SIZE)
TARGETS_S = {"help": 1.0, "decouple": 1.0}
TARGET_RATIO = 2.0  # issue 39: a 64x64 decouple at most 2x a fresh Python reading the file
FRESH_PYTHON = ("import sys\nimport numpy as np\nfrom astropy.io import fits\n"
                "np.array(fits.getdata(sys.argv[1], memmap=False))")
"""The baseline: a fresh Python that imports NumPy and astropy.io.fits and
reads the file's data into memory (``python -c FRESH_PYTHON FILE``)."""


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def fresh_env(pycache=None):
    """The environment of a fresh process: this one's, Taichi's banner off; with
    ``pycache`` (a directory) modules' bytecode is read from and written there
    (``PYTHONPYCACHEPREFIX``, ``PYTHONDONTWRITEBYTECODE`` dropped)."""
    env = dict(os.environ, ENABLE_TAICHI_HEADER_PRINT="False")
    if pycache is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(pycache)
    return env


def run_fresh(argv, pycache=None):
    """``python ARGV`` in a fresh process (:func:`fresh_env`): ``(wall seconds,
    CPU seconds (user + system, the process and its children), the completed
    process)``; an exit code other than 0 raises RuntimeError with its last line."""
    cpu = _children_cpu()
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, *argv], capture_output=True, text=True,
                          env=fresh_env(pycache))
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"{' '.join(map(str, argv[:3]))}: exit {proc.returncode}: {tail}")
    return seconds, _children_cpu() - cpu, proc


def _row(command, what, runs, target=None, ratios=None, baseline=None):
    """A table row from ``runs`` = [(wall, cpu), ...]; a decouple's ``ratios`` (wall,
    interleaved pairs) and ``baseline`` (its fresh Python's runs) give its ratios."""
    walls = [w for w, _ in runs]
    median = statistics.median(walls)
    cpu = statistics.median(c for _, c in runs)
    row = {"command": command, "what": what, "median [s]": median, "min [s]": min(walls),
           "max [s]": max(walls), "CPU median [s]": cpu, "x fresh Python": "",
           "CPU x fresh Python": "", "target [s]": "" if target is None else target,
           "met": "" if target is None else ("yes" if median < target else "no")}
    if ratios:
        ratio = statistics.median(ratios)
        row["x fresh Python"] = f"{ratio:.2f}x"
        row["CPU x fresh Python"] = f"{cpu / statistics.median(c for _, c in baseline):.2f}x"
        if target is not None:
            row["x fresh Python"] += (f" (target <= {TARGET_RATIO:g}x: "
                                      f"{'met' if ratio <= TARGET_RATIO else 'NOT met'})")
    return row


def _summary_notes(said, quiet, work):
    """The summary-line check: ``(ok, note)``."""
    summaries = [line for line in said if line.startswith("ipc-taichi: decoupled ")]
    others = [line for line in said if line not in summaries]
    ok = len(summaries) == 1 and not quiet
    note = (f"Summary line: {len(summaries)} on stderr"
            + (f", `{summaries[0].replace(work, '$TMP')}`" if summaries else "")
            + (f"; besides it: {'; '.join(others)}" if others else "")
            + f"; with --quiet {len(quiet)} lines" + ("" if ok else " - NOT one summary line"))
    return ok, note


def _bytecode_note(bytecode):
    if bytecode:
        return ("Bytecode: cached for every process (PYTHONPYCACHEPREFIX in the bench's "
                "temporary directory, filled by the untimed runs), as an installed package has.")
    return ("Bytecode: as this process has it (PYTHONDONTWRITEBYTECODE="
            f"{os.environ.get('PYTHONDONTWRITEBYTECODE', 'unset')}).")


def measure_startup(repeats=5, sizes=STARTUP_SIZES, bytecode=True):
    """Time ``--help``, and per size a fresh Python reading the file and a decouple
    of it, in fresh processes, interleaved.

    Returns a section for :func:`ipc_taichi.bench.render.render_section`:
    ``{"title", "rows", "notes", "summary_line_ok", "ratios"}``; the rows hold
    the median, min and max of ``repeats`` wall times [s], the median CPU time,
    the decouple's ratio to the fresh Python of its size, the target and whether
    the median meets it; ``ratios`` maps each size to the interleaved pairs'
    ratios. The arch is ``$IPC_TAICHI_ARCH`` (default ``auto``). ``bytecode``:
    the processes share a bytecode cache (see the module docstring); without
    it they inherit this process's setting.
    """
    load = os.getloadavg()
    runs = {"help": []} | {(k, n): [] for n in sizes for k in ("python", "decouple")}
    ratios = {n: [] for n in sizes}
    with tempfile.TemporaryDirectory(prefix="ipc-startup-") as work:
        pycache = os.path.join(work, "pycache") if bytecode else None
        commands = {"help": ["-m", "ipc_taichi.cli", "--help"]}
        for n in sizes:
            src, dst = os.path.join(work, f"in{n}.fits"), os.path.join(work, f"out{n}.fits")
            fits.writeto(src, couple_reference(uniform_frame(n)))
            commands["python", n] = ["-c", FRESH_PYTHON, src]
            commands["decouple", n] = ["-m", "ipc_taichi.cli", "decouple", src, "--output", dst,
                                       "--overwrite"]
            # untimed: Taichi's cache and the bytecode cache fill
            said = run_fresh(commands["decouple", n], pycache)[2].stderr
            if n == sizes[0]:
                quiet = run_fresh(commands["decouple", n] + ["--quiet"], pycache)[2].stderr
                summary_ok, summary = _summary_notes(said.strip().splitlines(),
                                                     quiet.strip().splitlines(), work)
        for _ in range(repeats):
            for key, argv in commands.items():
                runs[key].append(run_fresh(argv, pycache)[:2])
            for n in sizes:
                ratios[n].append(runs["decouple", n][-1][0] / runs["python", n][-1][0])
    arch = os.environ.get("IPC_TAICHI_ARCH") or "auto"
    rows = [_row("ipc-taichi --help", "help", runs["help"], TARGETS_S["help"])]
    for n in sizes:
        target = TARGETS_S["decouple"] if n == STARTUP_SIZE else None
        rows += [_row(f"fresh Python: numpy + astropy.io.fits, read the file ({n}x{n})",
                      "python", runs["python", n]),
                 _row(f"ipc-taichi decouple ({n}x{n}, arch {arch})", "decouple",
                      runs["decouple", n], target, ratios[n], runs["python", n])]
    notes = [f"Wall time of a fresh process (`python -m ipc_taichi.cli`, what the `ipc-taichi` "
             f"script runs), median of {repeats}, the runs interleaved; CPU: user + system "
             f"seconds of the process; x fresh Python: median of the interleaved pairs' "
             f"ratios of wall time; CPU x fresh Python: ratio of the CPU medians (the steadier "
             f"one on a loaded machine). Load average at start "
             f"{', '.join(f'{v:.2f}' for v in load)}, at end "
             f"{', '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores.",
             _bytecode_note(bytecode), summary]
    return {"title": "Start-up (issue 27: --help under 1 s; issue 39: a 64x64 decouple under "
                     f"1 s and <= {TARGET_RATIO:g}x a fresh Python reading the file)",
            "rows": rows, "notes": notes, "summary_line_ok": summary_ok, "ratios": ratios}

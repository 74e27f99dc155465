"""The main job (``make demo``, ``ipc-taichi demo``).

1. The paper's worked example (section 2.3): a 2x2 star at rows/cols 24-25 of
   a 51x51 zero frame, coupled with ``donlon2018`` and decoupled.
2. A uniform 0..60000 random frame (2048x2048 by default) through
   couple -> decouple, timed, with the error per iteration.
"""

import time

import numpy as np

from . import iteration, runtime
from .coupling import couple
from .datasets import WORKED_WINDOW, uniform_frame, worked_example
from .decoupling import decouple


def _trace(measured, truth, **kwargs):
    """Decouple with a per-iteration record of peak and max error."""
    rows = [(0, float(measured.max()), float(np.abs(measured - truth).max()), float("nan"))]

    def record(q, estimate):
        rows.append((q, float(estimate.max()), float(np.abs(estimate - truth).max()), 0.0))

    _, info = decouple(measured, callback=record, full_output=True, **kwargs)
    rows = [(q, peak, err, info.max_delta[q - 1] if q else float("nan"))
            for q, peak, err, _ in rows]
    return rows, info


def run_demo(size=2048, arch=None, precision=None, out=print):
    rt = runtime.init(arch, precision)
    out(f"ipc_taichi demo: arch={rt.arch} precision={rt.precision} law=donlon2018 "
        "(20000*sqrt2 form), 4 nearest neighbours, zero edge")
    out("")
    out("1. Worked example (paper section 2.3): 2x2 star in a 51x51 zero frame")
    truth = worked_example()
    measured = couple(truth)
    out("   coupled window [23:27, 23:27]:")
    for row in measured[WORKED_WINDOW]:
        out("   " + " ".join(f"{v:9.2f}" for v in row))
    rows, info = _trace(measured, truth, max_iter=7, tol=0.0)
    stop = iteration.first_met(info.max_delta, info.max_signal, iteration.TOL)
    out("   iter      peak   max|error|   max|dS|")
    for q, peak, err, delta in rows:
        mark = f"  <- stopping rule (tol {iteration.TOL:g}) stops here" if q == stop else ""
        ds = "" if q == 0 else f"{delta:9.3g}"
        out(f"   {q:4d} {peak:9.2f} {err:12.4g} {ds:>9s}{mark}")
    _, check = decouple(measured, full_output=True)
    out(f"   decouple() with the paper's rule: {check.iterations} iterations, "
        f"converged={check.converged}   (paper: peak 9618.94 -> 9983.31 -> 9999.13 -> 9999.95; "
        "errors 381.06, 16.69, 0.869, 0.0560, 0.0049)")
    out("")

    out(f"2. Uniform 0..60000 random frame, {size}x{size} (seed 2018)")
    truth = uniform_frame(size)
    decouple(couple(truth[:64, :64]))  # kernels compiled before the timings
    t0 = time.perf_counter()
    measured = couple(truth)
    t_couple = time.perf_counter() - t0
    t0 = time.perf_counter()
    decoupled, info = decouple(measured, full_output=True)
    t_decouple = time.perf_counter() - t0
    rows, _ = _trace(measured, truth)
    out("   iter      peak   max|error|   max|dS|")
    for q, peak, err, delta in rows:
        ds = "" if q == 0 else f"{delta:9.3g}"
        out(f"   {q:4d} {peak:9.2f} {err:12.4g} {ds:>9s}")
    out(f"   mean|coupled - true| = {np.abs(measured - truth).mean():.1f}   "
        f"max|decoupled - true| = {np.abs(decoupled - truth).max():.4f}")
    out(f"   iterations to converge: {info.iterations} (converged={info.converged})")
    out(f"   time on {rt.arch} ({rt.precision}): couple {t_couple:.3f} s, "
        f"decouple {t_decouple:.3f} s (kernels compiled beforehand)")
    return 0

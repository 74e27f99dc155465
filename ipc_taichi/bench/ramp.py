"""The bench row of a ramp: every group from scratch, and warm-started.

One up-the-ramp exposure (``groups`` reads of ``size x size`` pixels, a star
field on a sky accumulating with Poisson noise in each group's new charge,
coupled with the law; ``donlon2018`` and a constant law), decoupled through
the Python API as one 3-D stack, in this process:

- ``from scratch``: ``ipc_taichi.decouple(ramp)``, each group from ``S_0 = M``;
- ``warm start``: ``ipc_taichi.decouple(ramp, warm_start=True)``, each group
  from the previous groups' answers plus its new charge
  (:class:`ipc_taichi._warm.WarmStart`).

Both use the paper's stopping rule. The row reports the median time, the
iterations per group, the largest difference between the two answers beside
the stopping rule's ``tol * max|S|`` (the tolerance both meet), and each one's
largest error against the true signal.
"""

import statistics
import time

import numpy as np

import ipc_taichi

from .. import iteration
from ..datasets import star_field

__all__ = ["measure_ramp", "ramp_frames", "RAMP_SIZE", "RAMP_GROUPS"]

RAMP_SIZE = 2048
RAMP_GROUPS = 12
SKY = 40.0  # electrons per group on every pixel


def ramp_frames(size, groups, law="donlon2018", seed=5):
    """``(truth, measured)`` in electrons, shape ``(groups, size, size)``: a star
    field (its full signal reached at the last group) plus a sky, each group's
    new charge drawn from a Poisson law, accumulated, and coupled with ``law``
    (in the running runtime's precision)."""
    rng = np.random.default_rng(seed)
    rate = star_field(size, seed=seed) / groups + SKY
    truth = np.cumsum(rng.poisson(rate, (groups, size, size)), axis=0, dtype=np.float64)
    return truth, ipc_taichi.couple(truth, law=law)


def _one_law(measured, truth, law, repeats):
    """The two rows (from scratch, warm start) of one law."""
    ipc_taichi.decouple(measured[:2, :64, :64], law=law, warm_start=True)  # JIT outside
    starts = (("from scratch", False), ("warm start", True))
    outs = {name: np.empty_like(measured) for name, _ in starts}
    times = {name: [] for name, _ in starts}
    infos = {}
    for _ in range(repeats):  # interleaved: load and cache effects fall on both alike
        for name, warm in starts:
            t0 = time.perf_counter()
            infos[name] = ipc_taichi.decouple(measured, law=law, warm_start=warm,
                                              out=outs[name], full_output=True)[1]
            times[name].append(time.perf_counter() - t0)
    diff = np.abs(outs["warm start"].astype(np.float64) - outs["from scratch"])
    scale = iteration.TOL * np.abs(outs["from scratch"]).max(axis=(1, 2))
    rows = []
    for name, warm in starts:
        median = statistics.median(times[name])
        its = [i.iterations for i in infos[name]]
        rows.append({
            "law": law, "start": name, "median [s]": median, "best [s]": min(times[name]),
            "per group [s]": median / len(measured),
            "iterations": f"{sum(its)} ({', '.join(map(str, its))})",
            "converged": all(i.converged for i in infos[name]),
            "max diff vs scratch [e-]": float(diff.max()) if warm else 0.0,
            "tol x max(S) [e-]": float(scale.max()),
            "max error vs truth [e-]": float(np.abs(outs[name] - truth).max()),
            "times_s": times[name],
            "within_tolerance": bool(np.all(diff.max(axis=(1, 2)) <= scale)),
        })
    rows[1]["vs scratch (median, best)"] = (
        f"{rows[0]['median [s]'] / rows[1]['median [s]']:.2f}x, "
        f"{rows[0]['best [s]'] / rows[1]['best [s]']:.2f}x")
    rows[0]["vs scratch (median, best)"] = ""
    return rows


COLUMNS = ["law", "start", "median [s]", "best [s]", "per group [s]",
           "vs scratch (median, best)", "iterations",
           "converged", "max diff vs scratch [e-]", "tol x max(S) [e-]",
           "max error vs truth [e-]"]


def measure_ramp(size=RAMP_SIZE, groups=RAMP_GROUPS, precision="f32",
                 laws=("donlon2018", "constant:0.0125"), repeats=3, seed=5):
    """Time a ramp's decouple from scratch and warm-started, in this process,
    for each law in ``laws`` (the ramp coupled with that law).

    Returns
    -------
    dict
        A section for :func:`ipc_taichi.bench.render.render_section`:
        ``title``, ``rows`` (per law, one per start: seconds, per group,
        iterations, max difference from scratch and max error against the
        truth, in electrons), ``times_s``, ``within_tolerance`` and ``notes``.
        Taichi is left in ``precision``.
    """
    info = ipc_taichi.init(precision=precision)
    rows = []
    for law in laws:
        truth, measured = ramp_frames(size, groups, law, seed)
        rows += _one_law(measured.astype(info.dtype), truth, law, repeats)
    within = all(r["within_tolerance"] for r in rows)
    return {
        "title": f"A ramp: {size}x{size} x {groups} groups, {info.arch} {info.precision}",
        "rows": [{c: r[c] for c in COLUMNS} for r in rows],
        "times_s": {f"{r['law']}, {r['start']}": r["times_s"] for r in rows},
        "within_tolerance": within,
        "notes": [
            "ipc_taichi.bench.ramp.measure_ramp: one 3-D stack through "
            "ipc_taichi.decouple (Python API, NumPy in and out), median of "
            f"{repeats} warm runs of each (and the best), the two starts interleaved, in "
            "one process; per group: median / groups.",
            "Star field on a 40 e- sky, each group's new charge Poisson-drawn, coupled "
            "with the law; the paper's stopping rule for both starts.",
            f"Every group's warm-started answer {'within' if within else 'NOT within'} "
            "the stopping rule's tol x max(S) of the from-scratch one."],
    }

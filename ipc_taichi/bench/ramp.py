"""The bench row of a ramp: every group from scratch, and warm-started.

One up-the-ramp exposure (``groups`` reads of ``size x size`` pixels, a star
field on a sky accumulating with Poisson noise in each group's new charge,
coupled with the law), decoupled through the Python API as one 3-D stack, in
this process:

- ``from scratch``: ``ipc_taichi.decouple(ramp)``, each group from ``S_0 = M``;
- ``warm start``: ``ipc_taichi.decouple(ramp, warm_start=True)``, each group
  from the previous groups' answers plus its new charge
  (:class:`ipc_taichi._engine.WarmStart`).

Both use the paper's stopping rule. The row reports the median time, the
iterations per group, the largest difference between the two answers beside
the stopping rule's ``tol * max|S|`` (the tolerance both meet), and each one's
largest error against the true signal.
"""

import statistics
import time

import numpy as np

__all__ = ["measure_ramp", "ramp_frames", "RAMP_SIZE", "RAMP_GROUPS"]

RAMP_SIZE = 2048
RAMP_GROUPS = 12
SKY = 40.0  # electrons per group on every pixel


def ramp_frames(size, groups, law="donlon2018", seed=5):
    """``(truth, measured)`` in electrons, shape ``(groups, size, size)``: a star
    field (its full signal reached at the last group) plus a sky, each group's
    new charge drawn from a Poisson law, accumulated, and coupled with ``law``
    (in the running runtime's precision)."""
    import ipc_taichi
    from ipc_taichi.datasets import star_field

    rng = np.random.default_rng(seed)
    rate = star_field(size, seed=seed) / groups + SKY
    truth = np.cumsum(rng.poisson(rate, (groups, size, size)), axis=0, dtype=np.float64)
    return truth, ipc_taichi.couple(truth, law=law)


def _timed(fn, repeats):
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times, result


def measure_ramp(size=RAMP_SIZE, groups=RAMP_GROUPS, precision="f32", law="donlon2018",
                 repeats=3, seed=5):
    """Time a ramp's decouple from scratch and warm-started, in this process.

    Returns
    -------
    dict
        A section for :func:`ipc_taichi.bench.render.render_section`:
        ``title``, ``rows`` (one per start: seconds, per group, iterations,
        max difference from scratch and max error against the truth, in
        electrons) and ``notes``. Taichi is left in ``precision``.
    """
    import ipc_taichi
    from ipc_taichi import iteration

    info = ipc_taichi.init(precision=precision)
    truth, measured = ramp_frames(size, groups, law, seed)
    measured = measured.astype(info.dtype)
    ipc_taichi.decouple(measured[:2, :64, :64], law=law, warm_start=True)  # JIT outside
    rows, answers = [], {}
    for name, warm in (("from scratch", False), ("warm start", True)):
        out = np.empty_like(measured)
        median, times, (_, infos) = _timed(
            lambda warm=warm, out=out: ipc_taichi.decouple(
                measured, law=law, warm_start=warm, out=out, full_output=True), repeats)
        answers[name] = out
        its = [i.iterations for i in infos]
        rows.append({"start": name, "median [s]": median, "per group [s]": median / groups,
                     "iterations": f"{sum(its)} ({', '.join(map(str, its))})",
                     "converged": all(i.converged for i in infos),
                     "max error vs truth [e-]": float(np.abs(out - truth).max()),
                     "times_s": times})
    diff = np.abs(answers["warm start"].astype(np.float64) - answers["from scratch"])
    scale = iteration.TOL * np.abs(answers["from scratch"]).max(axis=(1, 2))
    rows[1]["max diff vs scratch [e-]"] = float(diff.max())
    rows[1]["tol x max(S) [e-]"] = float(scale.max())
    rows[0]["max diff vs scratch [e-]"] = 0.0
    rows[0]["tol x max(S) [e-]"] = float(scale.max())
    within = bool(np.all(diff.max(axis=(1, 2)) <= scale))
    speedup = rows[0]["median [s]"] / rows[1]["median [s]"]
    columns = ["start", "median [s]", "per group [s]", "iterations", "converged",
               "max diff vs scratch [e-]", "tol x max(S) [e-]", "max error vs truth [e-]"]
    return {
        "title": f"A ramp: {size}x{size} x {groups} groups, {law}, {info.arch} {info.precision}",
        "rows": [{c: r[c] for c in columns} for r in rows],
        "times_s": {r["start"]: r["times_s"] for r in rows},
        "speedup": speedup, "within_tolerance": within,
        "notes": [
            "ipc_taichi.bench.ramp.measure_ramp: one 3-D stack through "
            "ipc_taichi.decouple (Python API, NumPy in and out), median of "
            f"{repeats} warm runs, in one process.",
            "Star field on a 40 e- sky, each group's new charge Poisson-drawn, coupled "
            "with the law; the stopping rule is the paper's for both.",
            f"Warm start {speedup:.2f}x faster than from scratch; every group's answer "
            f"{'within' if within else 'NOT within'} the stopping rule's tol x max(S) "
            "of the from-scratch one."],
    }

"""The CPU rows of the benchmark: one configuration on one frame, timed in a
process of its own (:func:`measure_row`), and the floor's building blocks
measured on this machine (:func:`measure_floor`)."""

import os
import statistics
import time

import numpy as np

import ipc_taichi

from .. import engine, runtime
from ..bondmap import BondMap
from ..datasets import uniform_frame
from ..engine import make_alpha
from ..laws import donlon2018
from ..model import CouplingModel
from ..reference import decouple_numpy, decouple_reference

__all__ = ["measure_row", "measure_floor", "measure_bondmap", "iteration_time", "cpu_record",
           "SIZES", "KINDS", "NUMPY_REPEAT_CAP", "REFERENCE_MAX_SIZE", "BONDMAP_TARGET"]

SIZES = (512, 2048, 4096)
KINDS = ("uniform", "stars")
# repeats of the slow NumPy paths at the largest sizes (said in the output)
NUMPY_REPEAT_CAP = {4096: 2}
REFERENCE_MAX_SIZE = 2048


def _vm(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    return 0


def _reset_peak():
    """Reset VmHWM to the current RSS (Linux >= 4.0); False if not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def cpu_record():
    """The CPU a CPU number was measured on: ``model`` (``/proc/cpuinfo``'s
    model name), ``vector_extensions`` (its vector flags,
    :func:`ipc_taichi.engine.vector_extensions`), ``vector_unit`` (the one the
    ``lanes`` step is built for here) and the load average."""
    model = "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            model = next((line.split(":", 1)[1].strip() for line in f
                          if line.startswith("model name")), model)
    except OSError:
        pass
    return {"model": model, "vector_extensions": engine.vector_extensions(),
            "vector_unit": engine.host_vector_unit(),
            "load_average": [round(v, 2) for v in os.getloadavg()]}


def iteration_time(measured, out, **kw):
    """Seconds per Jacobi iteration of :func:`ipc_taichi.decouple` of
    ``measured`` (``kw``: its arguments): the time of 5 iterations less that
    of 1, over 4, so that the per-call work cancels."""
    t0 = time.perf_counter()
    ipc_taichi.decouple(measured, tol=0, max_iter=5, out=out, **kw)
    t1 = time.perf_counter()
    ipc_taichi.decouple(measured, tol=0, max_iter=1, out=out, **kw)
    return ((t1 - t0) - (time.perf_counter() - t1)) / 4


def measure_floor(n=1 << 22, repeats=5):
    """Measured building blocks of the floor on this machine (all cores).

    - ``pair_ns``: one pair alpha of ``donlon2018`` (2 inlined exp + 1 sqrt,
      the kernels' own :func:`ipc_taichi._kernels.make_exp`) over ``n``
      independent pairs in a parallel Taichi loop, ns per pair (wall), f64 and
      f32: what the alphas alone cost in scalar code (a reference point, not a
      strict bound: the fused sweep overlaps them better than this loop does).
    - ``stream_ns``: ``o = a + b`` over ``n`` elements (the 24 bytes per pixel
      in f64 that an iteration must move, 12 in f32), ns per element (wall):
      the memory floor.
    - ``numpy_pair_ns``: the same pair alpha in NumPy (one thread, SIMD where
      NumPy has it), ns per pair.
    """
    import taichi as ti

    def best(fn):
        fn()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return min(times) / n * 1e9

    rng = np.random.default_rng(0)
    a64, b64 = rng.uniform(0, 60000, n), rng.uniform(0, 60000, n)
    law = donlon2018()
    p64 = law.kernel_params()
    o64, w64 = np.empty(n), np.empty(n)
    out = {"numpy_pair_ns": best(lambda: law.alpha(a64, b64, out=o64, work=w64))}
    for precision, dtype in (("f64", np.float64), ("f32", np.float32)):
        runtime.init("cpu", precision)
        real = ti.f64 if precision == "f64" else ti.f32
        alpha = make_alpha(law.kind, precision, fast_exp=True)
        no_table = np.zeros((2, 2), dtype)

        @ti.kernel
        def pairs(a: ti.types.ndarray(dtype=real, ndim=1),
                  b: ti.types.ndarray(dtype=real, ndim=1),
                  o: ti.types.ndarray(dtype=real, ndim=1),
                  p: ti.types.ndarray(dtype=real, ndim=1),
                  table: ti.types.ndarray(dtype=real, ndim=2)):
            for i in range(a.shape[0]):
                o[i] = alpha(a[i], b[i], p, table)  # noqa: B023 (compiled in this iteration)

        @ti.kernel
        def stream(a: ti.types.ndarray(dtype=real, ndim=1),
                   b: ti.types.ndarray(dtype=real, ndim=1),
                   o: ti.types.ndarray(dtype=real, ndim=1)):
            for i in range(a.shape[0]):
                o[i] = a[i] + b[i]

        a, b, o = a64.astype(dtype), b64.astype(dtype), np.empty(n, dtype)
        p = p64.astype(dtype)
        # each lambda is timed at once, within this iteration (B023 does not apply)
        out[f"pair_ns_{precision}"] = best(
            lambda: (pairs(a, b, o, p, no_table), ti.sync()))  # noqa: B023
        out[f"stream_ns_{precision}"] = best(lambda: (stream(a, b, o), ti.sync()))  # noqa: B023
    return out


def measure_row(spec):
    """Time one configuration on one frame (runs in a subprocess of its own).

    ``spec``: ``config`` (``numpy``, ``numpy-reference``, ``taichi-<arch>-<precision>``),
    ``measured`` and ``truth`` (``.npy`` paths), ``repeats``. Returns a dict:
    the times, iterations, error against the truth, peak memory growth, and for
    Taichi the first call's and a warm call's time on a small frame
    (``first_call_s``, ``warm_call_s``; ``compile_s`` is their difference, the
    JIT's cost, not clamped: a negative value would say the measurement failed).
    """
    config, measured_path, truth_path, repeats = (spec["config"], spec["measured"],
                                                  spec["truth"], spec["repeats"])
    result = {"config": config}
    if config.startswith("taichi"):
        _, arch, precision = config.split("-")
        info = runtime.init(arch, precision)
        result["arch"] = info.arch

        def run(frame):
            out, fi = ipc_taichi.decouple(frame, arch=arch, precision=precision,
                                          full_output=True)
            return out, fi.iterations, fi.converged

        small = np.load(measured_path, mmap_mode="r")[:64, :64].copy()
        t0 = time.perf_counter()
        run(small)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        run(small)
        warm = time.perf_counter() - t0
        result.update(first_call_s=first, warm_call_s=warm, compile_s=first - warm)
        # the timed runs allocate their working buffers (reused from run to
        # run): the peak memory below includes them
        engine.clear_workspaces()
    elif config == "numpy":
        def run(frame):
            return decouple_numpy(frame)
    else:
        def run(frame):
            out, it, conv, _ = decouple_reference(frame)
            return out, it, conv
    base_rss = _vm("VmRSS")  # after imports and the JIT
    measured = np.load(measured_path)
    truth = np.load(truth_path, mmap_mode="r")
    exact_peak = _reset_peak()
    times = []
    out = None
    for _ in range(repeats):
        out = None  # release the previous result before the next run
        t0 = time.perf_counter()
        out, iterations, converged = run(measured)
        times.append(time.perf_counter() - t0)
    # without the reset (old kernels) VmHWM is the process's lifetime peak:
    # peak_exact says which
    peak = _vm("VmHWM")
    result.update(
        times_s=times, median_s=statistics.median(times), repeats=repeats,
        iterations=int(iterations), converged=bool(converged),
        max_error=float(np.abs(np.asarray(out, dtype=np.float64) - truth).max()),
        peak_bytes=int(peak - base_rss), peak_exact=exact_peak)
    return result


BONDMAP_TARGET = 1.3  # issue 35: a map may cost at most this much per iteration


def measure_bondmap(size=2048, repeats=7, precisions=("f64", "f32"),
                    laws=("donlon2018", "constant:0.0125")):
    """The cost of a bond map per Jacobi iteration on the CPU (issue 35's
    row): each law of ``laws``, nearest neighbours, zero edge, a ``size`` x
    ``size`` frame, uniform and with a map (a +-12 % gradient across x and a
    disc 40 % weaker, per bond); per iteration = (time of 5 iterations - time
    of 1) / 4, so the per-call work cancels; the two interleaved, ``repeats``
    times, medians. Returns a section for :func:`~ipc_taichi.bench.render.render_section`."""
    y, x = np.mgrid[0:size, 0:size] / size
    factor = (1.0 + 0.24 * (x - 0.5)) * np.where((x - 0.6) ** 2 + (y - 0.4) ** 2 < 0.04, 0.6, 1)
    rows = []
    for precision in precisions:
        runtime.init("cpu", precision)
        measured = ipc_taichi.couple(uniform_frame(size))
        out = np.empty_like(measured)
        for law in laws:
            uniform = CouplingModel.resolve(law)
            models = {"uniform": uniform, "map": CouplingModel.resolve(
                law, bonds=BondMap.full(uniform.geometry, factor))}
            rows.append(_map_row(measured, out, models, repeats, precision, law))
    engine.clear_workspaces()
    return {"title": f"A bond map per iteration (issue 35 target: <= {BONDMAP_TARGET}x the "
                     "uniform law)",
            "rows": rows,
            "notes": ["ipc_taichi.bench.cpu.measure_bondmap: nearest neighbours, zero edge, "
                      "the CPU's default layout (lanes); the map in the working precision; "
                      "per iteration = (5 iterations - 1) / 4, uniform and map interleaved, "
                      f"median of {repeats}; spread: the smallest and largest ratio of "
                      "neighbouring runs. A constant law without a map sums pre-combined "
                      "coefficients (no alpha per pair); with one each pair's factor is "
                      "read, as for the other laws."]}


def _map_row(measured, out, models, repeats, precision, law):
    """One row of :func:`measure_bondmap`: ``models`` (``uniform``, ``map``) timed."""
    per = {name: [] for name in models}
    for model in models.values():  # JIT and the map's upload outside the timing
        ipc_taichi.decouple(measured, model=model, tol=0, max_iter=1, out=out)
    for _ in range(repeats):
        for name, model in models.items():
            per[name].append(iteration_time(measured, out, model=model))
    u, m = statistics.median(per["uniform"]), statistics.median(per["map"])
    ratios = [a / b for a, b in zip(per["map"], per["uniform"])]
    return {"law": law, "precision": precision, "frame": f"{len(measured)}x{len(measured)}",
            "uniform [ms/iteration]": u * 1e3, "map [ms/iteration]": m * 1e3,
            "map / uniform": m / u, "spread": f"{min(ratios):.2f}-{max(ratios):.2f}"}

"""The bench row beside the JWST pipeline's own ``ipc`` step.

On one NIRCam-like full-frame ramp (``nints x ngroups`` groups of
``size x size`` pixels, coupled with a constant alpha), in one process:

- ``jwst ipc step``: :func:`jwst.ipc.ipc_corr.ipc_correction`, the compute of
  the pipeline's step: one pass of a 3x3 deconvolution kernel (here the exact
  inverse of the coupling kernel, cropped to 3x3 and normalised, as the IPC
  reference files hold) over every group, reference pixels left alone;
- ``decouple (constant law)``: :func:`ipc_taichi.decouple` of the same groups,
  law ``constant:<alpha>``, nearest neighbours, the paper's stopping rule,
  which runs the constant-law kernel (no alpha evaluation), in f64 and in f32
  (both converge to the stopping rule; f32 moves half the bytes).

Both read the ramp's float32 groups and are timed on the compute alone (the
step's data copied in before each run, outside the timing); both results are
compared with the true signal. Needs the
``jwst`` package (the ``jwst`` extra).

Issue 28's rows (``law_rows``, f32, the same process and the same step time):
the ramp coupled with, and decoupled by, ``donlon2018`` and a 257x257 table
law (:func:`table_law`, the size ``calibrate`` writes), each from scratch and
warm-started (``decouple(warm_start=True)``), and the constant law
warm-started; the machine's streaming floor measured beside them (``floor``:
one NumPy copy of a frame, :func:`streaming_floor`); and the general law on a
``general_size`` frame per iteration against that floor (``general``).

Issue 39's rows: the CPU's model and vector extensions recorded with the
result (``cpu``), and the f32 law rows and the per-iteration rows measured
for each vector unit of ``units`` (default :func:`law_units`: this CPU's, and
one AVX2 register's width on an AVX2 or AVX-512 CPU), the ``lanes`` step
built for that unit's width (:func:`ipc_taichi.engine.vector_unit_set`). Per iteration
(``general``), the same step with a constant law, ``donlon2018`` and the
table law: the difference to the constant law is the law's evaluation.
"""

import os
import statistics
import time

import numpy as np

import ipc_taichi

from .. import engine
from ..datasets import star_field, uniform_frame
from ..laws import TabulatedLaw, donlon2018
from .cpu import cpu_record, iteration_time

__all__ = ["measure_pipeline_ipc", "jwst_ipc_kernel", "table_law", "streaming_floor",
           "law_units", "PIPELINE_SIZE", "GENERAL_SIZE"]

NIRCAM_BORDER = 4  # reference pixels on each side of a NIRCam full frame
PIPELINE_SIZE = 2048  # a NIRCam full frame
GENERAL_SIZE = 4096  # the general law's frame, per iteration against the floor


def table_law(n=257):
    """``donlon2018`` sampled on an ``n x n`` grid over 0 .. 65535 e- (the
    size of table ``calibrate`` writes)."""

    return TabulatedLaw.from_callable(donlon2018().alpha, (0.0, 65535.0), n=n,
                                      name=f"table{n}")


def streaming_floor(shape, dtype, repeats=7):
    """The machine's streaming floor: the best time [s] of one NumPy copy of a
    frame of ``shape`` and ``dtype`` (one read and one write of every pixel)."""
    a = np.ones(shape, dtype)
    b = np.empty_like(a)
    np.copyto(b, a)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.copyto(b, a)
        times.append(time.perf_counter() - t0)
    return min(times)


def jwst_ipc_kernel(alpha):
    """The 3x3 deconvolution kernel a JWST IPC reference file would hold for a
    constant nearest-neighbour coupling ``alpha``: the exact inverse of the
    coupling kernel (computed on a 64x64 periodic grid), cropped to 3x3 and
    normalised to a sum of 1."""
    n = 64
    k = np.zeros((n, n))
    k[0, 0] = 1 - 4 * alpha
    k[0, 1] = k[1, 0] = k[0, -1] = k[-1, 0] = alpha
    inverse = np.real(np.fft.ifft2(1.0 / np.fft.fft2(k)))
    crop = np.roll(np.roll(inverse, 1, 0), 1, 1)[:3, :3]
    return crop / crop.sum()


def _ramp(size, nints, ngroups, alpha, seed, law=None):
    """``(truth, measured)`` in electrons, shape ``(nints * ngroups, size, size)``:
    a star field on a sky, accumulating group by group; the reference border
    holds no signal and is not coupled. ``law``: the coupling law (default
    ``constant:<alpha>``)."""
    b = NIRCAM_BORDER
    rate = np.zeros((size, size))
    rate[b:-b, b:-b] = star_field(size - 2 * b, seed=seed) / ngroups
    truth = np.stack([rate * (g + 1) for _ in range(nints) for g in range(ngroups)])
    measured = truth.copy()
    inner = ipc_taichi.couple(truth[:, b:-b, b:-b], law=law or f"constant:{alpha}")
    measured[:, b:-b, b:-b] = inner
    return truth, measured


def _ramp_model(measured, nints, ngroups):
    from stdatamodels.jwst.datamodels import RampModel

    size = measured.shape[-1]
    model = RampModel((nints, ngroups, size, size))
    model.meta.instrument.name = "NIRCAM"
    model.meta.instrument.detector = "NRCA1"
    model.meta.exposure.nints = nints
    model.meta.exposure.ngroups = ngroups
    model.meta.exposure.nframes = 1
    model.meta.exposure.groupgap = 0
    model.meta.exposure.readpatt = "RAPID"
    model.meta.subarray.name = "FULL"
    model.meta.subarray.xstart = model.meta.subarray.ystart = 1
    model.meta.subarray.xsize = model.meta.subarray.ysize = size
    return model


def _median(fn, repeats, before=None):
    times = []
    for _ in range(repeats):
        if before is not None:
            before()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def _time_decouple(groups, truth, law, info, repeats, warm_start=False, step=None):
    """Median time of :func:`ipc_taichi.decouple` of ``groups`` (f32 ramp
    groups, one stack) with ``law`` in the running precision; a row dict
    (``median_s``, ``times_s``, ``max_error`` over the science pixels,
    ``iterations``: the distinct counts, ``total_iterations``). With ``step``
    (a callable returning the JWST step's compute time and its CPU time), the
    step is timed before each run, interleaved, and ``vs_jwst_interleaved`` is
    the ratio of the two medians: on a machine shared with other work both see
    the same load; ``vs_jwst_cpu``: the ratio of the CPU times, ours over the
    threads it ran on (the step runs on one), what an idle machine shows
    where the threads scale (on a loaded one, two threads and one do not see
    the same machine)."""

    b = NIRCAM_BORDER
    science = (slice(None), slice(b, -b), slice(b, -b))
    run = dict(law=law, arch=info.arch, precision=info.precision, warm_start=warm_start)
    out = np.empty(groups.shape, dtype=info.dtype)
    ipc_taichi.decouple(groups[:2, :64, :64], **run)  # JIT outside the timing
    infos = []

    cpu = []

    def ours():
        c0 = time.process_time()
        infos[:] = ipc_taichi.decouple(groups, out=out, full_output=True, **run)[1]
        cpu.append(time.process_time() - c0)

    steps = []
    median, times = _median(ours, repeats, None if step is None else
                            lambda: steps.append(step()))
    threads = info.threads or os.cpu_count()
    extra = {} if step is None else {
        "jwst_times_s": [t for t, _ in steps], "cpu_s": cpu, "threads": threads,
        "vs_jwst_interleaved": median / statistics.median(t for t, _ in steps),
        "vs_jwst_cpu": statistics.median(cpu) / threads / statistics.median(c for _, c in steps)}
    return {**extra, "median_s": median, "times_s": times,
            "max_error": float(np.abs(out - truth)[science].max()),
            "iterations": sorted({i.iterations for i in infos}),
            "total_iterations": sum(i.iterations for i in infos)}


def law_units():
    """The vector units the law rows are measured for: this CPU's (``None``
    where it has none the ``lanes`` step is built for), and on an AVX2 or
    AVX-512 CPU (whose ``lanes`` vector is two 256-bit registers) the width of
    one AVX2 register, ``"8"`` f32 lanes."""
    unit = engine.host_vector_unit()
    return [unit, "8"] if unit in ("avx512", "avx2") else [unit]


def _unit_name(unit):
    if not unit:
        return "sweep"
    lanes = f"{engine.lane_count('f32', unit)} lanes"
    return lanes if unit.isdigit() else f"{unit}, {lanes}"


def _law_rows(size, nints, ngroups, alpha, seed, repeats, step, jwst_s, unit, warm=True):
    """Issue 28's rows in f32 (see the module docstring), each with ``vs_jwst``
    (against the step's first timing, ``jwst_s``) and ``vs_jwst_interleaved``;
    the ``lanes`` step built for ``unit``. ``warm``: the warm-started rows too
    (else the constant law from scratch, the others' from scratch only)."""

    info = ipc_taichi.init(precision="f32")
    rows = []
    for name, law in ((f"constant:{alpha}", None), ("donlon2018", "donlon2018"),
                      ("table 257x257", table_law())):
        truth, measured = _ramp(size, nints, ngroups, alpha, seed, law=law)
        groups = measured.astype(np.float32)
        starts = (False, True) if law is not None else (True,)
        for warm_start in (starts if warm else (False,)):
            row = _time_decouple(groups, truth, law or f"constant:{alpha}", info, repeats,
                                 warm_start=warm_start, step=step)
            row.update(row=f"decouple, {name} ({info.arch} f32, "
                           f"{'warm start' if warm_start else 'from scratch'}, "
                           f"{_unit_name(unit)})",
                       law=name, warm_start=warm_start, vs_jwst=row["median_s"] / jwst_s,
                       vector_unit=unit)
            rows.append(row)
    return rows


def _general(size, repeats, unit):
    """Per Jacobi iteration on a ``size`` x ``size`` f32 frame (5 iterations
    less 1, so that the per-call work cancels), the same step with a constant
    law, ``donlon2018`` (the general law) and the table law, interleaved, each
    against the streaming floor measured between them (one NumPy copy); the
    difference to the constant law is the law's evaluation. The ``lanes``
    step built for ``unit``. ``donlon2018``'s figures at the top level."""

    info = ipc_taichi.init(precision="f32")
    measured = ipc_taichi.couple(uniform_frame(size).astype(np.float32))
    out = np.empty_like(measured)
    laws = {"constant:0.0125": "constant:0.0125", "donlon2018": "donlon2018",
            "table 257x257": table_law()}
    for law in laws.values():  # JIT outside the timing
        ipc_taichi.decouple(measured[:64, :64], law=law, tol=0, max_iter=1)
    per = {name: [] for name in laws}
    floors = []
    for _ in range(repeats):
        for name, law in laws.items():
            per[name].append(iteration_time(measured, out, law=law))
        floors.append(streaming_floor(measured.shape, np.float32, repeats=3))
    floor = statistics.median(floors)
    median = {name: statistics.median(t) for name, t in per.items()}
    rows = [{"law": name, "iteration [ms]": median[name] * 1e3,
             "ns per pixel": median[name] / size ** 2 * 1e9,
             "x floor": median[name] / floor,
             "law's cost [ns/pixel]": (median[name] - median["constant:0.0125"])
             / size ** 2 * 1e9,
             "spread": f"{min(per[name]) * 1e3:.1f}-{max(per[name]) * 1e3:.1f} ms"}
            for name in laws]
    return {"size": size, "law": "donlon2018", "precision": info.precision,
            "vector_unit": unit, "lanes": _unit_name(unit),
            "iteration_s": median["donlon2018"], "iteration_times_s": per["donlon2018"],
            "floor_s": floor, "floor_times_s": floors,
            "vs_floor": median["donlon2018"] / floor,
            "ns_per_pixel": median["donlon2018"] / size ** 2 * 1e9, "laws": rows}


def measure_pipeline_ipc(size=PIPELINE_SIZE, nints=2, ngroups=4, alpha=0.0125, repeats=3, seed=3,
                         precisions=("f64", "f32"), laws=True, general_size=None, units=None):
    """Time the JWST ``ipc`` step's compute and :func:`ipc_taichi.decouple`
    with the constant law on the same ramp, in this process.

    Returns
    -------
    dict
        ``rows``: one dict per method (``row``, ``median_s``, ``times_s``,
        ``max_error`` in electrons over the science pixels; for the decoupler,
        one row per precision in ``precisions``, each with its ``iterations``
        and ``vs_jwst``, its median over the step's); ``ratio``: that of the
        first precision; the ramp's description. With ``laws``: ``law_rows``
        (issue 28's f32 rows, see the module docstring), ``floor_s`` (one
        NumPy copy of a ``size`` x ``size`` f32 frame) and ``general`` (the
        general law per iteration on a ``general_size`` frame, default twice
        ``size``, against the floor there), both for the first vector unit of
        ``units`` (default :func:`law_units`), and for each unit of ``units``
        ``by_unit`` (``{unit: {"law_rows", "general"}}``, the further units'
        law rows from scratch only); ``cpu``: the CPU's model and vector
        extensions (:func:`~ipc_taichi.bench.cpu.cpu_record`). Taichi is left
        in f32.
    """
    import logging

    from jwst.ipc import ipc_corr
    from stdatamodels.jwst.datamodels import IPCModel

    truth, measured = _ramp(size, nints, ngroups, alpha, seed)
    b = NIRCAM_BORDER
    science = (slice(None), slice(b, -b), slice(b, -b))
    model = _ramp_model(measured, nints, ngroups)
    ipc_model = IPCModel(data=jwst_ipc_kernel(alpha).astype(np.float32))
    ramp32 = measured.reshape(nints, ngroups, size, size).astype(np.float32)

    def reload():
        model.data = ramp32.copy()

    def step():
        reload()
        t0, c0 = time.perf_counter(), time.process_time()
        ipc_corr.ipc_correction(model, ipc_model)
        return time.perf_counter() - t0, time.process_time() - c0

    logging.getLogger("jwst").setLevel(logging.WARNING)
    jwst_s, jwst_times = _median(lambda: ipc_corr.ipc_correction(model, ipc_model), repeats,
                                 reload)
    jwst_out = np.asarray(model.data, dtype=np.float64).reshape(measured.shape)
    jwst_err = float(np.abs(jwst_out - truth)[science].max())

    # the decoupler reads the same float32 groups the step reads
    groups = ramp32.reshape(measured.shape)
    law = f"constant:{alpha}"
    rows = [{"row": "jwst ipc step (3x3 pre-inverted kernel, float32)", "median_s": jwst_s,
             "times_s": jwst_times, "max_error": jwst_err}]
    for precision in precisions:
        info = ipc_taichi.init(precision=precision)
        row = _time_decouple(groups, truth, law, info, repeats, step=step)
        row.update(row=f"decouple, constant law ({info.arch} {info.precision})",
                   vs_jwst=row["median_s"] / jwst_s)
        rows.append(row)
    by_unit = {}
    for k, unit in enumerate((units or law_units()) if laws else ()):
        with engine.vector_unit_set(unit or "none"):
            by_unit[unit] = {
                "law_rows": _law_rows(size, nints, ngroups, alpha, seed, repeats, step, jwst_s,
                                      unit, warm=k == 0),
                "general": _general(general_size or 2 * size, max(repeats, 5), unit)}
    first = next(iter(by_unit.values()), {"law_rows": [], "general": None})
    floor = streaming_floor((size, size), np.float32)
    return {"size": size, "nints": nints, "ngroups": ngroups, "alpha": alpha,
            "arch": info.arch, "ratio": rows[1]["vs_jwst"], "rows": rows,
            "law_rows": first["law_rows"], "floor_s": floor,
            "jwst_per_group_s": jwst_s / len(groups), "general": first["general"],
            "by_unit": by_unit, "cpu": cpu_record()}

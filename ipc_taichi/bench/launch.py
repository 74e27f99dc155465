"""Running the benchmark: every measurement in a fresh subprocess of its own
(one launcher, :func:`in_subprocess`; the worker side is :func:`work`), the results
gathered into one dict (:func:`run_benchmark`) and written atomically
(:func:`write_results`)."""

import json
import os
import platform
import subprocess
import sys
import tempfile

import numpy as np

from .. import __version__
from ..calibrate.benchmark import measure_calibrate
from ..datasets import star_field, uniform_frame
from ..discover.benchmark import benchmark_ramps, ramps_section
from ..gpus import cuda_present
from ..reference import couple_reference
from .cliramp import CLIRAMP_GROUPS, CLIRAMP_SIZE, measure_cliramp
from .cpu import (
    KINDS,
    NUMPY_REPEAT_CAP,
    REFERENCE_MAX_SIZE,
    SIZES,
    measure_bondmap,
    measure_floor,
    measure_row,
)
from .cuda import CUDA_SIZE, STACK_FRAMES, measure_cuda
from .pipeline import PIPELINE_SIZE, measure_pipeline_ipc
from .ramp import RAMP_GROUPS, RAMP_SIZE, measure_ramp
from .render import floor_model, render_markdown
from .startup import measure_startup

__all__ = ["run_benchmark", "write_results", "machine", "in_subprocess", "work", "cuda_present",
           "calibrate_section"]


def work(spec):
    """The worker side: run the measurement ``spec`` names, return a dict."""
    config = spec["config"]
    if config == "floor":
        return measure_floor()
    if config == "cuda-suite":
        return measure_cuda(spec["size"], spec["repeats"], spec["stack"])
    if config == "pipeline":
        return measure_pipeline_ipc(size=spec["size"], repeats=spec["repeats"])
    if config == "ramp":
        return measure_ramp(size=spec["size"], groups=spec["groups"],
                            precision=spec.get("precision", "f32"), repeats=spec["repeats"])
    if config == "cliramp":
        return measure_cliramp(size=spec["size"], groups=spec["groups"])
    if config == "bondmap":
        return measure_bondmap(size=spec["size"], repeats=spec["repeats"])
    if config == "discover-ramps":
        info = machine()
        return ramps_section(benchmark_ramps(), info["cpu"], info["cores"],
                             info["load_average_at_start"][0])
    if config == "calibrate":
        flats = {k: spec[k] for k in ("flat_size", "flat_ints", "flat_groups") if k in spec}
        return calibrate_section(measure_calibrate(spec.get("size", 2048),
                                                   spec.get("groups", 10), **flats))
    return measure_row(spec)


def calibrate_section(result):
    """The calibrate row as a section for :func:`render.render_section`."""
    return {"title": "Calibrate (issue target: under 60 s on 2 cores)",
            "rows": [{"dark": f"{result['size']}x{result['size']} x {result['groups']} groups",
                      "flat ramps": result["flats"],
                      "seconds": result["seconds"],
                      "hot pixels found": result["hot_pixels_found"],
                      "alpha_x at 10 ke- (made with 0.006)": result["alpha_x"],
                      "law": result["chosen"],
                      "BF / NL-IPC detected (none made)":
                          f"{result['brighter_fatter']} / {result['nonlinear_ipc']}"}],
            "notes": ["ipc_taichi.calibrate.benchmark.measure_calibrate: FITS read, hot-pixel "
                      "search, group-by-group measurement, flat ramps separated (gain, "
                      "non-linearity, brighter-fatter, IPC), the law chosen on 10 held-out "
                      "folds, the transfer check on held-out hot pixels, model written."]}


def in_subprocess(spec):
    """Run ``work(spec)`` in a fresh Python process; returns ``(result, None)``
    or ``(None, the last line of its error output)``."""
    proc = subprocess.run(
        [sys.executable, "-m", "ipc_taichi.bench", "--worker", json.dumps(spec)],
        capture_output=True, text=True, env=dict(os.environ, ENABLE_TAICHI_HEADER_PRINT="False"))
    if proc.returncode != 0:
        return None, (proc.stderr.strip().splitlines() or ["no output"])[-1]
    return json.loads(proc.stdout.strip().splitlines()[-1]), None


def _has_module(name):
    from importlib.util import find_spec

    try:
        return find_spec(name) is not None
    except ModuleNotFoundError:
        return False


def machine():
    """What the benchmark ran on."""
    from importlib.metadata import version  # taichi's version without importing it

    cpu = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    mem = 0
    try:
        with open("/proc/meminfo") as f:
            mem = int(f.readline().split()[1]) * 1024
    except OSError:
        pass
    try:
        load = os.getloadavg()
    except OSError:
        load = (float("nan"),) * 3
    return {
        "cpu": cpu, "cores": os.cpu_count(), "ram_gib": round(mem / 2**30, 1),
        "os": f"{platform.system()} {platform.release()}", "python": platform.python_version(),
        "numpy": np.__version__, "taichi": version("taichi"), "ipc_taichi": __version__,
        "load_average_at_start": [round(v, 2) for v in load],
        "cuda": cuda_present(),
    }


def _configs(cuda):
    configs = ["numpy", "numpy-reference", "taichi-cpu-f64", "taichi-cpu-f32"]
    if cuda:
        configs += ["taichi-cuda-f64", "taichi-cuda-f32"]
    return configs


def _frames(size, kind, workdir):
    truth = uniform_frame(size) if kind == "uniform" else star_field(size)
    measured = couple_reference(truth)
    paths = {}
    for name, arr in (("truth", truth), ("measured", measured)):
        paths[name] = os.path.join(workdir, f"{kind}-{size}-{name}.npy")
        np.save(paths[name], arr)
    return paths


def run_benchmark(sizes=SIZES, kinds=KINDS, repeats=5, configs=None, progress=print,
                  measure=True, cuda_size=CUDA_SIZE, stack=STACK_FRAMES,
                  pipeline_size=PIPELINE_SIZE, ramp_size=RAMP_SIZE, ramp_groups=RAMP_GROUPS):
    """Run every configuration on every frame; return the results dict.

    With ``measure``, also time the floor's building blocks
    (:func:`measure_floor`) in a subprocess of their own and, on a machine with
    a CUDA GPU, the CUDA rows (:func:`measure_cuda`, ``cuda_size`` frames, a
    ``stack``-frame stack) in another, and where the ``jwst`` package is
    installed, the constant law beside the JWST ``ipc`` step on a
    ``pipeline_size`` ramp (:func:`measure_pipeline_ipc`; 0 skips it), and a
    ``ramp_size`` x ``ramp_groups`` f32 ramp from scratch and warm-started
    (:func:`ipc_taichi.bench.ramp.measure_ramp`; 0 skips it).
    """
    info = machine()
    configs = list(configs or _configs(info["cuda"]))
    notes = []
    if not info["cuda"]:
        notes.append("No CUDA GPU on this machine: the Taichi CUDA rows and the CUDA section "
                     "(device-resident, host in/out, stack, CuPy peer, device floor) were not run.")
    rows = _measure_rows(sizes, kinds, repeats, configs, progress)
    notes += _row_notes(sizes, repeats)
    _add_ratios(rows)
    results = {"machine": info, "repeats": repeats, "notes": notes, "rows": rows,
               "floor": floor_model(info), "pipeline": None, "ramp": None, "calibrate": None,
               "cuda": None, "startup": None, "cliramp": None, "discover_ramps": None}
    if measure:
        results["floor"]["measured"] = _launch({"config": "floor"}, "The floor measurement",
                                               notes)
        results.update(_measure_sections(info, repeats, progress, notes, cuda_size, stack,
                                         pipeline_size, ramp_size, ramp_groups))
    return results


def _measure_rows(sizes, kinds, repeats, configs, progress):
    """The table's rows: every configuration on every frame, each in a
    subprocess of its own (a failed one kept as a row with its ``error``)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="ipc-bench-") as workdir:
        for size in sizes:
            for kind in kinds:
                paths = _frames(size, kind, workdir)
                for config in configs:
                    n = repeats
                    if config.startswith("numpy"):
                        if config == "numpy-reference" and size > REFERENCE_MAX_SIZE:
                            continue
                        n = min(repeats, NUMPY_REPEAT_CAP.get(size, repeats))
                    spec = {"config": config, "measured": paths["measured"],
                            "truth": paths["truth"], "repeats": n}
                    row, tail = in_subprocess(spec)
                    if row is None:
                        progress(f"  {config:16s} {kind:8s} {size:5d}: FAILED ({tail})")
                        rows.append({"config": config, "size": size, "kind": kind,
                                     "error": tail})
                        continue
                    row.update(size=size, kind=kind, frame_bytes=size * size * 8)
                    rows.append(row)
                    progress(f"  {config:16s} {kind:8s} {size:5d}: median {row['median_s']:.3f} s "
                             f"of {row['repeats']}, {row['iterations']} it, "
                             f"max err {row['max_error']:.3g}")
    return rows


def _row_notes(sizes, repeats):
    """The notes on the rows: NumPy's capped repeats, the reference's largest frame."""
    notes = []
    for size in sizes:
        capped = NUMPY_REPEAT_CAP.get(size)
        if capped is not None and capped < repeats:
            notes.append(f"NumPy at {size}x{size}: {capped} repeats instead of {repeats} "
                         "(it is slow); the median is of those.")
    if any(s > REFERENCE_MAX_SIZE for s in sizes):
        notes.append(f"numpy-reference (the paper-faithful one) is run up to "
                     f"{REFERENCE_MAX_SIZE}x{REFERENCE_MAX_SIZE} only.")
    return notes


def _launch(spec, what, notes):
    """``work(spec)`` in a subprocess; on failure, None and a note that ``what`` failed."""
    result, failed = in_subprocess(spec)
    if failed:
        notes.append(f"{what} failed: {failed}")
    return result


def _measure_sections(info, repeats, progress, notes, cuda_size, stack, pipeline_size,
                      ramp_size, ramp_groups):
    """The sections after the floor, each in a subprocess of its own (the
    start-up row runs its own): ``{"pipeline", "ramp", "cuda", "calibrate",
    "cliramp", "discover_ramps", "startup"}``, those run; a failed one None with
    a note in ``notes``."""
    found = {}
    if pipeline_size:
        if _has_module("jwst"):
            progress(f"  constant law beside the JWST ipc step, {pipeline_size}x{pipeline_size}")
            found["pipeline"] = _launch({"config": "pipeline", "size": pipeline_size,
                                         "repeats": 3}, "The row beside the JWST ipc step", notes)
        else:
            notes.append("The jwst package is not installed: the row beside the JWST ipc "
                         "step was not run (pip install 'ipc_taichi[jwst]').")
    if ramp_size:
        progress(f"  a {ramp_size}x{ramp_size} x {ramp_groups} ramp, from scratch and warm")
        found["ramp"] = _launch({"config": "ramp", "size": ramp_size, "groups": ramp_groups,
                                 "repeats": 5}, "The ramp row", notes)
    if info["cuda"] and cuda_size:
        progress(f"  CUDA rows at {cuda_size}x{cuda_size} (stack of {stack})")
        found["cuda"] = _launch({"config": "cuda-suite", "size": cuda_size,
                                 "repeats": max(repeats, 10), "stack": stack},
                                "The CUDA rows", notes)
    progress("  calibrate on a 2048x2048 x 10-group dark ramp")
    found["calibrate"] = _launch({"config": "calibrate", "size": 2048, "groups": 10},
                                 "The calibrate row", notes)
    progress(f"  a {CLIRAMP_SIZE}x{CLIRAMP_SIZE} x {CLIRAMP_GROUPS} ramp FITS through the CLI")
    found["cliramp"] = _launch({"config": "cliramp", "size": CLIRAMP_SIZE,
                                "groups": CLIRAMP_GROUPS}, "The CLI ramp row", notes)
    progress("  discover on a 256x256 x 10-read ramp pair (issue 38)")
    found["discover_ramps"] = _launch({"config": "discover-ramps"}, "The discover ramp row",
                                      notes)
    progress("  a bond map against the uniform law, per iteration, 2048x2048")
    found["bondmap"] = _launch({"config": "bondmap", "size": 2048, "repeats": 7},
                               "The bond-map row", notes)
    progress("  start-up: ipc-taichi --help, a 64x64 and a 2048x2048 decouple beside a fresh "
             "Python reading the file, fresh processes")
    try:
        found["startup"] = measure_startup(repeats)
    except RuntimeError as exc:
        notes.append(f"The start-up row failed: {exc}")
    return found


def _add_ratios(rows):
    peer = {(r["size"], r["kind"]): r["median_s"] for r in rows
            if r["config"] == "numpy" and "median_s" in r}
    for r in rows:
        key = (r.get("size"), r.get("kind"))
        if "median_s" in r and key in peer:
            r["speedup_vs_numpy"] = peer[key] / r["median_s"]


def write_results(results, directory):
    """Write results.json and RESULTS.md atomically into ``directory``."""
    os.makedirs(directory, exist_ok=True)
    for name, text in (("results.json", json.dumps(results, indent=1)),
                       ("RESULTS.md", render_markdown(results))):
        path = os.path.join(directory, name)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=name, dir=directory)
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)

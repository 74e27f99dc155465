"""``ipc-taichi bench`` (``make bench``): decoupling speed, side by side.

One run times, on the same frames, the plain-NumPy peer
(:func:`ipc_taichi.reference.decouple_numpy`),
the paper-faithful NumPy reference (:func:`ipc_taichi.reference.decouple_reference`),
Taichi on the CPU in f64 and f32 and, when a CUDA GPU is present, Taichi on
CUDA in f64 and f32. Frames: uniform 0..60000 (the paper's random frame) and
a star field, square, 512/2048/4096 pixels by default; law ``donlon2018``,
nearest neighbours, zero edge, the paper's stopping rule (20 iterations or
``max|dS| <= 1e-5 max|S|``).

Every configuration runs in a fresh subprocess, so that its peak memory
(``VmHWM`` of ``/proc/self/status``, reset just before the timed runs) is its
own and Taichi's runtime is initialised once for it. The JIT compile time is
measured on a small frame first and reported separately; the timed runs are
warm. Results go to ``bench/results.json`` and ``bench/RESULTS.md``, both
written atomically.
"""

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from .datasets import star_field, uniform_frame
from .laws import donlon2018
from .reference import decouple_numpy

__all__ = ["run_benchmark", "measure_floor"]

SIZES = (512, 2048, 4096)
KINDS = ("uniform", "stars")
# repeats of the slow NumPy paths at the largest sizes (said in the output)
NUMPY_REPEAT_CAP = {4096: 2}
REFERENCE_MAX_SIZE = 2048


# --------------------------------------------------------------------------- worker side

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

    from . import runtime
    from ._kernels import make_alpha

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
                o[i] = alpha(a[i], b[i], p, table)

        @ti.kernel
        def stream(a: ti.types.ndarray(dtype=real, ndim=1),
                   b: ti.types.ndarray(dtype=real, ndim=1),
                   o: ti.types.ndarray(dtype=real, ndim=1)):
            for i in range(a.shape[0]):
                o[i] = a[i] + b[i]

        a, b, o = a64.astype(dtype), b64.astype(dtype), np.empty(n, dtype)
        p = p64.astype(dtype)
        out[f"pair_ns_{precision}"] = best(lambda: (pairs(a, b, o, p, no_table), ti.sync()))
        out[f"stream_ns_{precision}"] = best(lambda: (stream(a, b, o), ti.sync()))
    return out


def _worker(spec):
    """Run one configuration on one frame; return a dict (runs in a subprocess)."""
    if spec["config"] == "floor":
        return measure_floor()
    config, measured_path, truth_path, repeats = (spec["config"], spec["measured"],
                                                  spec["truth"], spec["repeats"])
    base_rss = _vm("VmRSS")
    result = {"config": config}
    if config.startswith("taichi"):
        import ipc_taichi
        from ipc_taichi import runtime

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
        result["compile_s"] = max(0.0, first - (time.perf_counter() - t0))
    elif config == "numpy":
        def run(frame):
            return decouple_numpy(frame)
    else:
        from .reference import decouple_reference

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
    peak = _vm("VmHWM") if exact_peak else _vm("VmHWM")
    result.update(
        times_s=times, median_s=statistics.median(times), repeats=repeats,
        iterations=int(iterations), converged=bool(converged),
        max_error=float(np.abs(np.asarray(out, dtype=np.float64) - truth).max()),
        peak_bytes=int(peak - base_rss), peak_exact=exact_peak)
    return result


def _worker_main():
    spec = json.loads(sys.argv[2])
    print(json.dumps(_worker(spec)))


# --------------------------------------------------------------------------- driver side

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
    from . import __version__

    return {
        "cpu": cpu, "cores": os.cpu_count(), "ram_gib": round(mem / 2**30, 1),
        "os": f"{platform.system()} {platform.release()}", "python": platform.python_version(),
        "numpy": np.__version__, "taichi": version("taichi"), "ipc_taichi": __version__,
        "load_average_at_start": [round(v, 2) for v in load],
        "cuda": _cuda_present(),
    }


def _cuda_present():
    try:
        import ctypes

        ctypes.CDLL("libcuda.so.1")
        return True
    except OSError:
        return False


def _configs(cuda):
    configs = ["numpy", "numpy-reference", "taichi-cpu-f64", "taichi-cpu-f32"]
    if cuda:
        configs += ["taichi-cuda-f64", "taichi-cuda-f32"]
    return configs


def _frames(size, kind, workdir):
    from .reference import couple_reference

    truth = uniform_frame(size) if kind == "uniform" else star_field(size)
    measured = couple_reference(truth)
    paths = {}
    for name, arr in (("truth", truth), ("measured", measured)):
        paths[name] = os.path.join(workdir, f"{kind}-{size}-{name}.npy")
        np.save(paths[name], arr)
    return paths


def run_benchmark(sizes=SIZES, kinds=KINDS, repeats=5, configs=None, progress=print,
                  measure=True):
    """Run every configuration on every frame; return the results dict.

    With ``measure``, also time the floor's building blocks
    (:func:`measure_floor`) in a subprocess of their own.
    """
    info = machine()
    configs = list(configs or _configs(info["cuda"]))
    notes = []
    if not info["cuda"]:
        notes.append("No CUDA GPU on this machine: the Taichi CUDA rows were not run.")
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
                    proc = subprocess.run(
                        [sys.executable, "-m", "ipc_taichi.bench", "--worker", json.dumps(spec)],
                        capture_output=True, text=True,
                        env=dict(os.environ, ENABLE_TAICHI_HEADER_PRINT="False"))
                    if proc.returncode != 0:
                        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
                        progress(f"  {config:16s} {kind:8s} {size:5d}: FAILED ({tail})")
                        rows.append({"config": config, "size": size, "kind": kind,
                                     "error": tail})
                        continue
                    row = json.loads(proc.stdout.strip().splitlines()[-1])
                    row.update(size=size, kind=kind, frame_bytes=size * size * 8)
                    rows.append(row)
                    progress(f"  {config:16s} {kind:8s} {size:5d}: median {row['median_s']:.3f} s "
                             f"of {row['repeats']}, {row['iterations']} it, "
                             f"max err {row['max_error']:.3g}")
    for size in sizes:
        capped = NUMPY_REPEAT_CAP.get(size)
        if capped is not None and capped < repeats:
            notes.append(f"NumPy at {size}x{size}: {capped} repeats instead of {repeats} "
                         "(it is slow); the median is of those.")
    if any(s > REFERENCE_MAX_SIZE for s in sizes):
        notes.append(f"numpy-reference (the paper-faithful one) is run up to "
                     f"{REFERENCE_MAX_SIZE}x{REFERENCE_MAX_SIZE} only.")
    _add_ratios(rows)
    floor = floor_model(info)
    if measure:
        proc = subprocess.run(
            [sys.executable, "-m", "ipc_taichi.bench", "--worker",
             json.dumps({"config": "floor"})],
            capture_output=True, text=True,
            env=dict(os.environ, ENABLE_TAICHI_HEADER_PRINT="False"))
        if proc.returncode == 0:
            floor["measured"] = json.loads(proc.stdout.strip().splitlines()[-1])
        else:
            notes.append("The floor measurement failed: "
                         + (proc.stderr.strip().splitlines() or ["no output"])[-1])
    return {"machine": info, "repeats": repeats, "notes": notes, "rows": rows, "floor": floor}


def _add_ratios(rows):
    peer = {(r["size"], r["kind"]): r["median_s"] for r in rows
            if r["config"] == "numpy" and "median_s" in r}
    for r in rows:
        key = (r.get("size"), r.get("kind"))
        if "median_s" in r and key in peer:
            r["speedup_vs_numpy"] = peer[key] / r["median_s"]


def floor_model(info):
    """Work per pixel and iteration of the nearest-neighbour Jacobi step."""
    return {
        "per_pixel_iteration": {
            "alpha_pairs": 2, "exp": 4, "sqrt": 2,
            "other_flops": 34,
            "bytes_f64": 24, "bytes_f32": 12,
            "note": "2 pair alphas (each 2 exp + 1 sqrt + 8 flops), 18 flops for the flow, "
                    "update and maxima; memory: read S_(q-1) and M, write S_q once each "
                    "(neighbour reads hit cache)",
        },
        "h100": {"fp64_tflops": 34.0, "fp32_tflops": 67.0, "hbm_tb_s": 3.35,
                 "pixel_layout_flops": 250,
                 "note": "vendor peak figures (SXM, non-tensor)"},
    }


def _fmt_bytes(n):
    return f"{n / 2**20:.0f} MiB"


def render_markdown(results):
    m = results["machine"]
    lines = [
        "# Decoupling benchmark (`make bench`)",
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, {m['ram_gib']} GiB RAM, {m['os']}; "
        f"Python {m['python']}, NumPy {m['numpy']}, Taichi {m['taichi']}, "
        f"ipc_taichi {m['ipc_taichi']}. Load average at start: "
        f"{', '.join(str(v) for v in m['load_average_at_start'])} "
        "(anything near or above the core count means other processes shared the CPU "
        "and the timings are inflated).",
        "",
        "Law donlon2018, nearest neighbours, zero edge, the paper's stopping rule. Median of "
        f"{results['repeats']} warm runs per row (JIT compile time separate). `numpy` is the "
        "fastest plain-NumPy implementation we could write (pair-symmetric, in place, "
        "single-threaded); `numpy-reference` is the paper-faithful reference of the tests. "
        "Speed-up is relative to `numpy` on the same frame. Peak memory: growth of the "
        "process's peak RSS over its RSS before the frame was loaded (input frame included), "
        "also as a multiple of the frame's f64 bytes.",
        "",
        "| size | frame | implementation | median [s] | JIT [s] | iterations | max error vs truth "
        "| peak memory | x frame | speed-up vs numpy |",
        "|---:|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results["rows"]:
        if "error" in r:
            lines.append(f"| {r['size']} | {r['kind']} | {r['config']} | failed: {r['error']} "
                         "| | | | | | |")
            continue
        compile_s = f"{r['compile_s']:.2f}" if "compile_s" in r else "-"
        lines.append(
            f"| {r['size']} | {r['kind']} | {r['config']} | {r['median_s']:.3f} | {compile_s} | "
            f"{r['iterations']}{'' if r['converged'] else ' (not converged)'} | "
            f"{r['max_error']:.3g} | {_fmt_bytes(r['peak_bytes'])} | "
            f"{r['peak_bytes'] / r['frame_bytes']:.1f} | "
            f"{r.get('speedup_vs_numpy', float('nan')):.1f}x |")
    lines += ["", "Notes:", ""] + [f"- {n}" for n in results["notes"]]
    lines += ["", _floor_text(results), ""]
    return "\n".join(lines)


def _floor_text(results):
    """The floor: work per pixel and iteration, measured building blocks, and
    how close each timed path gets (at the largest size)."""
    rows = [r for r in results["rows"] if "median_s" in r]
    floor = results["floor"]
    fm = floor["per_pixel_iteration"]
    cores = results["machine"]["cores"]
    out = ["## The floor", "",
           f"Per pixel and Jacobi iteration (nearest neighbours, pair-symmetric): "
           f"{fm['alpha_pairs']} alpha evaluations = {fm['exp']} exp + {fm['sqrt']} sqrt + "
           f"about {fm['other_flops']} other flops; memory traffic {fm['bytes_f64']} bytes "
           f"(f64) / {fm['bytes_f32']} bytes (f32): {fm['note']}.", ""]
    measured = floor.get("measured")
    bound = {}
    if measured:
        for prec in ("f64", "f32"):
            pair, stream = measured[f"pair_ns_{prec}"], measured[f"stream_ns_{prec}"]
            bound[prec] = max(fm["alpha_pairs"] * pair, stream)
            out.append(f"- This CPU, {prec}, measured on all {cores} cores: one pair alpha "
                       f"{pair:.2f} ns, streaming one pixel's bytes {stream:.2f} ns; the "
                       f"alphas alone cost **{bound[prec]:.1f} ns per pixel and iteration** "
                       f"in scalar code (Taichi's CPU backend emits no SIMD for these loops).")
        out.append(f"- NumPy (one thread, SIMD exp where it has it): one pair alpha "
                   f"{measured['numpy_pair_ns']:.2f} ns.")
    h = floor["h100"]
    for prec, tflops in (("f64", h["fp64_tflops"]), ("f32", h["fp32_tflops"])):
        nbytes = fm[f"bytes_{prec}"]
        mem_ms = nbytes * 4096 ** 2 / (h["hbm_tb_s"] * 1e12) * 1e3
        flops = h["pixel_layout_flops"] * 4096 ** 2
        cmp_ms = flops / (tflops * 1e12) * 1e3
        out.append(f"- H100, 4096x4096 {prec} (vendor peaks, not measured): memory "
                   f"{mem_ms:.3f} ms + compute {cmp_ms:.3f} ms per iteration (the `pixel` "
                   f"layout evaluates 4 alphas per pixel, about {h['pixel_layout_flops']} "
                   f"flops), i.e. about {5 * max(mem_ms, cmp_ms):.1f} ms for 5 iterations.")
    out += ["", "How close each path gets (largest size, wall time per pixel and iteration):", ""]
    for r in rows:
        if r["size"] == max(x["size"] for x in rows):
            per = r["median_s"] / (r["iterations"] * r["size"] ** 2) * 1e9
            prec = "f32" if r["config"].endswith("f32") else "f64"
            ratio = (f", {per / bound[prec]:.2f}x the cost of its alphas alone"
                     if r["config"].startswith("taichi-cpu") and prec in bound else "")
            out.append(f"- {r['config']} {r['kind']} {r['size']}: {per:.1f} ns{ratio}.")
    out += ["", "See docs/performance.md for the discussion."]
    return "\n".join(out)


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


# --------------------------------------------------------------------------- command line

def add_parser(sub):
    p = sub.add_parser(
        "bench", help="time decoupling: NumPy vs Taichi CPU f64/f32 (and CUDA when present)",
        description="Decouple the same frames with plain NumPy and with Taichi (CPU f64, f32; "
                    "CUDA f64, f32 when a GPU is present), each configuration in a fresh "
                    "process; print a table and write bench/results.json and bench/RESULTS.md.")
    p.add_argument("--sizes", default=",".join(map(str, SIZES)),
                   help="comma-separated square frame sizes (default: 512,2048,4096)")
    p.add_argument("--kinds", default=",".join(KINDS),
                   help="frames: uniform (0..60000) and/or stars (default: both)")
    p.add_argument("--repeats", type=int, default=5,
                   help="timed runs per configuration, median reported (default 5)")
    p.add_argument("--configs", default=None,
                   help="comma-separated subset of numpy,numpy-reference,taichi-cpu-f64,"
                        "taichi-cpu-f32,taichi-cuda-f64,taichi-cuda-f32")
    p.add_argument("--output", default="bench", help="directory for results (default: bench)")
    p.set_defaults(run=run_cli)


def run_cli(args):
    from .errors import IPCInputError

    try:
        sizes = tuple(int(s) for s in args.sizes.split(","))
    except ValueError:
        raise IPCInputError(f"--sizes {args.sizes!r}: expected integers like 512,2048") from None
    kinds = tuple(k.strip() for k in args.kinds.split(","))
    bad = [k for k in kinds if k not in KINDS]
    if bad or not sizes or min(sizes) < 8 or args.repeats < 1:
        raise IPCInputError(f"bench: need sizes >= 8, kinds in {KINDS}, repeats >= 1")
    configs = args.configs.split(",") if args.configs else None
    print(f"ipc-taichi bench: sizes {sizes}, frames {kinds}, {args.repeats} repeats",
          flush=True)
    results = run_benchmark(sizes, kinds, args.repeats, configs,
                            progress=lambda s: print(s, flush=True))
    for note in results["notes"]:
        print("note:", note)
    write_results(results, args.output)
    print(f"wrote {os.path.join(args.output, 'results.json')} and "
          f"{os.path.join(args.output, 'RESULTS.md')}")
    return 1 if any("error" in r for r in results["rows"]) else 0


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--worker":
        _worker_main()

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

__all__ = ["run_benchmark", "measure_floor", "measure_cuda", "CupyPeer", "render_cuda"]

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
    if spec["config"] == "cuda-suite":
        return measure_cuda(spec["size"], spec["repeats"], spec["stack"])
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
        from ipc_taichi import _engine

        # the timed runs allocate their working buffers (reused from run to
        # run): the peak memory below includes them
        _engine.clear_workspaces()
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


# --------------------------------------------------------------------------- CUDA rows

CUDA_SIZE = 4096
STACK_FRAMES = 16

# The CuPy peer: one Jacobi step of the paper's decoupler as a plain CUDA
# kernel (one thread per pixel, 4 alphas, zero signal outside the frame),
# driven from CuPy with the same stopping and divergence rules
# (ipc_taichi.iteration) and CuPy's own max-reductions. Written for this
# benchmark; CuPy is only a peer here, never a dependency.
PEER_SOURCE = r"""
extern "C" __global__ void jacobi_step(const REAL* __restrict__ s, const REAL* __restrict__ m,
                                       REAL* __restrict__ out, const int ny, const int nx,
                                       const REAL amp_diff, const REAL inv_diff,
                                       const REAL amp_level, const REAL inv_level,
                                       const REAL floor_) {
    const int x = blockIdx.x * blockDim.x + threadIdx.x;
    const int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= nx || y >= ny) return;
    const long i = (long)y * nx + x;
    const REAL c = s[i];
    REAL nb[4];
    nb[0] = x > 0 ? s[i - 1] : (REAL)0;
    nb[1] = x + 1 < nx ? s[i + 1] : (REAL)0;
    nb[2] = y > 0 ? s[i - nx] : (REAL)0;
    nb[3] = y + 1 < ny ? s[i + nx] : (REAL)0;
    REAL flow = 0;
#pragma unroll
    for (int k = 0; k < 4; ++k) {
        const REAL n = nb[k];
        const REAL a = amp_diff * exp(-fabs(c - n) * inv_diff)
                     + amp_level * exp(-sqrt(c * c + n * n) * inv_level) + floor_;
        flow += a * (n - c);
    }
    out[i] = m[i] - flow;
}
"""


class CupyPeer:
    """The CuPy peer for one precision (see :data:`PEER_SOURCE`)."""

    def __init__(self, precision):
        import cupy as cp

        from . import laws

        self.cp = cp
        self.dtype = np.float64 if precision == "f64" else np.float32
        real = "double" if precision == "f64" else "float"
        self.kernel = cp.RawKernel(f"#define REAL {real}\n" + PEER_SOURCE, "jacobi_step")
        self.params = tuple(self.dtype(v) for v in laws.donlon2018().kernel_params())

    def decouple(self, m):
        """Device-resident: ``m`` a CuPy array; returns ``(signal, iterations)``."""
        from . import iteration

        cp = self.cp
        ny, nx = m.shape
        prev, nxt = m.copy(), cp.empty_like(m)
        block = (32, 8, 1)
        grid = ((nx + 31) // 32, (ny + 7) // 8, 1)
        deltas, signals = [], []
        for q in range(1, iteration.MAX_ITER + 1):
            self.kernel(grid, block, (prev, m, nxt, np.int32(ny), np.int32(nx)) + self.params)
            deltas.append(float(cp.abs(nxt - prev).max()))
            signals.append(float(cp.abs(nxt).max()))
            iteration.check_divergence(deltas, signals)
            prev, nxt = nxt, prev
            if iteration.met(deltas[-1], signals[-1], iteration.TOL):
                break
        return prev, q


def _floor_kernels(precision):
    """Taichi kernels for the floor on the device: the alpha arithmetic alone
    (4 alphas per pixel from one load, no neighbour loads), a device copy, and
    a plain one-thread-per-pixel step without the stopping-rule maxima."""
    import taichi as ti

    from ._kernels import make_alpha

    real = ti.f64 if precision == "f64" else ti.f32
    alpha = make_alpha("parametric", precision, fast_exp=False)
    frame = ti.types.ndarray(dtype=real, ndim=2)
    vector = ti.types.ndarray(dtype=real, ndim=1)

    @ti.kernel
    def alpha_math(a: frame, o: frame, p: vector, table: frame):
        for i, j in ti.ndrange(a.shape[0], a.shape[1]):
            c = a[i, j]
            acc = ti.cast(0.0, real)
            for k in ti.static(range(4)):
                n = c + (k + 1) * 37.0
                acc += alpha(c, n, p, table) * (n - c)
            o[i, j] = acc

    @ti.kernel
    def copy(a: frame, o: frame):
        for i, j in ti.ndrange(a.shape[0], a.shape[1]):
            o[i, j] = a[i, j]

    @ti.kernel
    def plain_step(s: frame, m: frame, o: frame, p: vector, table: frame):
        for i, j in ti.ndrange(s.shape[0], s.shape[1]):
            c = s[i, j]
            flow = ti.cast(0.0, real)
            for k in ti.static(range(4)):
                dy, dx = ti.static(((0, 1), (0, -1), (1, 0), (-1, 0))[k])
                n = ti.cast(0.0, real)
                if 0 <= i + dy < s.shape[0] and 0 <= j + dx < s.shape[1]:
                    n = s[i + dy, j + dx]
                flow += alpha(c, n, p, table) * (n - c)
            o[i, j] = m[i, j] - flow

    return alpha_math, copy, plain_step


def _timed(fn, sync, repeats):
    """``(median ms, best ms, last result)`` of ``repeats`` warm runs."""
    result = fn()
    sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        sync()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), min(times), result


def measure_cuda(size=CUDA_SIZE, repeats=10, stack=STACK_FRAMES, arch="cuda",
                 precisions=("f64", "f32")):
    """The CUDA rows: device-resident, host in and out, a stack, the CuPy peer
    and the floor, on one ``size`` x ``size`` uniform frame (law donlon2018,
    nearest neighbours, the paper's stopping rule). Runs in a worker process.

    ``arch="cpu"`` runs the same code with PyTorch CPU tensors as the "device"
    (the tests do, to keep this function honest without a GPU); the CuPy peer
    then is skipped. Returns ``{"rows": [...], "notes": [...], "device": ...}``.
    """
    import ipc_taichi

    from . import _device, _engine, runtime
    from .reference import couple_reference

    notes = []
    try:
        import torch

        if arch == "cuda" and not torch.cuda.is_available():
            torch = None
            notes.append("PyTorch here has no CUDA (a CPU build): the device-resident rows "
                         "were not run; install a CUDA build of torch for them.")
    except ImportError:
        torch = None
        notes.append("PyTorch is not installed: the device-resident rows were not run.")
    try:
        if arch != "cuda":
            raise ImportError("CuPy peer runs on CUDA only")
        import cupy as cp
    except ImportError:
        cp = None
        notes.append("CuPy is not installed (or no CUDA): the CuPy peer rows were not run.")
    truth = uniform_frame(size)
    measured64 = couple_reference(truth)
    rows = []
    device = "CPU (PyTorch CPU tensors stand in for the device)" if arch != "cuda" else "CUDA"
    for precision in precisions:
        info = runtime.init(arch, precision)
        dtype = info.dtype
        measured = measured64.astype(dtype)
        tdev = "cuda" if arch == "cuda" else "cpu"
        if arch == "cuda":
            device = _device.cuda_driver().device_name()

        def sync():
            import taichi as ti

            ti.sync()
            if torch is not None and arch == "cuda":
                torch.cuda.synchronize()

        def add(row, median, best, signal, iterations, frames=1):
            err = float(np.abs(np.asarray(signal, dtype=np.float64).reshape(-1, size, size)[0]
                               - truth).max())
            rows.append({"row": row, "precision": precision, "size": size, "frames": frames,
                         "median_ms": median, "best_ms": best, "iterations": iterations,
                         "max_error": err})

        def run(data, **kw):
            return ipc_taichi.decouple(data, arch=arch, precision=precision, full_output=True,
                                       **kw)

        # NumPy in and out: page-locked for the call (the default)
        _engine.clear_workspaces()
        free0 = _device.cuda_driver().memory()[0] if arch == "cuda" else None
        med, best, (sig, fi) = _timed(lambda: run(measured), sync, repeats)
        add("host in/out (NumPy)", med, best, sig, fi.iterations)
        if free0 is not None:
            used = free0 - _device.cuda_driver().memory()[0]
            rows[-1]["device_bytes"] = int(used)
        (ws,) = _engine.cached_workspaces()
        rows[-1]["workspace_bytes"] = ws.nbytes
        rows[-1]["frame_bytes"] = measured.nbytes
        # NumPy in and out from buffers the caller keeps page-locked
        pin_in = _device.pinned_empty(measured.shape, dtype, arch=arch)
        pin_in[...] = measured
        pin_out = _device.pinned_empty(measured.shape, dtype, arch=arch)
        med, best, (sig, fi) = _timed(lambda: run(pin_in, out=pin_out), sync, repeats)
        add("host in/out, pinned buffers", med, best, sig, fi.iterations)
        # the same with pageable copies (no page-locking)
        saved = _device.PIN_MIN_BYTES
        _device.PIN_MIN_BYTES = 1 << 62
        try:
            med, best, (sig, fi) = _timed(lambda: run(measured), sync, repeats)
        finally:
            _device.PIN_MIN_BYTES = saved
        add("host in/out, pageable copies", med, best, sig, fi.iterations)
        # the copies alone, through the workspace the runs above used
        if ws.device_buffers:
            med_up, best_up, _ = _timed(lambda: ws.copies.upload(ws.io, pin_in), sync, repeats)
            add("upload one frame (pinned)", med_up, best_up, sig, 0)
            med_dn, best_dn, _ = _timed(lambda: ws.copies.download(pin_out, ws.io), sync,
                                        repeats)
            add("download one frame (pinned)", med_dn, best_dn, sig, 0)
        # device-resident: a tensor in, a tensor out, nothing crosses the bus
        dev_ms = None
        if torch is not None:
            t_in = torch.from_numpy(measured).to(tdev)
            med, best, (sig, fi) = _timed(lambda: run(t_in), sync, repeats)
            add("device-resident (torch)", med, best, sig.cpu().numpy(), fi.iterations)
            dev_ms = med
            t_in = sig = None
        # a stack of frames, NumPy in and out
        cube = np.broadcast_to(measured, (stack,) + measured.shape).copy()
        med, best, (sig, fis) = _timed(lambda: run(cube), sync, max(1, repeats // 4))
        add(f"{stack}-frame stack, host in/out, per frame", med / stack, best / stack, sig,
            fis[0].iterations, frames=stack)
        cube = sig = None  # release 2 x 16 frames before the next rows
        # the CuPy peer
        if cp is not None:
            peer = CupyPeer(precision)
            m_dev = cp.asarray(measured)
            med, best, (s, q) = _timed(lambda: peer.decouple(m_dev), sync, repeats)
            add("CuPy peer, device-resident", med, best, cp.asnumpy(s), q)
            med, best, (s, q) = _timed(lambda: cp.asnumpy(peer.decouple(cp.asarray(measured))[0]),
                                       sync, repeats)
            add("CuPy peer, host in/out (pageable)", med, best, s, q)
            m_dev = None
            cp.get_default_memory_pool().free_all_blocks()
        # the floor, on this device, with Taichi ndarrays
        import taichi as ti

        alpha_math, copy, plain_step = _floor_kernels(precision)
        kind = ti.f64 if precision == "f64" else ti.f32
        a, o = ti.ndarray(kind, measured.shape), ti.ndarray(kind, measured.shape)
        a.from_numpy(measured)
        p, table = ti.ndarray(kind, 5), ti.ndarray(kind, (2, 2))
        p.from_numpy(laws_params(dtype))
        table.fill(0)
        for name, fn in (("floor: alpha arithmetic alone (4 alphas/pixel)",
                          lambda: alpha_math(a, o, p, table)),
                         ("floor: device copy of the frame", lambda: copy(a, o)),
                         ("floor: plain step (4 alphas, no maxima)",
                          lambda: plain_step(a, a, o, p, table))):
            med, best, _ = _timed(fn, sync, repeats)
            rows.append({"row": name, "precision": precision, "size": size, "frames": 1,
                         "median_ms": med, "best_ms": best})
        a = o = None
        if dev_ms is not None:
            rows.append({"row": "note: device-resident per iteration", "precision": precision,
                         "size": size, "frames": 1, "median_ms": dev_ms / max(1, fi.iterations),
                         "best_ms": dev_ms / max(1, fi.iterations)})
        _engine.clear_workspaces()
    return {"rows": rows, "notes": notes, "device": device, "arch": arch}


def laws_params(dtype):
    """donlon2018's kernel parameters in ``dtype``."""
    return donlon2018().kernel_params().astype(dtype)


MUST_SHOW = {
    ("device-resident (torch)", "f64"): 3.0, ("device-resident (torch)", "f32"): 1.5,
    ("host in/out (NumPy)", "f64"): 20.0, ("host in/out (NumPy)", "f32"): 10.0,
}


def render_cuda(cuda):
    """The CUDA section of RESULTS.md."""
    if not cuda:
        return ""
    if not cuda["rows"]:
        return "## CUDA\n\nNo CUDA row was measured.\n" + "".join(
            f"- {n}\n" for n in cuda["notes"])
    lines = ["## CUDA", "", f"Device: {cuda['device']}. Frame {cuda['rows'][0]['size']} x "
             f"{cuda['rows'][0]['size']} uniform 0..60000, law donlon2018, nearest neighbours, "
             "the paper's stopping rule. Median and best of warm runs (synchronised).", "",
             "| what | precision | median [ms] | best [ms] | iterations | max error | target |",
             "|---|---|---:|---:|---:|---:|---|"]
    judged = cuda.get("arch") == "cuda" and cuda["rows"][0]["size"] == 4096
    for r in cuda["rows"]:
        target = MUST_SHOW.get((r["row"], r["precision"])) if judged else None
        verdict = "" if target is None else (
            f"<= {target} ms: {'met' if r['median_ms'] <= target else 'NOT met'}")
        it = r.get("iterations")
        err = r.get("max_error")
        lines.append(f"| {r['row']} | {r['precision']} | {r['median_ms']:.3f} | "
                     f"{r['best_ms']:.3f} | {'' if not it else it} | "
                     f"{'' if err is None or not it else f'{err:.3g}'} | {verdict} |")
    by = {(r["row"], r["precision"]): r for r in cuda["rows"]}
    for prec in ("f64", "f32"):
        dev = by.get(("device-resident (torch)", prec))
        peer = by.get(("CuPy peer, device-resident", prec))
        if dev and peer:
            lines.append(f"- {prec}: device-resident {dev['median_ms']:.2f} ms vs CuPy peer "
                         f"{peer['median_ms']:.2f} ms "
                         f"({'not slower' if dev['median_ms'] <= peer['median_ms'] else 'SLOWER'}).")
        st = next((r for r in cuda["rows"] if r["precision"] == prec
                   and r["row"].endswith("stack, host in/out, per frame")), None)
        up, dn = by.get(("upload one frame (pinned)", prec)), by.get(
            ("download one frame (pinned)", prec))
        if st and up and dn and dev:
            one = up["median_ms"] + dn["median_ms"] + dev["median_ms"]
            lines.append(f"- {prec}: stack per frame {st['median_ms']:.2f} ms vs upload + "
                         f"download + device decouple of one frame {one:.2f} ms: "
                         f"{st['median_ms'] / one:.2f}x (target <= 1.2x).")
        host = by.get(("host in/out (NumPy)", prec))
        if host and "workspace_bytes" in host:
            extra = (f", device memory used by the call {host['device_bytes'] / host['frame_bytes']:.2f}x"
                     if "device_bytes" in host else "")
            lines.append(f"- {prec}: working buffers {host['workspace_bytes'] / host['frame_bytes']:.2f}x "
                         f"the frame's bytes{extra} (target <= 3.5x).")
    lines += [""] + [f"- {n}" for n in cuda["notes"]]
    return "\n".join(lines) + "\n"


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
                  measure=True, cuda_size=CUDA_SIZE, stack=STACK_FRAMES):
    """Run every configuration on every frame; return the results dict.

    With ``measure``, also time the floor's building blocks
    (:func:`measure_floor`) in a subprocess of their own and, on a machine with
    a CUDA GPU, the CUDA rows (:func:`measure_cuda`, ``cuda_size`` frames, a
    ``stack``-frame stack) in another.
    """
    info = machine()
    configs = list(configs or _configs(info["cuda"]))
    notes = []
    if not info["cuda"]:
        notes.append("No CUDA GPU on this machine: the Taichi CUDA rows and the CUDA section "
                     "(device-resident, host in/out, stack, CuPy peer, device floor) were not run.")
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
    cuda = None
    if measure and info["cuda"] and cuda_size:
        progress(f"  CUDA rows at {cuda_size}x{cuda_size} (stack of {stack})")
        proc = subprocess.run(
            [sys.executable, "-m", "ipc_taichi.bench", "--worker",
             json.dumps({"config": "cuda-suite", "size": cuda_size, "repeats": max(repeats, 10),
                         "stack": stack})],
            capture_output=True, text=True,
            env=dict(os.environ, ENABLE_TAICHI_HEADER_PRINT="False"))
        if proc.returncode == 0:
            cuda = json.loads(proc.stdout.strip().splitlines()[-1])
        else:
            notes.append("The CUDA rows failed: "
                         + (proc.stderr.strip().splitlines() or ["no output"])[-1])
    return {"machine": info, "repeats": repeats, "notes": notes, "rows": rows, "floor": floor,
            "cuda": cuda}


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
    cuda = render_cuda(results.get("cuda"))
    if cuda:
        lines += [cuda]
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


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--worker":
        _worker_main()

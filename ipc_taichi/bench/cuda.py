"""The CUDA rows of the benchmark (:func:`measure_cuda`): device-resident,
host in and out (staged, the default; from the caller's pinned buffers;
pageable; page-locked for the call), the copies alone, a stack, the CuPy peer and the floor on the
device. ``arch="cpu"`` runs the same code with PyTorch CPU tensors standing in
for the device (the tests do). The engine is asked only through its public
face, :mod:`ipc_taichi.engine` (:func:`~ipc_taichi.engine.workspace_cache_info`,
:func:`~ipc_taichi.engine.frame_copies`, :func:`~ipc_taichi.engine.pageable_copies`).
"""

import statistics
import time

import numpy as np

import ipc_taichi

from .. import engine, runtime
from ..datasets import uniform_frame
from ..engine import make_alpha
from ..laws import donlon2018
from ..reference import couple_reference
from .peers import CupyPeer

__all__ = ["measure_cuda", "CUDA_SIZE", "STACK_FRAMES", "laws_params"]

CUDA_SIZE = 4096
STACK_FRAMES = 16


def _floor_kernels(precision):
    """Taichi kernels for the floor on the device: the alpha arithmetic alone
    (4 alphas per pixel from one load, no neighbour loads), a device copy, and
    a plain one-thread-per-pixel step without the stopping-rule maxima."""
    import taichi as ti

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
            device = engine.cuda_driver().device_name()

        def sync():
            import taichi as ti

            ti.sync()
            if torch is not None and arch == "cuda":
                torch.cuda.synchronize()

        # add, run and the lambdas timed below are all called within this iteration: the
        # loop variables they read cannot change under them (hence the B023 noqa's)
        def add(row, median, best, signal, iterations, frames=1):
            err = float(np.abs(np.asarray(signal, dtype=np.float64).reshape(-1, size, size)[0]
                               - truth).max())
            rows.append({"row": row, "precision": precision,  # noqa: B023
                         "size": size, "frames": frames,
                         "median_ms": median, "best_ms": best, "iterations": iterations,
                         "max_error": err})

        def run(data, **kw):
            return ipc_taichi.decouple(data, arch=arch, precision=precision,  # noqa: B023
                                       full_output=True, **kw)

        # NumPy in and out: staged through the workspace's page-locked frame (the default)
        engine.clear_workspaces()
        free0 = engine.cuda_driver().memory()[0] if arch == "cuda" else None
        med, best, (sig, fi) = _timed(lambda: run(measured), sync, repeats)  # noqa: B023
        add("host in/out (NumPy)", med, best, sig, fi.iterations)
        if free0 is not None:
            used = free0 - engine.cuda_driver().memory()[0]
            rows[-1]["device_bytes"] = int(used)
        rows[-1]["workspace_bytes"] = sum(engine.workspace_cache_info().values())
        rows[-1]["frame_bytes"] = measured.nbytes
        # NumPy in and out from buffers the caller keeps page-locked
        pin_in = engine.pinned_empty(measured.shape, dtype, arch=arch)
        pin_in[...] = measured
        pin_out = engine.pinned_empty(measured.shape, dtype, arch=arch)
        med, best, (sig, fi) = _timed(lambda: run(pin_in, out=pin_out),  # noqa: B023
                                      sync, repeats)
        add("host in/out, pinned buffers", med, best, sig, fi.iterations)
        # the same with pageable copies (no staging, no page-locking)
        with engine.pageable_copies():
            med, best, (sig, fi) = _timed(lambda: run(measured), sync, repeats)  # noqa: B023
        add("host in/out, pageable copies", med, best, sig, fi.iterations)
        # the same with the caller's frames page-locked for each call
        with engine.copy_policy("register"):
            med, best, (sig, fi) = _timed(lambda: run(measured), sync, repeats)  # noqa: B023
        add("host in/out, page-locked per call", med, best, sig, fi.iterations)
        # the copies alone, through the workspace the runs above used
        copies = engine.frame_copies()
        if copies is not None:
            upload, download = copies
            med_up, best_up, _ = _timed(lambda: upload(pin_in), sync, repeats)  # noqa: B023
            add("upload one frame (pinned)", med_up, best_up, sig, 0)
            med_dn, best_dn, _ = _timed(lambda: download(pin_out), sync, repeats)  # noqa: B023
            add("download one frame (pinned)", med_dn, best_dn, sig, 0)
        # device-resident: a tensor in, a tensor out, nothing crosses the bus
        dev_ms = None
        if torch is not None:
            t_in = torch.from_numpy(measured).to(tdev)
            med, best, (sig, fi) = _timed(lambda: run(t_in), sync, repeats)  # noqa: B023
            add("device-resident (torch)", med, best, sig.cpu().numpy(), fi.iterations)
            dev_ms = med
            t_in = sig = None
        # a stack of frames, NumPy in and out
        cube = np.broadcast_to(measured, (stack,) + measured.shape).copy()
        med, best, (sig, fis) = _timed(lambda: run(cube),  # noqa: B023
                                       sync, max(1, repeats // 4))
        add(f"{stack}-frame stack, host in/out, per frame", med / stack, best / stack, sig,
            fis[0].iterations, frames=stack)
        cube = sig = None  # release 2 x 16 frames before the next rows
        # the CuPy peer
        if cp is not None:
            peer = CupyPeer(precision)
            m_dev = cp.asarray(measured)
            med, best, (s, q) = _timed(lambda: peer.decouple(m_dev), sync, repeats)  # noqa: B023
            add("CuPy peer, device-resident", med, best, cp.asnumpy(s), q)
            med, best, (s, q) = _timed(
                lambda: _host_result(peer.decouple(cp.asarray(measured)), cp),  # noqa: B023
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
                          lambda: alpha_math(a, o, p, table)),  # noqa: B023
                         ("floor: device copy of the frame", lambda: copy(a, o)),  # noqa: B023
                         ("floor: plain step (4 alphas, no maxima)",
                          lambda: plain_step(a, a, o, p, table))):  # noqa: B023
            med, best, _ = _timed(fn, sync, repeats)
            rows.append({"row": name, "precision": precision, "size": size, "frames": 1,
                         "median_ms": med, "best_ms": best})
        a = o = None
        if dev_ms is not None:
            rows.append({"row": "note: device-resident per iteration", "precision": precision,
                         "size": size, "frames": 1, "median_ms": dev_ms / max(1, fi.iterations),
                         "best_ms": dev_ms / max(1, fi.iterations)})
        engine.clear_workspaces()
    return {"rows": rows, "notes": notes, "device": device, "arch": arch}


def _host_result(result, cp):
    """The CuPy peer's ``(signal, iterations)`` with the signal on the host."""
    signal, iterations = result
    return cp.asnumpy(signal), iterations


def laws_params(dtype):
    """donlon2018's kernel parameters in ``dtype``."""
    return donlon2018().kernel_params().astype(dtype)

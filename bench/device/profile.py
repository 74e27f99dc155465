# ruff: noqa
"""Device profile of one 4096x4096 donlon2018 decouple (issue 40): host-side time split,
steps run ahead vs synchronous, copy policies, correctness vs the NumPy reference.
PROF_KP=1: Taichi's kernel profiler instead (one decouple of each kind)."""
import json, os, statistics, sys, time
import numpy as np
import taichi as ti

KP = os.environ.get("PROF_KP") == "1"
_init = ti.init
def _init_kp(*a, **k):
    if KP:
        k["kernel_profiler"] = True
    return _init(*a, **k)
ti.init = _init_kp

import ipc_taichi
from ipc_taichi import engine, decoupling, runtime

# the engine's parts that the profile times (through the engine's face)
_engine, _workspace = engine._engine, engine._workspace
from ipc_taichi.datasets import uniform_frame
from ipc_taichi.reference import couple_reference, decouple_reference

ARCH = os.environ.get("IPC_TAICHI_ARCH", "cuda")
if os.environ.get("PROF_FORCE") == "1":
    _engine.FORCE_DEVICE_BUFFERS = True
SIZE = int(os.environ.get("PROF_SIZE", "4096"))
REF = int(os.environ.get("PROF_REF", "1024"))
REP = int(os.environ.get("PROF_REP", "10"))
OUT = os.environ.get("OUT", "/tmp")
try:
    import torch
    TDEV = "cuda" if ARCH == "cuda" else "cpu"
except ImportError:
    torch = None

def sync():
    ti.sync()
    if torch is not None and ARCH == "cuda":
        torch.cuda.synchronize()

def timed(fn, n=REP):
    r = fn(); sync(); ts = []
    for _ in range(n):
        t0 = time.perf_counter(); r = fn(); sync(); ts.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(ts), min(ts), r

here = decoupling._iterate
def synchronous(step, ws, mi, tol, cb, rec):
    return decoupling._iterate_here(step, ws, mi, tol, cb, rec)

acc = {}
def wrap(obj, name, key, do_sync):
    f = getattr(obj, name)
    def w(*a, **k):
        t0 = time.perf_counter(); r = f(*a, **k)
        if do_sync: sync()
        acc[key] = acc.get(key, 0.0) + (time.perf_counter() - t0) * 1e3
        acc[key + "#"] = acc.get(key + "#", 0) + 1
        return r
    setattr(obj, name, w)
    return f

report = {"size": SIZE, "arch": ARCH}
if ARCH == "cuda":
    report["device"] = engine.cuda_driver().device_name() if False else None

def main():
    truth = uniform_frame(SIZE)
    m64 = couple_reference(truth)
    # correctness vs the NumPy reference in f64 (REF x REF), and tiled == whole
    runtime.init(ARCH, "f64")
    if ARCH == "cuda":
        report["device"] = engine.cuda_driver().device_name()
    small = couple_reference(uniform_frame(REF, seed=5))
    want, qn = decouple_reference(small)[:2]
    got, info = ipc_taichi.decouple(small, arch=ARCH, precision="f64", full_output=True)
    rel = float(np.abs(got - want).max() / np.abs(want).max())
    from ipc_taichi.tiling import decouple_tiled
    tiled = decouple_tiled(small, 256, arch=ARCH, precision="f64")
    report["check"] = {"ref_size": REF, "max_rel_vs_numpy": rel, "iterations": info.iterations, "ref_iterations": qn,
                       "tiled_vs_whole": float(np.abs(tiled - got).max() / np.abs(got).max())}
    if torch is not None:
        tg = ipc_taichi.decouple(torch.from_numpy(small).to(TDEV), arch=ARCH, precision="f64")
        decoupling._iterate = synchronous
        ts = ipc_taichi.decouple(torch.from_numpy(small).to(TDEV), arch=ARCH, precision="f64")
        decoupling._iterate = here
        report["check"]["ahead_equals_synchronous"] = bool(torch.equal(tg, ts))
        report["check"]["torch_equals_numpy"] = bool(np.array_equal(tg.cpu().numpy(), got))
    print(json.dumps(report["check"]), flush=True)
    if KP:
        return kernel_profile(m64)
    rows = report["rows"] = []
    for prec in ("f64", "f32"):
        info = runtime.init(ARCH, prec)
        m = m64.astype(info.dtype)
        def run(x, **kw):
            return ipc_taichi.decouple(x, arch=ARCH, precision=prec, full_output=True, **kw)
        def add(name, r):
            med, best, (sig, fi) = r
            s = np.asarray(sig.cpu().numpy() if hasattr(sig, "cpu") else sig, dtype=np.float64)
            rows.append({"row": name, "prec": prec, "median_ms": med, "best_ms": best,
                         "iterations": fi.iterations, "max_err": float(np.abs(s - truth).max())})
            print(json.dumps(rows[-1]), flush=True)
        engine.clear_workspaces()
        free0 = engine.cuda_driver().memory()[0] if ARCH == "cuda" else 0
        if torch is not None:
            t_in = torch.from_numpy(m).to(TDEV)
            add("device-resident, steps ahead (new)", timed(lambda: run(t_in)))
            if ARCH == "cuda":
                used = free0 - engine.cuda_driver().memory()[0]
                rows[-1]["device_bytes_taichi_over_frame"] = used / m.nbytes
                rows[-1]["workspace_over_frame"] = sum(engine.workspace_cache_info().values()) / m.nbytes
            decoupling._iterate = synchronous
            fast = _engine.fast
            _engine.fast = lambda k: k
            add("device-resident, steps synchronous, Taichi's own launches (old)", timed(lambda: run(t_in)))
            decoupling._iterate = here
            add("device-resident, steps ahead, Taichi's own launches", timed(lambda: run(t_in)))
            _engine.fast = fast
            # host-side split of one device-resident call (no extra syncs): launch vs wait
            acc.clear()
            f1 = wrap(_engine._Run, "_launch", "launch_host", False)
            f2 = wrap(_workspace.Workspace, "maxima_wait", "maxima_wait", False)
            f3 = wrap(_engine._Run, "load", "load(sync flag)", False)
            f4 = wrap(_engine._Run, "finish", "finish(store)", False)
            for _ in range(5):
                t0 = time.perf_counter(); run(t_in); sync(); acc["total"] = acc.get("total", 0) + (time.perf_counter() - t0) * 1e3
            _engine._Run._launch, _workspace.Workspace.maxima_wait, _engine._Run.load, _engine._Run.finish = f1, f2, f3, f4
            rows.append({"row": "split device-resident (ms per call, 5 calls)", "prec": prec,
                         **{k: v / 5 for k, v in acc.items()}})
            print(json.dumps(rows[-1]), flush=True)
            # the same split with a sync after each part (device time attributed)
            acc.clear()
            f1 = wrap(_engine._Run, "_launch", "step(sync)", True)
            f3 = wrap(_engine._Run, "load", "load(sync)", True)
            f4 = wrap(_engine._Run, "finish", "finish(sync)", True)
            for _ in range(5):
                t0 = time.perf_counter(); run(t_in); sync(); acc["total"] = acc.get("total", 0) + (time.perf_counter() - t0) * 1e3
            _engine._Run._launch, _engine._Run.load, _engine._Run.finish = f1, f3, f4
            rows.append({"row": "split device-resident, synced parts (ms per call)", "prec": prec,
                         **{k: v / 5 for k, v in acc.items()}})
            print(json.dumps(rows[-1]), flush=True)
            t_in = None
        add("host in/out staged (new default)", timed(lambda: run(m)))
        with engine.copy_policy("register"):
            add("host in/out page-locked per call (old default)", timed(lambda: run(m)))
        with engine.pageable_copies():
            add("host in/out pageable", timed(lambda: run(m)))
        out = np.empty_like(m)
        add("host in/out staged, out= reused", timed(lambda: run(m, out=out)))
        pin_in = engine.pinned_empty(m.shape, m.dtype); pin_in[...] = m
        pin_out = engine.pinned_empty(m.shape, m.dtype)
        add("host in/out pinned buffers", timed(lambda: run(pin_in, out=pin_out)))
        # split of a staged host call, synced parts
        acc.clear()
        g1 = wrap(engine.HostCopies, "upload", "upload", True)
        g2 = wrap(engine.HostCopies, "download", "download", True)
        f3 = wrap(_engine._Run, "load", "load incl upload", True)
        f4 = wrap(_engine._Run, "finish", "finish incl download", True)
        for _ in range(5):
            t0 = time.perf_counter(); run(m); sync(); acc["total"] = acc.get("total", 0) + (time.perf_counter() - t0) * 1e3
        engine.HostCopies.upload, engine.HostCopies.download, _engine._Run.load, _engine._Run.finish = g1, g2, f3, f4
        rows.append({"row": "split host in/out staged (ms per call)", "prec": prec, **{k: v / 5 for k, v in acc.items()}})
        print(json.dumps(rows[-1]), flush=True)
        # copy rates alone
        if ARCH == "cuda":
            copies = engine.frame_copies()
            up, down = copies
            for nm, fn in (("upload pinned", lambda: up(pin_in)), ("download pinned", lambda: down(pin_out)),
                           ("upload staged", lambda: up(m)), ("download staged", lambda: down(out))):
                med, best, _ = timed(fn)
                rows.append({"row": nm, "prec": prec, "median_ms": med, "best_ms": best,
                             "GB_s": m.nbytes / med / 1e6})
                print(json.dumps(rows[-1]), flush=True)
            drv = engine.cuda_driver()
            fresh = np.empty_like(m); fresh[...] = 1
            t0 = time.perf_counter(); drv.register(fresh.ctypes.data, fresh.nbytes); t1 = time.perf_counter()
            drv.unregister(fresh.ctypes.data); t2 = time.perf_counter()
            rows.append({"row": "cuMemHostRegister/unregister one frame", "prec": prec,
                         "register_ms": (t1 - t0) * 1e3, "unregister_ms": (t2 - t1) * 1e3})
            print(json.dumps(rows[-1]), flush=True)
            t0 = time.perf_counter(); z = np.empty_like(m); z[...] = 0; t1 = time.perf_counter()
            rows.append({"row": "first touch of a fresh frame (np.empty + fill)", "prec": prec, "ms": (t1 - t0) * 1e3})
            print(json.dumps(rows[-1]), flush=True)
        pin_in = pin_out = None
        engine.clear_workspaces()

def kernel_profile(m64):
    for prec in ("f64", "f32"):
        info = runtime.init(ARCH, prec)
        m = m64.astype(info.dtype)
        t_in = torch.from_numpy(m).to(TDEV)
        for _ in range(2):
            ipc_taichi.decouple(t_in, arch=ARCH, precision=prec); sync()
        ti.profiler.clear_kernel_profiler_info()
        for _ in range(3):
            ipc_taichi.decouple(t_in, arch=ARCH, precision=prec); sync()
        print(f"=== kernel profiler, {prec}, 3 device-resident decouples of {SIZE}x{SIZE}", flush=True)
        ti.profiler.print_kernel_profiler_info("trace" if False else "count")
        sys.stdout.flush()

main()
json.dump(report, open(os.path.join(OUT, "profile.json" if not KP else "kp.json"), "w"), indent=1)

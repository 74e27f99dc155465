# ruff: noqa
"""A Roman-like 4096x4096x12 f32 ramp FITS through the CLI on CUDA, with the time split
(read, upload, decouple, download, write/other), in this process after a warm-up; then the
whole CLI command in a fresh process (wall as a user waits)."""
import json, os, subprocess, sys, time
import numpy as np
SIZE = int(os.environ.get("RAMP_SIZE", "4096")); GROUPS = int(os.environ.get("RAMP_GROUPS", "12"))
ARCH = os.environ.get("IPC_TAICHI_ARCH", "cuda")
OUT = os.environ.get("OUT", "/tmp")
import ipc_taichi
from ipc_taichi import decoupling, engine
from ipc_taichi.bench.cliramp import write_ramp_fits, CLIRAMP_LAW
from ipc_taichi.cli import main
import ipc_taichi.products.fits as pf
work = "/tmp/ramp"; os.makedirs(work, exist_ok=True)
src = os.path.join(work, "ramp.fits"); small = os.path.join(work, "small.fits")
t0 = time.perf_counter(); write_ramp_fits(src, SIZE, GROUPS); write_ramp_fits(small, 64, 3)
print(f"ramp written in {time.perf_counter() - t0:.1f} s ({os.path.getsize(src) / 1e6:.0f} MB)", flush=True)
args = ["decouple", None, None, "--law", CLIRAMP_LAW, "--arch", ARCH, "--precision", "f32", "--quiet", "--overwrite"]
if SIZE != 4096:
    args += ["--refpix", "4"]
def cli(i, o):
    a = list(args); a[1], a[2] = i, o
    code = main(a); assert code in (0, None), code
cli(small, os.path.join(work, "small-out.fits"))  # warm-up: JIT, runtime
acc = {}
def wrap(obj, name, key):
    f = getattr(obj, name)
    def w(*a, **k):
        t = time.perf_counter(); r = f(*a, **k)
        acc[key] = acc.get(key, 0.0) + time.perf_counter() - t
        return r
    setattr(obj, name, w)
import ipc_taichi.products.fitsfile as ff
for mod in [m for n, m in list(sys.modules.items()) if n.startswith("ipc_taichi.products")]:
    if getattr(mod, "read_array", None) is ff.read_array and mod is not ff:
        wrap(mod, "read_array", "read (read_array)")
wrap(engine.HostCopies, "upload", "upload")
wrap(engine.HostCopies, "download", "download")
wrap(decoupling, "_iterate", "decouple iterations")
E = engine._engine
wrap(E._Run, "load", "load (incl. upload)")
wrap(E._Run, "finish", "finish (store + download)")
rows = []
for rep in range(2):
    acc.clear()
    out = os.path.join(work, f"out{rep}.fits")
    t0 = time.perf_counter(); cli(src, out); total = time.perf_counter() - t0
    row = {"total_s": total, **{k: v for k, v in acc.items()}}
    row["other (plan, conversions, write, headers)"] = total - acc.get("read (read_array)", 0) - acc.get("load (incl. upload)", 0) \
        - acc.get("decouple iterations", 0) - acc.get("finish (store + download)", 0)
    rows.append(row); print(json.dumps(row), flush=True)
# the whole CLI in a fresh process
env = dict(os.environ)
a = list(args); a[1], a[2] = src, os.path.join(work, "outp.fits")
walls = []
for rep in range(2):
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "ipc_taichi.cli", *a], capture_output=True, text=True, env=env)
    walls.append(time.perf_counter() - t0)
    if p.returncode: print(p.stderr[-2000:])
# read + write alone through the CLI's I/O
from ipc_taichi.bench.cliramp import copy_through_cli_io
t0 = time.perf_counter(); copy_through_cli_io(src, os.path.join(work, "copy.fits")); io_s = time.perf_counter() - t0
res = {"size": SIZE, "groups": GROUPS, "law": CLIRAMP_LAW, "in_process": rows, "cli_process_wall_s": walls,
       "read_write_only_s": io_s}
print(json.dumps(res), flush=True)
json.dump(res, open(os.path.join(OUT, "ramp.json"), "w"), indent=1)

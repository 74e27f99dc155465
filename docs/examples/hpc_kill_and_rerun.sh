#!/bin/bash
# Runs here without Slurm: 300 small files through an external Dask scheduler (a scheduler
# file) with two workers; the command line killed (SIGKILL) a third of the way; re-run with
# --skip-existing. Run it in an empty folder: bash docs/examples/hpc_kill_and_rerun.sh
set -u
export IPC_TAICHI_ARCH=cpu IPC_TAICHI_PRECISION=f64
unset IPC_TAICHI_THREADS SLURM_CPUS_PER_TASK
V=${VENV:-$(cd "$(dirname "$0")/../.." && pwd)/.venv}/bin
$V/python - <<'PY'
import numpy as np; from astropy.io import fits; import os
from ipc_taichi.reference import couple_reference
rng = np.random.default_rng(7); os.makedirs("in", exist_ok=True)
with open("files.txt", "w") as f:
    for k in range(300):
        p = f"in/f{k:04d}.fits"; fits.writeto(p, couple_reference(rng.uniform(0, 5e4, (10, 11)))); f.write(p + "\n")
PY
$V/dask scheduler --scheduler-file sched.json --no-dashboard --host 127.0.0.1 > sched.log 2>&1 & S=$!
while [ ! -f sched.json ]; do sleep 0.2; done
$V/dask worker --scheduler-file sched.json --nthreads 1 --no-dashboard > w1.log 2>&1 & W1=$!
$V/dask worker --scheduler-file sched.json --nthreads 1 --no-dashboard > w2.log 2>&1 & W2=$!
$V/python -c "from distributed import Client; Client(scheduler_file='sched.json').wait_for_workers(2, timeout=120)"
setsid $V/python -m ipc_taichi.cli decouple --files-from files.txt -o out --scheduler-file sched.json --quiet & C=$!
while [ "$(ls out 2>/dev/null | grep -c '^f.*_decoupled.fits$')" -lt 100 ]; do sleep 0.05; done
kill -KILL $C; wait $C 2>/dev/null; echo "first run killed (SIGKILL)"
sleep 2
ls out | grep '^f.*_decoupled.fits$' | sort > first.txt
for f in $(cat first.txt); do stat -c '%n %i %Y %s' out/$f; done > first.stat
echo "outputs after the kill: $(wc -l < first.txt)"
$V/python -m ipc_taichi.cli decouple --files-from files.txt -o out --scheduler-file sched.json --skip-existing 2> second.err; echo "rerun exit code: $?"
tail -1 second.err
echo "skipped lines: $(grep -c '^ipc-taichi: skipped' second.err), decoupled lines: $(grep -c '^ipc-taichi: decoupled' second.err)"
echo "outputs now: $(ls out | grep -c '^f.*_decoupled.fits$')"
for f in $(cat first.txt); do stat -c '%n %i %Y %s' out/$f; done | diff -q - first.stat && echo "first-run outputs unchanged (inode, mtime, size)"
comm -12 <(grep '^ipc-taichi: decoupled' second.err | sed 's/.*-> out\///; s/:.*//' | sort) first.txt | wc -l | sed 's/^/re-decoupled files of the first run: /'
$V/python - <<'PY'
from distributed import Client
from ipc_taichi.workers import taichi_threads
import os
with Client(scheduler_file="sched.json") as c:
    print("workers' Taichi cpu_max_num_threads:", c.run(taichi_threads), "of", len(os.sched_getaffinity(0)), "CPUs")
PY
kill $W1 $W2 $S

#!/bin/bash
# Issue 40's device run (a lent GPU machine without a package registry), from the
# repository root: SECTIONS="env tests profile bench peer ramp kp" bash bench/device/run.sh
# Results under $OUT (log.txt, profile.json, cuda.json, ramp.json, gpu_peer.json, kp.json).
#
# Bring the wheels the machine lacks into $WHEELS (default build/whl), here, where pip works:
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
#     --implementation cp --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
#     -d build/whl taichi==1.7.4 dill astropy pyerfa astropy-iers-data
# (the taichi wheel, 56 MB, fits a 64 MiB transfer only without taichi/_lib/c_api,
# taichi/assets and taichi-1.7.4.data: repack it as a zip without them). The wheels are
# unpacked, not installed: the machine's python3 keeps its torch, CuPy, NumPy and SciPy.
# The peer section runs gpu_peer.py (a CuPy peer script kept outside the repository)
# when it is copied beside this file.
D=$(cd "$(dirname "$0")" && pwd)
TREE=${TREE:-$(cd "$D/../.." && pwd)}
WHEELS=${WHEELS:-$TREE/build/whl}
export PYTHONUNBUFFERED=1 IPC_TAICHI_ARCH=cuda IPC_TAICHI_PRECISION=f64
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
S=${SECTIONS:-"env tests profile bench peer ramp kp"}
python3 - <<PYEOF
import zipfile, glob
for w in glob.glob("$WHEELS/*"):
    zipfile.ZipFile(w).extractall("/tmp/site")
PYEOF
# byte-compile now (as pip does): Python 3.12 warns on some of Taichi's sources, which
# the tests' filterwarnings=error would turn into errors at import
python3 -m compileall -q /tmp/site/taichi >/dev/null 2>&1
export PYTHONPATH=/tmp/site:$TREE
cd "$TREE" || exit 1
main() {
t00=$(date +%s)
sec() { echo; echo "##### $1 (t=$(( $(date +%s) - t00 )) s)"; }
for s in $S; do
case $s in
env) sec env
  nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm,clocks.max.sm --format=csv
  lscpu | grep -E "Model name|^CPU\(s\)"; free -g | head -2; uname -r
  cat /sys/kernel/mm/transparent_hugepage/enabled
  python3 -c "import sys, numpy, torch, cupy, taichi, astropy, scipy; print(sys.version.split()[0], 'numpy', numpy.__version__, 'torch', torch.__version__, 'cupy', cupy.__version__, 'taichi', taichi.__version__, 'astropy', astropy.__version__, 'scipy', scipy.__version__)" 2>&1 | grep -v Taichi\]
  ;;
tests) sec tests
  timeout 300 python3 -m pytest -q -p no:cacheprovider -m gpu -rs -W "ignore::UserWarning:cupy" tests/test_gpu.py 2>&1 | tail -40
  echo "(tests done at t=$(( $(date +%s) - t00 )) s)"
  ;;
profile) sec profile
  timeout 240 python3 $D/profile.py 2>&1 | grep -v "^\[Taichi\]"
  ;;
kp) sec "kernel profiler"
  PROF_KP=1 timeout 150 python3 $D/profile.py 2>&1 | grep -v "^\[Taichi\]"
  ;;
bench) sec "bench measure_cuda"
  timeout 240 python3 -c "
import json
from ipc_taichi.bench import measure_cuda, render_cuda
r = measure_cuda(4096, ${BENCH_REPEATS:-10}, ${BENCH_STACK:-16})
json.dump(r, open('$OUT/cuda.json', 'w'), indent=1)
print(render_cuda(r))
" 2>&1 | grep -v "^\[Taichi\]"
  ;;
peer) sec "CuPy peer (gpu_peer.py)"
  IPC_PROJECT=$TREE timeout 150 python3 $D/gpu_peer.py 2>&1 | grep -v "^\[Taichi\]"
  ;;
ramp) sec "Roman-like ramp through the CLI"
  timeout 240 python3 $D/ramp.py 2>&1 | grep -v "^\[Taichi\]"
  ;;
esac
done
sec done
}
main 2>&1 | tee $OUT/log.txt

"""The benchmark's worker: ``python -m ipc_taichi.bench --worker SPEC`` runs
one measurement (:func:`ipc_taichi.bench.launch.work`) and prints its result
as JSON on the last line."""

import json
import sys

from .launch import work

if len(sys.argv) > 2 and sys.argv[1] == "--worker":
    print(json.dumps(work(json.loads(sys.argv[2]))))
else:
    sys.exit("usage: python -m ipc_taichi.bench --worker SPEC (run the benchmark with "
             "'ipc-taichi bench')")

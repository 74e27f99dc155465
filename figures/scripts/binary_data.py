"""Run the binary-star grid and the fitting-method comparison (paper section 4).

Writes ``data/binary_grid.json``, ``data/binary_methods.json`` (means and
spreads over sub-pixel offsets and noise realisations, see
:func:`analysis.binary.summarise`) and ``data/binary_fitter.json`` (the paper's
fit of a coupled 3 px pair under each fitter choice,
:func:`analysis.binary.fitter_choices`), and keeps per-task results in
``data/cache/binary_cache.npz`` (git-ignored) so that a re-run recomputes only what changed.
Run from ``figures/``::

    python scripts/binary_data.py [--quick] [--workers 2]
"""

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))

from analysis.binary import BinaryGrid, MethodStudy, fitter_choices, run_study, summarise  # noqa: E402
from analysis.psf import optical_psf  # noqa: E402
from ipc_taichi.fitsio import atomic_output  # noqa: E402


def write_json(path, payload):
    with atomic_output(path, overwrite=True) as tmp:
        with open(tmp, "w") as f:
            json.dump(payload, f, separators=(",", ":"))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="a small subset (bright 4:1 pair at 3 and 20 px; dim, 2 read noises)")
    parser.add_argument("--workers", type=int, default=2, help="processes (0: in this process)")
    parser.add_argument("--out", default="data", help="output folder (default: data)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)

    os.makedirs(args.out, exist_ok=True)
    cache = os.path.join(args.out, "cache", "binary_cache.npz")
    suffix = "_quick" if args.quick else ""
    for study, name in ((BinaryGrid.quick() if args.quick else BinaryGrid(), "grid"),
                        (MethodStudy.quick() if args.quick else MethodStudy(), "methods")):
        start = time.perf_counter()
        tasks, results = run_study(study, workers=args.workers, cache_path=cache,
                                   progress=not args.no_progress)
        summary = summarise(study, tasks, results)
        summary["seconds"] = round(time.perf_counter() - start, 1)
        summary["workers"] = args.workers
        path = os.path.join(args.out, f"binary_{name}{suffix}.json")
        write_json(path, summary)
        print(f"{path}: {len(tasks)} tasks in {summary['seconds']} s", file=sys.stderr)
    if not args.quick:
        start = time.perf_counter()
        rows = fitter_choices(optical_psf("jwst_f405n"))
        path = os.path.join(args.out, "binary_fitter.json")
        write_json(path, {"rows": rows, "seconds": round(time.perf_counter() - start, 1)})
        print(f"{path}: {len(rows)} fitter choices", file=sys.stderr)


if __name__ == "__main__":
    main()

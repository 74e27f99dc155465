"""``ipc-taichi bench``: time decoupling (:func:`ipc_taichi.bench.run_benchmark`)."""

import os

from ..bench import CUDA_SIZE, KINDS, SIZES, STACK_FRAMES, run_benchmark, write_results
from ..bench.pipeline import PIPELINE_SIZE
from ..errors import IPCInputError
from .commands import one_line

__all__ = ["add_parser", "run"]


def add_parser(sub):
    p = sub.add_parser(
        "bench", help=one_line("bench"),
        description="Decouple the same frames with plain NumPy and with Taichi (CPU f64, f32; "
                    "CUDA f64, f32 when a GPU is present), each configuration in a fresh "
                    "process; print a table and write bench/results.json and bench/RESULTS.md.")
    p.add_argument("--sizes", default=",".join(map(str, SIZES)),
                   help="comma-separated square frame sizes (default: "
                        f"{','.join(map(str, SIZES))})")
    p.add_argument("--kinds", default=",".join(KINDS),
                   help="frames: uniform (0..60000) and/or stars (default: both)")
    p.add_argument("--repeats", type=int, default=5,
                   help="timed runs per configuration, median reported (default 5)")
    p.add_argument("--configs", default=None,
                   help="comma-separated subset of numpy,numpy-reference,taichi-cpu-f64,"
                        "taichi-cpu-f32,taichi-cuda-f64,taichi-cuda-f32")
    p.add_argument("--cuda-size", type=int, default=CUDA_SIZE,
                   help=f"frame side of the CUDA section (device-resident, host in/out, stack, "
                        f"CuPy peer, floor; default {CUDA_SIZE}; 0 skips it; skipped without "
                        "a GPU)")
    p.add_argument("--stack", type=int, default=STACK_FRAMES,
                   help=f"frames in the CUDA stack row (default {STACK_FRAMES})")
    p.add_argument("--jwst-size", type=int, default=PIPELINE_SIZE,
                   help="frame side of the ramp on which the constant law runs beside the "
                        f"JWST pipeline's ipc step (default {PIPELINE_SIZE}; 0 skips it; "
                        "skipped without the jwst package)")
    p.add_argument("--output", default="bench", help="directory for results (default: bench)")
    p.set_defaults(run=run)


def run(args):
    try:
        sizes = tuple(int(s) for s in args.sizes.split(","))
    except ValueError:
        raise IPCInputError(f"--sizes {args.sizes!r}: expected integers like 512,2048") from None
    kinds = tuple(k.strip() for k in args.kinds.split(","))
    bad = [k for k in kinds if k not in KINDS]
    if bad or not sizes or min(sizes) < 8 or args.repeats < 1:
        raise IPCInputError(f"bench: need sizes >= 8, kinds in {KINDS}, repeats >= 1")
    if args.cuda_size < 0 or args.stack < 1 or args.jwst_size < 0 or 0 < args.jwst_size < 16:
        raise IPCInputError("bench: need --cuda-size >= 0, --stack >= 1 and --jwst-size 0 "
                            "or >= 16")
    configs = args.configs.split(",") if args.configs else None
    print(f"ipc-taichi bench: sizes {sizes}, frames {kinds}, {args.repeats} repeats",
          flush=True)
    results = run_benchmark(sizes, kinds, args.repeats, configs,
                            progress=lambda s: print(s, flush=True),
                            cuda_size=args.cuda_size, stack=args.stack,
                            pipeline_size=args.jwst_size)
    for note in results["notes"]:
        print("note:", note)
    write_results(results, args.output)
    print(f"wrote {os.path.join(args.output, 'results.json')} and "
          f"{os.path.join(args.output, 'RESULTS.md')}")
    return 1 if any("error" in r for r in results["rows"]) else 0

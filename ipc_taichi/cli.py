"""The ``ipc-taichi`` command line.

Each subcommand lives in the module that owns its concept and registers
itself through ``add_parser(subparsers)``; this module only dispatches and
turns errors into one-line messages and exit codes:

- 0: done; 1: the computation failed (e.g. divergence) or some inputs failed;
- 2: bad input or usage (file, HDU, law, argument).
"""

import argparse
import importlib
import logging
import sys
import warnings

from . import __version__
from .errors import ConvergenceWarning, DivergenceError

# modules providing subcommands, in the order --help lists them
SUBCOMMAND_MODULES = ["ipc_taichi._cli_frames", "ipc_taichi.demo", "ipc_taichi.bench",
                      "ipc_taichi.discover.cli"]


def add_model_arguments(parser, iterative=False):
    """Options shared by every command that runs the coupling model."""
    g = parser.add_argument_group("coupling model")
    g.add_argument("--law", default="donlon2018",
                   help="coupling law: donlon2018 (default; the 20000*sqrt2 form that reproduces "
                        "the paper's tables), donlon2018_printed (Eq. 7 as printed), "
                        "constant:ALPHA (fraction, e.g. constant:0.0125), "
                        "parametric:AMP_DIFF,SCALE_DIFF,AMP_LEVEL,SCALE_LEVEL,FLOOR, "
                        "table:FILE.npz (arrays 'signal', 'alpha')")
    g.add_argument("--geometry", default="nearest",
                   help="neighbour weights multiplying alpha, e.g. "
                        "'horizontal=1,vertical=0.9,diagonal=0.1,second=0.02' (default: nearest, "
                        "4 neighbours with weight 1)")
    g.add_argument("--edge", choices=("zero", "isolated"), default="zero",
                   help="beyond the frame: 'zero' = zero-signal pixels that take charge "
                        "(default, the paper's choice); 'isolated' = no coupling across the "
                        "edge, total charge conserved")
    if iterative:
        g.add_argument("--max-iter", type=int, default=20,
                       help="at most this many Jacobi iterations (default 20, as the paper)")
        g.add_argument("--tol", type=float, default=1e-5,
                       help="stop when max|S_q - S_(q-1)| <= TOL * max|S_q| (default 1e-5, "
                            "as the paper); 0 runs exactly --max-iter iterations")
    r = parser.add_argument_group("runtime")
    r.add_argument("--arch", choices=("auto", "cpu", "cuda"), default=None,
                   help="Taichi arch (default: $IPC_TAICHI_ARCH or auto = CUDA if present, "
                        "else CPU)")
    r.add_argument("--precision", choices=("f64", "f32"), default=None,
                   help="floating precision (default: $IPC_TAICHI_PRECISION or f64)")


def build_parser():
    parser = argparse.ArgumentParser(
        prog="ipc-taichi",
        description="Simulate and remove signal-dependent interpixel capacitance (IPC) in "
                    "hybrid IR detector frames (Donlon, Ninkov & Baum, JATIS 2018), with "
                    "Taichi kernels on the CPU or a CUDA GPU.",
        epilog="Run 'ipc-taichi COMMAND --help' for each command. Pixel convention: "
               "image[y, x]; FITS NAXIS1 = x.")
    parser.add_argument("--version", action="version", version=f"ipc_taichi {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).add_parser(sub)
    return parser


def main(argv=None):
    logging.basicConfig(format="ipc-taichi: %(message)s", level=logging.WARNING)
    parser = build_parser()
    args = parser.parse_args(argv)

    def show_warning(message, category, filename, lineno, file=None, line=None):
        kind = "warning" if issubclass(category, ConvergenceWarning) else category.__name__
        print(f"ipc-taichi: {kind}: {message}", file=sys.stderr)

    warnings.showwarning = show_warning
    try:
        return int(args.run(args) or 0)
    except DivergenceError as exc:
        print(f"ipc-taichi: error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, OSError, RuntimeError) as exc:
        print(f"ipc-taichi: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("ipc-taichi: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

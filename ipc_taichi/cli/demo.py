"""``ipc-taichi demo``: the main job (:func:`ipc_taichi.demo.run_demo`)."""

from ..demo import run_demo
from .commands import one_line
from .options import add_runtime_arguments

__all__ = ["add_parser", "run"]


def add_parser(sub):
    p = sub.add_parser("demo", help=one_line("demo"),
                       description="The paper's worked example (section 2.3) coupled and "
                                   "decoupled, then a uniform random frame, timed.")
    p.add_argument("--size", type=int, default=2048, help="side of the random frame (default 2048)")
    add_runtime_arguments(p)
    p.set_defaults(run=run)


def run(args):
    return run_demo(args.size, args.arch, args.precision)

"""The options shared by the subcommands, defined once.

``--law/--geometry/--edge`` or ``--model FILE`` (the coupling model), ``--max-iter/--tol`` (the
stopping rule), ``--arch/--precision`` (the Taichi runtime) and ``--quiet``.
:func:`model_from_args` turns the model options into one
:class:`ipc_taichi.model.CouplingModel`, resolved (and checked) once, before
any work.
"""

from .. import iteration
from ..errors import IPCInputError
from ..model import DEFAULT_LAW, EDGES, CouplingModel

__all__ = ["add_model_arguments", "add_iteration_arguments", "add_runtime_arguments",
           "add_quiet_argument", "model_from_args", "model_is_explicit", "DEFAULT_LAW"]

def add_model_arguments(parser):
    """``--law``, ``--geometry``, ``--edge`` or ``--model FILE``: the coupling model."""
    g = parser.add_argument_group("coupling model")
    g.add_argument("--model", metavar="FILE", default=None,
                   help="a coupling-model file (JSON, as written by 'ipc-taichi calibrate'): "
                        "law, geometry and edge measured for this detector; replaces "
                        "--law/--geometry/--edge")
    g.add_argument("--law", default=None,
                   help="coupling law, in electrons of collected charge: donlon2018 (default; "
                        "the 20000*sqrt2 form that reproduces the paper's tables), "
                        "donlon2018_printed (Eq. 7 as printed), constant:ALPHA (fraction, "
                        "e.g. constant:0.0125), "
                        "parametric:AMP_DIFF,SCALE_DIFF,AMP_LEVEL,SCALE_LEVEL,FLOOR, "
                        "table:FILE.npz (arrays 'signal', 'alpha')")
    g.add_argument("--geometry", default=None,
                   help="neighbour weights multiplying alpha, e.g. "
                        "'horizontal=1,vertical=0.9,diagonal=0.1,second=0.02'; terms not named "
                        "are zero (default: nearest, "
                        "4 neighbours with weight 1)")
    g.add_argument("--edge", choices=EDGES, default=None,
                   help="beyond the frame: 'zero' = zero-signal pixels that take charge "
                        "(default, the paper's choice); 'isolated' = no coupling across the "
                        "edge, total charge conserved")
    return g


def add_iteration_arguments(parser):
    """``--max-iter``, ``--tol``: the paper's stopping rule."""
    g = parser.add_argument_group("stopping rule")
    g.add_argument("--max-iter", type=int, default=iteration.MAX_ITER,
                   help=f"at most this many Jacobi iterations (default {iteration.MAX_ITER}, "
                        "as the paper)")
    g.add_argument("--tol", type=float, default=iteration.TOL,
                   help=f"stop when max|S_q - S_(q-1)| <= TOL * max|S_q| (default "
                        f"{iteration.TOL:g}, as the paper); 0 runs exactly --max-iter iterations")
    return g


def add_runtime_arguments(parser, products=False):
    """``--arch``, ``--precision``: the Taichi runtime (``products``: a command
    on product files, whose precision may follow the file: ``auto``)."""
    r = parser.add_argument_group("runtime")
    r.add_argument("--arch", choices=("auto", "cpu", "cuda"), default=None,
                   help="Taichi arch (default: $IPC_TAICHI_ARCH or auto = CUDA if present, "
                        "else CPU)")
    if products:
        r.add_argument("--precision", choices=("auto", "f64", "f32"), default=None,
                       help="floating precision (default: $IPC_TAICHI_PRECISION, else auto: "
                            "the file's own, f32 for float32 science data (exact to within "
                            "about one float32 step of the data, see docs/products.md), "
                            "else f64)")
    else:
        r.add_argument("--precision", choices=("f64", "f32"), default=None,
                       help="floating precision (default: $IPC_TAICHI_PRECISION or f64)")
    return r


def add_quiet_argument(parser, what="progress bars and notices"):
    """``--quiet``."""
    parser.add_argument("--quiet", action="store_true", help=f"no {what}")


def model_is_explicit(args):
    """Whether the user chose the model (``--model`` or ``--law``), rather than
    getting the paper's law by default."""
    return args.model is not None or args.law is not None


def model_from_args(args):
    """The :class:`CouplingModel` of ``--model FILE`` or ``--law/--geometry/--edge``
    (default: the paper's law, nearest neighbours, edge ``zero``). Bad values,
    or ``--model`` together with any of the others, raise
    :class:`ipc_taichi.IPCInputError` and friends: usage errors."""
    if args.model is not None:
        given = [f"--{name}" for name in ("law", "geometry", "edge")
                 if getattr(args, name) is not None]
        if given:
            raise IPCInputError(f"--model {args.model} holds the law, geometry and edge; "
                                f"do not also give {', '.join(given)}")
    return CouplingModel.resolve(args.law, args.geometry, args.edge, model=args.model)

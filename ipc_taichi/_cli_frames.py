"""``ipc-taichi couple`` and ``ipc-taichi decouple``: one FITS image in, one out."""

import datetime

import numpy as np

from . import __version__
from .coupling import couple
from .decoupling import decouple
from .fitsio import check_output_path, parse_hdu, read_image, write_image
from .geometry import Geometry
from .laws import get_law


def add_parser(sub):
    from .cli import add_model_arguments

    for name, helptext in (
        ("couple", "apply IPC to a signal image (forward model): IN -> OUT"),
        ("decouple", "remove IPC from a measured image (iterative Jacobi inversion): IN -> OUT"),
    ):
        p = sub.add_parser(
            name, help=helptext, description=helptext + ". The output keeps the input HDU's "
            "header (minus scaling keywords) and records what was done in IPC* keywords and "
            "HISTORY. A 3-D cube is processed frame by frame. NaN pixels stay NaN and do not "
            "couple. The output is written atomically and never overwritten without --overwrite.")
        p.add_argument("input", metavar="IN.fits")
        p.add_argument("output", metavar="OUT.fits")
        p.add_argument("--hdu", default=None,
                       help="input HDU: index, EXTNAME or EXTNAME,EXTVER (default: first HDU "
                            "with image data)")
        p.add_argument("--overwrite", action="store_true", help="replace OUT.fits if it exists")
        add_model_arguments(p, iterative=(name == "decouple"))
        p.set_defaults(run=run_couple if name == "couple" else run_decouple)


def _model_keywords(args, law, geometry, info_arch, info_precision):
    return {
        "IPCVER": (__version__, "ipc_taichi version"),
        "IPCLAW": (law.name[:68], "IPC coupling law alpha(S,N)"),
        "IPCGEOM": (geometry.describe()[:68], "IPC geometry (dy,dx)=weight"),
        "IPCEDGE": (args.edge, "IPC edge rule"),
        "IPCARCH": (info_arch, "Taichi arch used"),
        "IPCPREC": (info_precision, "floating precision"),
    }


def _now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _prepare(args):
    check_output_path(args.output, args.overwrite)  # fail before computing
    data, header, label = read_image(args.input, parse_hdu(args.hdu))
    law = get_law(args.law)
    geometry = Geometry.parse(args.geometry)
    return data, header, label, law, geometry


def run_couple(args):
    from . import runtime

    data, header, label, law, geometry = _prepare(args)
    out = couple(data, law=law, geometry=geometry, edge=args.edge, arch=args.arch,
                 precision=args.precision)
    rt = runtime.current()
    keywords = _model_keywords(args, law, geometry, rt.arch, rt.precision)
    keywords["IPCOP"] = ("couple", "IPC operation applied")
    write_image(args.output, out, header, args.overwrite, keywords,
                [f"{_now()} ipc_taichi {__version__} couple {label}: law {law.name}, "
                 f"edge {args.edge}, geometry {geometry.describe()}"])
    return 0


def run_decouple(args):
    from . import runtime

    data, header, label, law, geometry = _prepare(args)
    out, infos = decouple(data, law=law, geometry=geometry, edge=args.edge,
                          max_iter=args.max_iter, tol=args.tol, arch=args.arch,
                          precision=args.precision, full_output=True)
    infos = infos if isinstance(infos, list) else [infos]
    rt = runtime.current()
    keywords = _model_keywords(args, law, geometry, rt.arch, rt.precision)
    keywords.update({
        "IPCOP": ("decouple", "IPC operation applied"),
        "IPCITER": (max(i.iterations for i in infos), "Jacobi iterations (max over frames)"),
        "IPCCONV": (all(i.converged for i in infos), "stopping rule met (all frames)"),
        "IPCTOL": (args.tol, "stop: max|dS| <= TOL*max|S|"),
        "IPCMAXIT": (args.max_iter, "iteration limit"),
    })
    history = [f"{_now()} ipc_taichi {__version__} decouple {label}: law {law.name}, "
               f"edge {args.edge}, geometry {geometry.describe()}"]
    for k, i in enumerate(infos):
        prefix = f"frame {k}: " if len(infos) > 1 else ""
        history.append(f"{prefix}{i.iterations} iterations, "
                       f"{'converged' if i.converged else 'NOT converged'}, "
                       f"last max|dS| {i.max_delta[-1]:.3g}")
    write_image(args.output, out, header, args.overwrite, keywords, history)
    return 0

"""``ipc-taichi couple`` and ``ipc-taichi decouple``: FITS images in and out.

``couple IN OUT`` and ``decouple IN OUT``: one file in, one out.

``decouple IN1 [IN2 ...] -o OUTDIR``: many files. Each output is
``OUTDIR/<input name without .fits>_decoupled.fits`` (``--suffix``). With more
than one file the work runs on Dask: a local cluster of single-threaded worker
processes (``--workers``), or the scheduler at ``--scheduler ADDRESS``. A file
that fails (unreadable, bad HDU, divergence, its worker died) is reported in
one line and leaves nothing at its output path; the others complete; the exit
code is 1 when any failed. ``--tile N`` decouples each file tile by tile
through memory-mapped FITS sections (frames larger than memory; exact, see
:mod:`ipc_taichi.tiling`). A progress bar is shown on a terminal unless
``--quiet``.
"""

import datetime
import os
import sys

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
        if name == "couple":
            p.add_argument("input", metavar="IN.fits")
            p.add_argument("output", metavar="OUT.fits")
        else:
            p.add_argument("paths", nargs="+", metavar="IN.fits",
                           help="IN.fits OUT.fits, or with -o: one or more inputs")
            m = p.add_argument_group("many files, large frames")
            m.add_argument("-o", "--output-dir", default=None, metavar="OUTDIR",
                           help="decouple every IN.fits into OUTDIR/<name>SUFFIX.fits")
            m.add_argument("--suffix", default="_decoupled",
                           help="added to each input's name in OUTDIR (default _decoupled)")
            m.add_argument("--scheduler", default=None, metavar="ADDRESS",
                           help="Dask scheduler to run on (default: a local cluster)")
            m.add_argument("--workers", type=int, default=None,
                           help="worker processes of the local cluster (default: "
                                "min(files, CPU cores))")
            m.add_argument("--tile", type=int, default=None, metavar="N",
                           help="decouple tile by tile (N x N cores plus a halo) through "
                                "memory-mapped FITS sections; exact")
            m.add_argument("--quiet", action="store_true", help="no progress bar")
        p.add_argument("--hdu", default=None,
                       help="input HDU: index, EXTNAME or EXTNAME,EXTVER (default: first HDU "
                            "with image data)")
        p.add_argument("--overwrite", action="store_true", help="replace OUT.fits if it exists")
        add_model_arguments(p, iterative=(name == "decouple"))
        p.set_defaults(run=run_couple if name == "couple" else run_decouple)


def _model_keywords(edge, law, geometry, info_arch, info_precision):
    return {
        "IPCVER": (__version__, "ipc_taichi version"),
        "IPCLAW": (law.name[:68], "IPC coupling law alpha(S,N)"),
        "IPCGEOM": (geometry.describe()[:68], "IPC geometry (dy,dx)=weight"),
        "IPCEDGE": (edge, "IPC edge rule"),
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
    keywords = _model_keywords(args.edge, law, geometry, rt.arch, rt.precision)
    keywords["IPCOP"] = ("couple", "IPC operation applied")
    write_image(args.output, out, header, args.overwrite, keywords,
                [f"{_now()} ipc_taichi {__version__} couple {label}: law {law.name}, "
                 f"edge {args.edge}, geometry {geometry.describe()}"])
    return 0


def _decouple_records(law, geometry, edge, tol, max_iter, label, arch, precision, infos):
    """Header keywords and HISTORY lines of a decoupled output."""
    keywords = _model_keywords(edge, law, geometry, arch, precision)
    keywords.update({
        "IPCOP": ("decouple", "IPC operation applied"),
        "IPCITER": (max(i.iterations for i in infos), "Jacobi iterations (max over frames)"),
        "IPCCONV": (all(i.converged for i in infos), "stopping rule met (all frames)"),
        "IPCTOL": (tol, "stop: max|dS| <= TOL*max|S|"),
        "IPCMAXIT": (max_iter, "iteration limit"),
    })
    history = [f"{_now()} ipc_taichi {__version__} decouple {label}: law {law.name}, "
               f"edge {edge}, geometry {geometry.describe()}"]
    for k, i in enumerate(infos):
        prefix = f"frame {k}: " if len(infos) > 1 else ""
        history.append(f"{prefix}{i.iterations} iterations, "
                       f"{'converged' if i.converged else 'NOT converged'}, "
                       f"last max|dS| {i.max_delta[-1]:.3g}")
    return keywords, history


def decouple_file(input_path, output_path, hdu=None, overwrite=False, law="donlon2018",
                  geometry="nearest", edge="zero", max_iter=20, tol=1e-5, arch=None,
                  precision=None, tile=None, progress=False):
    """Decouple one FITS image or cube into ``output_path`` (atomically).

    Returns ``{"iterations": max over frames, "converged": all frames}``.
    With ``tile``, the file is processed tile by tile through memory-mapped
    sections (:func:`ipc_taichi.tiling.decouple_fits_tiled`).
    """
    from . import runtime

    check_output_path(output_path, overwrite)  # fail before computing
    law = get_law(law)
    geometry = geometry if isinstance(geometry, Geometry) else Geometry.parse(geometry)
    if tile:
        from astropy.io import fits

        from .tiling import decouple_fits_tiled

        infos = decouple_fits_tiled(input_path, output_path, hdu=parse_hdu(hdu), tile=tile,
                                    overwrite=overwrite, law=law, geometry=geometry, edge=edge,
                                    max_iter=max_iter, tol=tol, arch=arch, precision=precision,
                                    progress=progress)
        rt = runtime.current()
        keywords, history = _decouple_records(law, geometry, edge, tol, max_iter,
                                              f"{input_path} (tiles {tile})", rt.arch,
                                              rt.precision, infos)
        with fits.open(output_path, mode="update") as hdul:
            for key, value in keywords.items():
                hdul[0].header[key] = value
            for line in history:
                hdul[0].header.add_history(line)
    else:
        data, header, label = read_image(input_path, parse_hdu(hdu))
        out, infos = decouple(data, law=law, geometry=geometry, edge=edge, max_iter=max_iter,
                              tol=tol, arch=arch, precision=precision, full_output=True)
        infos = infos if isinstance(infos, list) else [infos]
        rt = runtime.current()
        keywords, history = _decouple_records(law, geometry, edge, tol, max_iter, label,
                                              rt.arch, rt.precision, infos)
        write_image(output_path, out, header, overwrite, keywords, history)
    return {"iterations": max(i.iterations for i in infos),
            "converged": all(i.converged for i in infos)}


def _options(args):
    return dict(hdu=args.hdu, overwrite=args.overwrite, law=args.law, geometry=args.geometry,
                edge=args.edge, max_iter=args.max_iter, tol=args.tol, arch=args.arch,
                precision=args.precision, tile=args.tile)


def output_name(input_path, output_dir, suffix):
    """``OUTDIR/<input name without .fits/.fit/.fts>SUFFIX.fits``."""
    name = os.path.basename(input_path)
    for ext in (".gz", ".fits", ".fit", ".fts"):
        if name.lower().endswith(ext):
            name = name[:-len(ext)]
    return os.path.join(output_dir, name + suffix + ".fits")


def run_decouple(args):
    from .errors import IPCInputError

    from ._engine import resolve_model

    # bad model options are usage errors (exit 2), found before any work
    resolve_model(args.law, Geometry.parse(args.geometry), args.edge)
    if args.output_dir is None:
        if len(args.paths) != 2:
            raise IPCInputError("decouple: give IN.fits OUT.fits, or several inputs with "
                                "-o OUTDIR")
        decouple_file(args.paths[0], args.paths[1], progress=not args.quiet, **_options(args))
        return 0
    if not os.path.isdir(args.output_dir):
        raise IPCInputError(f"{args.output_dir}: output directory does not exist")
    pairs = [(p, output_name(p, args.output_dir, args.suffix)) for p in args.paths]
    seen = {}
    for src, dst in pairs:
        if dst in seen:
            raise IPCInputError(f"{src} and {seen[dst]} would both be written to {dst}")
        seen[dst] = src
    return _run_many(pairs, args)


def _run_many(pairs, args):
    """Decouple many files; one line per failure; exit code 1 if any failed."""
    show = not args.quiet and sys.stderr.isatty()
    bar = None
    if show:
        from tqdm import tqdm

        bar = tqdm(total=len(pairs), unit="file", desc="decouple", file=sys.stderr)

    def report(res):
        if not res["ok"]:
            print(f"ipc-taichi: error: {res['error']}", file=sys.stderr, flush=True)
        if bar is not None:
            bar.update(1)

    options = _options(args)
    if len(pairs) == 1 and not args.scheduler:
        results = []
        for src, dst in pairs:  # no cluster for a single file
            res = {"input": src, "output": dst}
            try:
                res.update(ok=True, **decouple_file(src, dst, **options))
            except Exception as exc:
                res.update(ok=False, error=str(exc).splitlines()[0] if str(exc) else
                           f"{src}: {type(exc).__name__}")
            report(res)
            results.append(res)
    else:
        from .cluster import close_client, decouple_files, local_client

        workers = args.workers or min(len(pairs), os.cpu_count() or 1)
        client = local_client(args.scheduler, workers)
        try:
            results = decouple_files(pairs, options, client, progress=report)
        finally:
            close_client(client)
    if bar is not None:
        bar.close()
    failed = [r for r in results if not r["ok"]]
    if failed:
        print(f"ipc-taichi: {len(failed)} of {len(results)} files failed", file=sys.stderr)
        return 1
    if not args.quiet:
        print(f"decoupled {len(results)} files into {args.output_dir}", file=sys.stderr)
    return 0

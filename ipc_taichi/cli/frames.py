"""``ipc-taichi couple`` and ``ipc-taichi decouple``: FITS products in and out.

``couple IN OUT`` and ``decouple IN OUT``: one product in, the same product out
(:func:`ipc_taichi.products.process_fits`: every HDU and keyword kept, the
science array changed, DQ/reference pixels/units honoured).

``decouple IN1 [IN2 ...] -o OUTDIR``: many files. Each output is
``OUTDIR/<input name without .fits>_decoupled.fits`` (``--suffix``). With more
than one file the work runs on Dask: a local cluster of single-threaded worker
processes (``--workers``), or the scheduler at ``--scheduler ADDRESS``. A file
that fails is reported in one line and leaves nothing at its output path; the
others complete; the exit code is 1 when any failed. ``--tile N`` decouples
tile by tile through memory maps (frames larger than memory; exact).

The overwrite rule: with two positional names ``IN OUT``, ``--overwrite``
replaces OUT only if OUT is a file this tool wrote (its primary header has
``IPCOP``), so that ``ipc-taichi decouple *.fits --overwrite`` matching exactly
two inputs cannot replace the second input by the decoupled first. To replace
any other file, name it as the output explicitly: ``--output OUT --overwrite``.
"""

import contextlib
import glob
import os
import sys
import time

from ..errors import IPCInputError
from ..hpc import available_cores
from ..products import ProductOptions, couple_file, decouple_file, written_by_ipc_taichi
from ..products.missions import DEFAULT_DQ
from ..products.options import product_precision
from ..progress import terminal_progress
from .commands import one_line
from .many import add_cluster_arguments, many_paths, report_skipped_only, skip_one, split_done
from .options import (
    add_iteration_arguments,
    add_model_arguments,
    add_quiet_argument,
    add_runtime_arguments,
    model_from_args,
    model_is_explicit,
)

__all__ = ["add_parsers", "run_couple", "run_decouple", "output_name", "summary_line"]

EXIT_FAILED, EXIT_UNCONVERGED = 1, 3


def _add_product_arguments(p):
    g = p.add_argument_group("products (see docs/products.md)")
    g.add_argument("--hdu", default=None,
                   help="science HDU: index, EXTNAME or EXTNAME,EXTVER (default: SCI, else the "
                        "first HDU with image data); DQ/PIXELDQ/GROUPDQ are refused")
    g.add_argument("--dq-bits", default=DEFAULT_DQ, metavar="FLAGS",
                   help="DQ/PIXELDQ/GROUPDQ flags of pixels left out (they keep their values "
                        "and do not couple): names (the file's DQ_DEF first, then its "
                        "mission's: JWST, HST, Roman) or integers, comma-separated (default "
                        f"{DEFAULT_DQ}; 0 = none)")
    g.add_argument("--saturation", type=float, default=None, metavar="LEVEL",
                   help="pixels at or above LEVEL (data units) are left out like flagged ones "
                        "(their charge is unknown)")
    g.add_argument("--keep-unphysical", action="store_true",
                   help="keep unflagged pixels no detector can hold (a charge outside "
                        "-2e4..1e6 e-) in the correction, as before: the law spreads them to "
                        "their neighbours (default: masked like flagged pixels, counted in "
                        "IPCNBAD; infinite values are always masked)")
    g.add_argument("--keep-noise", action="store_true",
                   help="leave ERR and VAR_POISSON/VAR_RNOISE/VAR_FLAT as they came (default, "
                        "decouple: propagated through the linearised decoupler, IPCNOISE)")
    g.add_argument("--refpix", type=int, default=None, metavar="N",
                   help="reference border of N pixels, never changed, zero-signal neighbours "
                        "(default: the REFERENCE_PIXEL flags, else the observatory's: 4 for a "
                        "JWST near-IR full frame or a subarray at the detector edge, 5 for a "
                        "WFC3/IR _ima, else 0)")
    g.add_argument("--gain", default=None, metavar="E_PER_DN",
                   help="gain in e-/DN, a number or a gain image FITS file (default: the GAIN "
                        "keyword); needed for data in DN or DN/s")
    g.add_argument("--exptime", type=float, default=None, metavar="SECONDS",
                   help="integration time of rate data (default: the science HDU's SAMPTIME, "
                        "else EFFINTTM, else EXPTIME; science header first, then primary)")
    g.add_argument("--pedestal", default="auto", metavar="auto|none|E|FILE",
                   help="charge on the node before the first read, electrons: auto (default: "
                        "the zeroth read of a multi-read product, e.g. a WFC3/IR _ima), none, "
                        "a number, or an image file; the law sees data + pedestal")
    g.add_argument("--coadds", type=int, default=None, metavar="N",
                   help="exposures summed in each frame (default: NCOADDS or NDIT, else 1); "
                        "the law sees the charge of one")
    g.add_argument("--bunit", default=None,
                   help="units of the data, overriding BUNIT: electron, DN, DN/s, electron/s "
                        "(no BUNIT: DN when a gain is known, --gain or GAIN, else electrons)")
    g.add_argument("--output-dtype", choices=("same", "float32", "float64"), default="same",
                   help="science dtype out (default same: float stays float, integer becomes "
                        "float64)")


def add_parsers(sub):
    """Register ``couple`` and ``decouple``."""
    common = ("FITS or Roman ASDF. The output is the input product with its science array "
              "changed: every other HDU and header keyword is kept; IPC* keywords and "
              "HISTORY record what was done (decouple also sets S_IPC = 'COMPLETE'). The law "
              "is in electrons: data in DN or DN/s are converted with the gain (and "
              "integration time) and back. DQ-flagged pixels keep their values and do not "
              "couple; reference pixels are never changed. Stacks and ramps are processed "
              "frame by frame. NaN pixels stay NaN. The output is written atomically and "
              "never overwritten without --overwrite. See docs/products.md.")
    for name in ("couple", "decouple"):
        helptext = one_line(name)
        p = sub.add_parser(name, help=helptext, description=f"{helptext}. {common}")
        p.add_argument("paths", nargs="*" if name == "decouple" else "+", metavar="IN.fits",
                       help="IN.fits OUT.fits, IN.fits --output OUT.fits"
                       + (", or with -o: one or more inputs" if name == "decouple" else ""))
        p.add_argument("--output", default=None, metavar="OUT.fits",
                       help="the output, named explicitly: with --overwrite it replaces any "
                            "file (a second positional OUT is replaced only if ipc-taichi "
                            "wrote it)")
        p.add_argument("--overwrite", action="store_true", help="replace OUT.fits if it exists")
        if name == "decouple":
            m = p.add_argument_group("many files, large frames")
            m.add_argument("-o", "--output-dir", default=None, metavar="OUTDIR",
                           help="decouple every IN.fits into OUTDIR/<name>SUFFIX.fits")
            m.add_argument("--suffix", default="_decoupled",
                           help="added to each input's name in OUTDIR (default _decoupled)")
            m.add_argument("--scheduler", default=None, metavar="ADDRESS",
                           help="Dask scheduler to run on (default: a local cluster)")
            add_cluster_arguments(m)
            m.add_argument("--gpus", default=None, metavar="all|ID,ID",
                           help="run on a local cluster of one single-threaded worker per GPU, "
                                "each seeing only its own (CUDA_VISIBLE_DEVICES): 'all' or a "
                                "list of GPU ids; see docs/performance.md for clusters")
            m.add_argument("--workers", type=int, default=None,
                           help="worker processes of the local cluster, >= 1 (default: "
                                "min(files, CPUs: $SLURM_CPUS_PER_TASK in a Slurm job, "
                                "else this process's))")
            m.add_argument("--tile", type=int, default=None, metavar="N",
                           help="decouple tile by tile (N x N cores plus a halo) through "
                                "memory maps; exact")
        _add_product_arguments(p)
        add_model_arguments(p)
        if name == "decouple":
            add_iteration_arguments(p)
        add_runtime_arguments(p, products=True)
        add_quiet_argument(p, "summary line, progress bar or CUDA notice (warnings and errors "
                              "are still said)")
        p.set_defaults(run=run_couple if name == "couple" else run_decouple)


def _product_options(args):
    """The :class:`ProductOptions` of the command line."""
    dtype = None if args.output_dtype == "same" else args.output_dtype
    options = dict(hdu=args.hdu, overwrite=args.overwrite, arch=args.arch,
                   precision=product_precision(args.precision), dq_bits=args.dq_bits,
                   refpix=args.refpix,
                   gain=args.gain, exptime=args.exptime, bunit=args.bunit, output_dtype=dtype,
                   pedestal=args.pedestal, coadds=args.coadds, saturation=args.saturation,
                   unphysical="keep" if args.keep_unphysical else "mask",
                   noise="keep" if args.keep_noise else "propagate",
                   model_chosen=model_is_explicit(args),
                   # the edge asked for (None: none); the product's frame decides what
                   # it gets (products.plan.edge_of)
                   edge=args.edge)
    if hasattr(args, "max_iter"):
        options.update(max_iter=args.max_iter, tol=args.tol, tile=args.tile)
    return ProductOptions.from_kwargs(**options)


def _single_pair(args, command):
    """``(IN, OUT)`` of the one-file forms; applies the overwrite rule."""
    if args.output is not None:
        if len(args.paths) != 1:
            raise IPCInputError(f"{command}: with --output give exactly one input")
        return args.paths[0], args.output
    if len(args.paths) != 2:
        more = ", or several inputs with -o OUTDIR" if command == "decouple" else ""
        raise IPCInputError(f"{command}: give IN.fits OUT.fits, IN.fits --output OUT.fits{more}")
    src, dst = args.paths
    if args.overwrite and os.path.exists(dst) and not written_by_ipc_taichi(dst):
        raise IPCInputError(
            f"{dst}: exists and was not written by ipc-taichi, so it may be an input; "
            f"to replace it, name it explicitly: --output {dst} --overwrite")
    return src, dst


def _report(summary, src):
    """One warning line per frame that missed the stopping rule; the exit code."""
    if summary.get("converged", True) is not False:
        return 0
    print(f"ipc-taichi: warning: {src}: the stopping rule was not met "
          f"({summary['iterations']} iterations); written with IPCCONV = F", file=sys.stderr)
    return EXIT_UNCONVERGED


def summary_line(summary, src, dst, operation, model_file=None):
    """The one line said on stderr for each file done: the law (or model
    file), iterations, convergence, HDUs changed, seconds."""
    done = "decoupled" if operation == "decouple" else "coupled"
    how = (f"model {os.path.basename(str(model_file))} (law {summary['law']})"
           if model_file is not None else f"law {summary['law']}")
    parts = [f"{how}, edge {summary['edge']}"]
    if operation == "decouple":
        converged = summary.get("converged")
        state = ("fixed count (--tol 0)" if converged is None else
                 "converged" if converged else "NOT converged")
        parts.append(f"{summary['iterations']} iterations, {state}")
    hdus = summary["hdus"]
    count = hdus if isinstance(hdus, int) else len(hdus)
    frames = summary.get("frames", 1)
    parts.append(f"{count} HDU{'s' if count != 1 else ''} changed"
                 + (f" ({frames} frames)" if frames > 1 else ""))
    bad = summary.get("masked_unphysical", 0)
    if bad:
        parts.append(f"{bad} unphysical pixel{'s' if bad != 1 else ''} masked")
    parts.append(f"{summary['seconds']:.1f} s")
    return f"ipc-taichi: {done} {src} -> {dst}: {', '.join(parts)}"


def _say(summary, src, dst, operation, args, write=None):
    if args.quiet:
        return
    line = summary_line(summary, src, dst, operation, args.model)
    (write or (lambda text: print(text, file=sys.stderr, flush=True)))(line)


def _progress(args, operation):
    """The bar of one product's frames or iterations on a terminal (a context
    giving None off a terminal or with --quiet)."""
    return terminal_progress(operation, args.quiet) or contextlib.nullcontext()


def run_couple(args):
    model = model_from_args(args)
    src, dst = _single_pair(args, "couple")
    with _progress(args, "couple") as bar:
        summary = couple_file(src, dst, model=model,
                              options=_product_options(args).replace(progress=bar))
    _say(summary, src, dst, "couple", args)
    return 0


def output_name(input_path, output_dir, suffix):
    """``OUTDIR/<input name without .fits/.fit/.fts>SUFFIX.fits`` (``.asdf``
    for an ASDF input; a compressed input gives an uncompressed output)."""
    name = os.path.basename(input_path)
    ext = ".fits"
    for packed in (".gz", ".bz2", ".zip"):  # read as astropy reads them; written plain
        if name.lower().endswith(packed):
            name = name[:-len(packed)]
    for known in (".fits", ".fit", ".fts", ".asdf"):
        if name.lower().endswith(known):
            name = name[:-len(known)]
            ext = ".asdf" if known == ".asdf" else ".fits"
    return os.path.join(output_dir, name + suffix + ext)


def run_decouple(args):
    model = model_from_args(args)  # bad model options are usage errors, found before any work
    args.paths = many_paths(args)
    if args.workers is not None and args.workers < 1:
        raise IPCInputError(f"--workers {args.workers}: needs at least 1 worker")
    if args.tile is not None and args.tile < 1:
        raise IPCInputError(f"--tile {args.tile}: needs N >= 1")
    if args.output_dir is None:
        src, dst = _single_pair(args, "decouple")
        if skip_one(args, src, dst):
            return 0
        with _progress(args, "decouple") as bar:
            summary = decouple_file(src, dst, model=model,
                                    options=_product_options(args).replace(progress=bar))
        _say(summary, src, dst, "decouple", args)
        return _report(summary, src)
    if args.output is not None:
        raise IPCInputError("decouple: give either --output OUT.fits or -o OUTDIR")
    if os.path.exists(args.output_dir) and not os.path.isdir(args.output_dir):
        raise IPCInputError(f"{args.output_dir}: exists and is not a directory")
    try:
        os.makedirs(args.output_dir, exist_ok=True)
    except OSError as exc:
        raise IPCInputError(f"{args.output_dir}: cannot create the output directory "
                            f"({exc.strerror})") from None
    pairs = [(p, output_name(p, args.output_dir, args.suffix)) for p in args.paths]
    pairs, skipped = split_done(pairs, args)
    seen = {}
    for src, dst in pairs:
        if dst in seen:
            raise IPCInputError(f"{src} and {seen[dst]} would both be written to {dst}")
        if os.path.exists(src) and os.path.exists(dst) and os.path.samefile(src, dst):
            raise IPCInputError(f"{src}: would be overwritten by its own output")
        seen[dst] = src
    if not pairs:
        return report_skipped_only(skipped, args)
    return _run_many(pairs, args, model, skipped)


def _absolute_files(options):
    """``options`` with the files they name (a gain or pedestal image) made
    absolute: a worker's working directory is not this process's."""
    changes = {}
    for name in ("gain", "pedestal"):
        value = getattr(options, name)
        if isinstance(value, (str, os.PathLike)) and os.path.exists(value):
            changes[name] = os.path.abspath(value)
    return options.replace(**changes) if changes else options


def _remove_temporaries(pairs, since):
    """Temporary files a stopped run's workers left beside the outputs."""
    for _, dst in pairs:
        parent = os.path.dirname(os.path.abspath(dst))
        for path in glob.glob(os.path.join(parent, ".tmp-*" + os.path.basename(dst))):
            try:
                if os.path.getmtime(path) >= since:
                    os.unlink(path)
            except OSError:
                pass


def _run_many(pairs, args, model, skipped=0):
    """Decouple many files; one line per failure; exit code 1 if any failed."""
    show = not args.quiet and sys.stderr.isatty()
    bar = None
    if show:
        from tqdm import tqdm

        bar = tqdm(total=len(pairs), unit="file", desc="decouple", file=sys.stderr)

    def report(res):
        if not res["ok"]:
            print(f"ipc-taichi: error: {res['error']}", file=sys.stderr, flush=True)
        else:
            _say(res, res["input"], res["output"], "decouple", args,
                 write=None if bar is None else bar.write)
        if bar is not None:
            bar.update(1)

    options = {"model": model, "options": _absolute_files(_product_options(args))}
    since = time.time() - 1
    try:
        if len(pairs) == 1 and not (args.scheduler or args.scheduler_file):
            results = []
            for src, dst in pairs:  # no cluster for a single file
                res = {"input": src, "output": dst}
                try:
                    res.update(ok=True, **decouple_file(src, dst, **options))
                except (ValueError, OSError, RuntimeError) as exc:
                    text = str(exc).splitlines()[0] if str(exc) else ""
                    res.update(ok=False, error=text if text.startswith(str(src)) else
                               f"{src}: {text or type(exc).__name__}")
                report(res)
                results.append(res)
        else:
            from ..cluster import close_client, decouple_files, local_client

            workers = args.workers or min(len(pairs), available_cores())
            gpus = None if args.gpus is None else (
                [] if args.gpus.strip() == "all" else
                [g.strip() for g in args.gpus.split(",") if g.strip()])
            # absolute: the workers do not share this process's working directory; the
            # lines said name the files as they were given
            sent = [(os.path.abspath(src), os.path.abspath(dst)) for src, dst in pairs]
            given = dict(zip(sent, pairs))

            def as_given(res):
                src, dst = given.get((res["input"], res["output"]), (res["input"], res["output"]))
                if not res["ok"] and res["error"].startswith(res["input"]):
                    res["error"] = src + res["error"][len(res["input"]):]
                res.update(input=src, output=dst)
                report(res)

            client = local_client(args.scheduler, workers, gpus=gpus,
                                  scheduler_file=args.scheduler_file)
            try:
                results = decouple_files(sent, options, client, progress=as_given)
            finally:
                close_client(client)
    except KeyboardInterrupt:
        _remove_temporaries(pairs, since)
        raise
    finally:
        if bar is not None:
            bar.close()
    failed = [r for r in results if not r["ok"]]
    if failed:
        print(f"ipc-taichi: {len(failed)} of {len(results)} files failed", file=sys.stderr)
        return EXIT_FAILED
    code = 0
    for r in results:
        code = max(code, _report(r, r["input"]))
    if not args.quiet:
        print(f"decoupled {len(results)} files into {args.output_dir}"
              + (f" ({skipped} skipped: already decoupled)" if skipped else ""), file=sys.stderr)
    return code

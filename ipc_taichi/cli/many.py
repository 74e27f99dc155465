"""``ipc-taichi decouple`` on clusters: ``--files-from``, ``--skip-existing``, ``--scheduler-file``.

- ``--files-from LIST``: the inputs listed in LIST (one path a line, ``-`` for
  standard input), added to those named on the command line; needs ``-o OUTDIR``.
- ``--skip-existing``: an output that carries this tool's provenance of a
  decoupling (:func:`ipc_taichi.hpc.already_decoupled`) is said to be skipped
  and left as it is, so a killed job re-run does only what is left; any other
  existing output is refused as without the option.
- ``--scheduler-file FILE``: the Dask scheduler that ``dask scheduler
  --scheduler-file FILE`` (or ``dask-mpi``) started; its workers' Taichi pools
  are capped (:func:`ipc_taichi.hpc.cap_worker_threads`).

See docs/hpc.md.
"""

import sys

from ..errors import IPCInputError
from ..hpc import already_decoupled, read_file_list

__all__ = ["add_cluster_arguments", "many_paths", "split_done", "skip_one",
           "report_skipped_only"]


def add_cluster_arguments(group):
    """``--files-from``, ``--skip-existing``, ``--scheduler-file`` (in ``group``)."""
    group.add_argument("--files-from", default=None, metavar="LIST",
                       help="decouple the files listed in LIST too, one path a line ('-': "
                            "standard input; blank lines and lines starting with # left out); "
                            "with -o OUTDIR")
    group.add_argument("--skip-existing", action="store_true",
                       help="an output that ipc-taichi decoupled already (its IPCOP / "
                            "meta.ipc_taichi) is skipped and kept as it is, so a killed job "
                            "can be run again; other existing outputs are still refused")
    group.add_argument("--scheduler-file", default=None, metavar="FILE",
                       help="Dask scheduler file of a running scheduler (dask scheduler "
                            "--scheduler-file FILE); its workers' Taichi pools are capped")


def many_paths(args):
    """The inputs: the positional ones, then those of ``--files-from``; the
    option combinations that cannot work are usage errors."""
    paths = list(args.paths)
    if args.files_from is not None:
        if args.output_dir is None:
            raise IPCInputError(f"--files-from {args.files_from}: give -o OUTDIR (each "
                                "output is named after its input)")
        paths += read_file_list(args.files_from)
    if not paths:
        raise IPCInputError("decouple: give IN.fits OUT.fits, IN.fits --output OUT.fits, or "
                            "inputs with -o OUTDIR (or --files-from LIST)")
    if args.skip_existing and args.overwrite:
        raise IPCInputError("--skip-existing keeps existing outputs, --overwrite replaces "
                            "them: give one")
    if args.scheduler and args.scheduler_file:
        raise IPCInputError("give either --scheduler ADDRESS or --scheduler-file FILE")
    return paths


def _say_skipped(src, dst, args):
    if not args.quiet:
        print(f"ipc-taichi: skipped {src} -> {dst}: already decoupled by ipc-taichi",
              file=sys.stderr, flush=True)


def skip_one(args, src, dst):
    """Whether the one-file form skips ``dst`` (``--skip-existing``, said)."""
    if args.skip_existing and already_decoupled(dst):
        _say_skipped(src, dst, args)
        return True
    return False


def split_done(pairs, args):
    """``(pairs still to do, how many skipped)``: with ``--skip-existing`` the
    pairs whose output is already decoupled are said and left out."""
    if not args.skip_existing:
        return pairs, 0
    todo = []
    for src, dst in pairs:
        if already_decoupled(dst):
            _say_skipped(src, dst, args)
        else:
            todo.append((src, dst))
    return todo, len(pairs) - len(todo)


def report_skipped_only(skipped, args):
    """Every output was there already: said, exit 0."""
    if not args.quiet:
        print(f"decoupled 0 files into {args.output_dir} ({skipped} skipped: already "
              "decoupled)", file=sys.stderr)
    return 0

"""``ipc-taichi export-reference`` (:func:`ipc_taichi.refformats.write_reference`)."""

import sys

from .commands import one_line
from .options import add_quiet_argument

__all__ = ["add_parser", "run_export"]


def add_parser(sub):
    from ..refformats import IPC4D_SHAPE
    from ..refkernels import DEFAULT_SIGNAL

    p = sub.add_parser(
        "export-reference", help=one_line("export-reference"),
        description="Write a coupling model as the IPC reference file a pipeline reads: "
                    "jwst (CRDS 'ipc', FITS: inverse kernels, 4-D per pixel when the model "
                    "has a map), roman (Roman IPC, ASDF: one forward 3x3 kernel) or ipc4d "
                    "(romanimpreprocess, ASDF: forward kernels (3,3,ny,nx)). A signal-"
                    "dependent law is written as its kernel at --signal; the whole model is "
                    "kept in the file, so 'calibrate --reference' and our readers get it "
                    "back exactly. docs/references.md.")
    p.add_argument("model", metavar="MODEL.json", help="the coupling-model file")
    p.add_argument("--format", required=True, choices=("jwst", "roman", "ipc4d"),
                   dest="fmt", help="the reference format")
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="the file to write")
    p.add_argument("--signal", type=float, default=DEFAULT_SIGNAL, metavar="S",
                   help="electrons: the level a signal-dependent law is written at "
                        f"(alpha(S, S); default {DEFAULT_SIGNAL:g})")
    p.add_argument("--shape", type=int, nargs=2, default=None, metavar=("NY", "NX"),
                   help="ipc4d of a model without a map: the frame (default "
                        f"{IPC4D_SHAPE[0]} {IPC4D_SHAPE[1]})")
    p.add_argument("--instrument", default="NIRISS", help="jwst: INSTRUME (default NIRISS)")
    p.add_argument("--detector", default="NIS", help="jwst: DETECTOR (default NIS)")
    p.add_argument("--pedigree", default="GROUND", help="jwst: PEDIGREE (default GROUND)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    add_quiet_argument(p, "summary line")
    p.set_defaults(run=run_export)


def run_export(args):
    from ..model import CouplingModel
    from ..refformats import write_reference

    model = CouplingModel.load(args.model)
    done = write_reference(model, args.output, args.fmt, signal=args.signal,
                           overwrite=args.overwrite, shape=args.shape,
                           instrument=args.instrument, detector=args.detector,
                           pedigree=args.pedigree)
    if not args.quiet:
        print(f"export-reference: wrote {args.output} ({args.fmt}, kernels "
              f"{'x'.join(map(str, done['kernel_shape']))}, alpha(S,S) = {done['alpha']:.5g} "
              f"at S = {done['signal_e']:g} e-)", file=sys.stderr)
    return 0

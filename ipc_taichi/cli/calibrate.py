"""``ipc-taichi calibrate`` (:func:`ipc_taichi.calibrate.calibrate`)."""

import sys

from .commands import one_line
from .options import add_quiet_argument

__all__ = ["add_parser", "run_calibrate"]


def add_parser(sub):
    p = sub.add_parser(
        "calibrate", help=one_line("calibrate"),
        description="Measure alpha(S,0) per direction from isolated hot pixels in darks and "
                    "ramps (followed group by group); from flat ramps separate the gain, "
                    "classical non-linearity, brighter-fatter and IPC (alpha(S,S) with "
                    "brighter-fatter removed); fit a symmetric law chosen by held-out "
                    "evidence (a constant unless the data demand more); check it on held-out "
                    "hot pixels; write a coupling-model file for --model (IPC only; the "
                    "brighter-fatter kernel and non-linearity as named sections). "
                    "docs/calibrate.md.")
    p.add_argument("--darks", nargs="+", default=[], metavar="FILE",
                   help="dark products: 2-D frames, 3-D stacks or 4-D ramps (FITS or ASDF)")
    p.add_argument("--flats", nargs="+", default=[], metavar="FILE",
                   help="flat ramps (4-D SCI, or one ramp of rising reads per file; ramps "
                        "of one illumination are combined), or frames at one level per file "
                        "(>= 2 frames each; these cannot separate brighter-fatter)")
    p.add_argument("--reference", metavar="FILE",
                   help="a JWST 'ipc' reference (FITS, inverse kernel) or Roman IPC reference "
                        "(ASDF, forward kernel)")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.json",
                   help="the coupling-model file to write")
    p.add_argument("--report", metavar="REPORT.json", help="write the full report here")
    p.add_argument("--figures", metavar="DIR", help="write the measured-vs-law figures here")
    p.add_argument("--gain", default=None, help="e-/DN for inputs in DN (a number or a gain "
                                                "image .fits; default: the GAIN keyword)")
    p.add_argument("--bunit", default=None,
                   help="units of the inputs, overriding BUNIT (e.g. DN, electron); a file "
                        "without BUNIT is DN when a gain is known, else electrons (said)")
    p.add_argument("--hdu", default=None, help="science HDU of the FITS inputs (default SCI)")
    p.add_argument("--read-noise", type=float, default=None,
                   help="read noise per read [e-] (default: measured on the darks)")
    p.add_argument("--dq-bits", default=None,
                   help="DQ bits left out (default DO_NOT_USE,SATURATED,JUMP_DET,DEAD)")
    p.add_argument("--refpix", type=int, default=None, help="reference border width (pixels)")
    p.add_argument("--threshold", type=float, default=30.0,
                   help="hot-pixel detection level in robust sigmas (default 30)")
    p.add_argument("--collection-steps", type=int, default=None, metavar="N",
                   help="simulated flat ramps only: charge collected in N discrete steps per "
                        "group (default: continuous, as a detector collects)")
    p.add_argument("--folds", type=int, default=10,
                   help="folds of the held-out law choice (default 10)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    add_quiet_argument(p, "summary lines")
    p.set_defaults(run=run_calibrate)


def run_calibrate(args):
    from ..calibrate import calibrate
    from ..calibrate.inputs import DEFAULT_DQ_BITS
    from ..calibrate.report import summary_lines
    from ..errors import IPCInputError

    if args.folds < 2:
        raise IPCInputError(f"--folds must be >= 2, got {args.folds}")
    result = calibrate(args.darks, args.flats, args.reference, args.output,
                       report_path=args.report, figures=args.figures, gain=args.gain,
                       bunit=args.bunit, hdu=args.hdu, read_noise=args.read_noise,
                       dq_bits=args.dq_bits or DEFAULT_DQ_BITS, refpix=args.refpix,
                       threshold=args.threshold, folds=args.folds,
                       collection_steps=args.collection_steps, overwrite=args.overwrite)
    if not args.quiet:
        for line in summary_lines(result["report"], result["model"]):
            print(f"calibrate: {line}", file=sys.stderr)
        print(f"calibrate: wrote {args.output}", file=sys.stderr)
    return 0

"""``ipc-taichi calibrate`` (:func:`ipc_taichi.calibrate.calibrate`)."""

import sys

from .options import add_quiet_argument

__all__ = ["add_parser", "run_calibrate"]


def add_parser(sub):
    p = sub.add_parser(
        "calibrate", help="measure this detector's coupling: darks/flats/reference -> MODEL.json",
        description="Measure alpha(S,0) per direction from isolated hot pixels in darks and "
                    "ramps (followed group by group), alpha(S,S) per axis from flat-field "
                    "covariances, fit a symmetric law chosen by evidence (BIC), and write a "
                    "coupling-model file for --model (format: docs/calibrate.md).")
    p.add_argument("--darks", nargs="+", default=[], metavar="FILE",
                   help="dark products: 2-D frames, 3-D stacks or 4-D ramps (FITS or ASDF)")
    p.add_argument("--flats", nargs="+", default=[], metavar="FILE",
                   help="flat products, one file per illumination level, >= 2 frames each")
    p.add_argument("--reference", metavar="FILE",
                   help="a JWST 'ipc' reference (FITS, inverse kernel) or Roman IPC reference "
                        "(ASDF, forward kernel)")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.json",
                   help="the coupling-model file to write")
    p.add_argument("--report", metavar="REPORT.json", help="write the full report here")
    p.add_argument("--figures", metavar="DIR", help="write the measured-vs-law figures here")
    p.add_argument("--gain", default=None, help="e-/DN for inputs in DN (a number or a gain "
                                                "image .fits; default: the GAIN keyword)")
    p.add_argument("--hdu", default=None, help="science HDU of the FITS inputs (default SCI)")
    p.add_argument("--read-noise", type=float, default=None,
                   help="read noise per read [e-] (default: measured on the darks)")
    p.add_argument("--dq-bits", default=None,
                   help="DQ bits left out (default DO_NOT_USE,SATURATED,JUMP_DET,DEAD)")
    p.add_argument("--refpix", type=int, default=None, help="reference border width (pixels)")
    p.add_argument("--threshold", type=float, default=30.0,
                   help="hot-pixel detection level in robust sigmas (default 30)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    add_quiet_argument(p, "summary lines")
    p.set_defaults(run=run_calibrate)


def run_calibrate(args):
    from ..calibrate import calibrate
    from ..calibrate.inputs import DEFAULT_DQ_BITS

    result = calibrate(args.darks, args.flats, args.reference, args.output,
                       report_path=args.report, figures=args.figures, gain=args.gain,
                       hdu=args.hdu, read_noise=args.read_noise,
                       dq_bits=args.dq_bits or DEFAULT_DQ_BITS, refpix=args.refpix,
                       threshold=args.threshold, overwrite=args.overwrite)
    if not args.quiet:
        rep = result["report"]
        print(f"calibrate: {result['model'].describe()}", file=sys.stderr)
        print(f"calibrate: law chosen: {rep['fit'].get('chosen')}; hot pixels found: "
              f"{rep['hot_pixels']['found']}; flat levels: {len(rep['flats']['levels'])}",
              file=sys.stderr)
        for line in rep["not_measured"]:
            print(f"calibrate: not measured: {line}", file=sys.stderr)
        for line in (rep["fit"].get("assumed") or []):
            print(f"calibrate: assumed: {line}", file=sys.stderr)
        print(f"calibrate: wrote {args.output}", file=sys.stderr)
    return 0

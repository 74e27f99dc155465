"""``ipc-taichi discover`` and ``ipc-taichi simulate-lab``
(:func:`ipc_taichi.discover.search.discover`,
:func:`ipc_taichi.discover.labdata.simulate_lab`)."""

import json
import sys
from types import SimpleNamespace

from ..errors import IPCInputError
from ..fitsio import check_output_path
from .commands import one_line
from .options import add_quiet_argument, add_runtime_arguments

__all__ = ["add_parsers", "run_discover", "run_simulate_lab", "run_ramp_file"]


def add_parsers(sub):
    from ..discover.effects import EFFECT_NAMES

    p = sub.add_parser(
        "discover", help=one_line("discover"),
        description="Compare MEASURED frames with the model's prediction of their SCENE "
                    "(format: docs/discover.md), name the missing effects one by one (delta "
                    "BIC), refit, and report the gap from baseline to the noise floor.")
    p.add_argument("data", metavar="DATA.fits")
    p.add_argument("--report", metavar="REPORT.json",
                   help="write the JSON report here (default: print it)")
    p.add_argument("--figures", metavar="DIR", help="write the figures into this directory")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise-floor simulations")
    p.add_argument("--threshold", type=float, default=None,
                   help="minimum delta BIC to add an effect (default 25)")
    p.add_argument("--overwrite", action="store_true", help="replace REPORT.json if it exists")
    p.add_argument("--model", metavar="FILE", default=None,
                   help="start from this coupling-model file (law, geometry, edge, and the "
                        "brighter-fatter kernel and non-linearity calibrate measured; as "
                        "written by 'ipc-taichi calibrate') instead of the file's IPCLAW")
    add_quiet_argument(p, "progress lines")
    add_runtime_arguments(p)
    p.set_defaults(run=run_discover)

    s = sub.add_parser(
        "simulate-lab", help=one_line("simulate-lab"),
        description="Draw scenes (background, flat patches, hot pixels, point sources), pass "
                    "them through the detector model with the given hidden effects and write "
                    "the discover format. Effects: " + ", ".join(EFFECT_NAMES) + ".")
    s.add_argument("output", metavar="OUT.fits")
    s.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                   help="hidden effect (repeatable): diagonal_ipc=ALPHA_DIAG, "
                        "anisotropic_ipc=FRACTION, second_neighbor_ipc=ALPHA_SECOND, "
                        "classical_nonlinearity=DEFICIT_AT_50KE, brighter_fatter="
                        "DEFLECTION_AT_50KE, charge_diffusion=SIGMA_PX, dark_current=E, "
                        "flat_field=RMS, reciprocity_failure=ALPHA_PER_DECADE, "
                        "excess_read_noise=TRUE_READNOISE, misregistration=SHIFT_X_PX, "
                        "signal_dependent_ipc=LAW (frames made with LAW, IPCLAW says --law)")
    s.add_argument("--readnoise", type=float, default=12.0, help="e- RMS (default 12)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--law", default=None,
                   help="the starting model's law, written to IPCLAW (default donlon2018)")
    s.add_argument("--model", metavar="FILE", default=None,
                   help="a coupling-model file: the frames are made with its law, geometry, "
                        "edge, brighter-fatter kernel and non-linearity, and IPCLAW holds its "
                        "law (instead of --law)")
    s.add_argument("--oversample", type=int, default=1, metavar="N",
                   help="write SCENE on a grid N times finer than MEASURED (OVERSAMP = N; "
                        "default 1: pixel totals)")
    s.add_argument("--pairs", type=int, default=2, help="SCENE/MEASURED pairs (default 2)")
    s.add_argument("--size", default="128", help="frame size N or NYxNX (default 128)")
    s.add_argument("--no-shot-noise", action="store_true", help="SHOTNOIS = F")
    s.add_argument("--nan-fraction", type=float, default=0.0,
                   help="fraction of MEASURED pixels set to NaN (default 0)")
    s.add_argument("--float32", action="store_true", help="store float32 (default float64)")
    s.add_argument("--overwrite", action="store_true", help="replace OUT.fits if it exists")
    add_runtime_arguments(s)
    s.set_defaults(run=run_simulate_lab)
    _add_ramp_file(sub)


def _add_ramp_file(sub):
    r = sub.add_parser(
        "ramp-file", help=one_line("ramp-file"),
        description="Write a JWST ramp (SCI of integrations x groups, raw DN with the bias, "
                    "or electrons) as a discover ramp file: each integration's groups less "
                    "its first (FIRSTSUB), its SCENE the mean slope of the other integrations "
                    "(SCENEVAR its variance), READNOIS given or measured (docs/discover.md, "
                    "'Real ramps').")
    r.add_argument("input", metavar="JWST.fits")
    r.add_argument("output", metavar="OUT.fits")
    r.add_argument("--gain", type=float, required=True, help="e-/DN")
    r.add_argument("--tgroup", type=float, default=None,
                   help="s between groups (default: the TGROUP keyword)")
    r.add_argument("--readnoise", type=float, default=None,
                   help="e- per read (default: measured on the same increments)")
    r.add_argument("--exclude", action="append", default=[], metavar="Y0:Y1,X0:X1",
                   help="leave out a box (0-based, ends excluded; repeatable): a source that "
                        "moves between integrations")
    r.add_argument("--remove-frame-offsets", action="store_true",
                   help="subtract each group's median over the frame (as a reference-pixel "
                        "step would)")
    r.add_argument("--law", default="donlon2018", help="IPCLAW written (default donlon2018)")
    r.add_argument("--hdu", default=None, help="science HDU (default SCI)")
    r.add_argument("--overwrite", action="store_true", help="replace OUT.fits if it exists")
    r.set_defaults(run=run_ramp_file)


def _parse_box(text):
    try:
        rows, cols = str(text).split(",")
        (y0, y1), (x0, x1) = (tuple(int(v) for v in part.split(":")) for part in (rows, cols))
    except ValueError:
        raise IPCInputError(f"--exclude {text!r}: expected Y0:Y1,X0:X1 (integers)") from None
    return y0, y1, x0, x1


def run_ramp_file(args):
    from ..discover.jwstramps import write_jwst_ramps

    check_output_path(args.output, args.overwrite)
    boxes = [_parse_box(b) for b in args.exclude]
    ramps = write_jwst_ramps(args.input, args.output, args.gain, tgroup=args.tgroup,
                             readnoise=args.readnoise, law=args.law, overwrite=args.overwrite,
                             hdu=args.hdu, exclude=boxes,
                             frame_offsets=args.remove_frame_offsets)
    for note in ramps.notes:
        print(f"ramp-file: {note}", file=sys.stderr)
    print(f"wrote {args.output}: {len(ramps.reads)} ramp pairs of {ramps.reads[0].shape[0]} "
          f"reads, TFRAME {ramps.tgroup:g} s, READNOIS {ramps.readnoise:.2f} e-")
    return 0


def _ipclaw_written(path):
    """The ``IPCLAW`` a written lab file holds."""
    from astropy.io import fits

    with fits.open(path) as hdul:
        return hdul[0].header["IPCLAW"]


def _init(args):
    from .. import runtime

    runtime.init(args.arch, args.precision)


def run_discover(args):
    from ..discover.report import summary_line, to_json, write_figures, write_report
    from ..discover.search import EVIDENCE_THRESHOLD, discover

    if args.report:
        check_output_path(args.report, args.overwrite)  # fail before computing
    _init(args)
    say = None if args.quiet else (lambda line: print(f"discover: {line}", file=sys.stderr))
    threshold = EVIDENCE_THRESHOLD if args.threshold is None else args.threshold
    if args.model is not None:  # fail before computing: the file and its sections
        from ..discover.model import effects_from_document
        from ..model import CouplingModel

        effects_from_document(CouplingModel.load(args.model, with_document=True)[1], args.model)
    from ..discover.ramps import is_ramp_file

    if is_ramp_file(args.data):  # 3-D MEASURED: the time structure (discover.ramp_search)
        from ..discover.ramp_search import discover_ramps

        result = SimpleNamespace(report=discover_ramps(args.data, seed=args.seed,
                                                       threshold=threshold, log=say,
                                                       start=args.model))
        if args.figures:
            from ..discover.rampfigures import write_ramp_figure

            path = write_ramp_figure(result.report, args.figures)
            print(f"discover: wrote {path}", file=sys.stderr)
            args.figures = None
    else:
        result = discover(args.data, seed=args.seed, threshold=threshold, log=say,
                          start=args.model)
    if args.figures:
        write_figures(result, args.figures)
    if args.report:
        write_report(result.report, args.report, args.overwrite)
        print(f"{summary_line(result.report)}; report {args.report}")
    else:
        print(json.dumps(to_json(result.report), indent=2))
        if not args.quiet:
            print(f"discover: {summary_line(result.report)}", file=sys.stderr)
    return 0


def _parse_effects(items):
    from ..discover.effects import EFFECTS

    effects = {}
    for item in items:
        name, eq, value = item.partition("=")
        name = name.strip()
        if not eq or name not in EFFECTS:
            raise IPCInputError(f"--effect {item!r}: expected NAME=VALUE with NAME one of "
                                f"{', '.join(EFFECTS)}")
        try:
            effects[name] = EFFECTS[name].parse(value)
        except ValueError:
            raise IPCInputError(f"--effect {item!r}: {value!r} is not a number") from None
    return effects


def _parse_size(text):
    try:
        parts = [int(v) for v in str(text).lower().split("x")]
    except ValueError:
        raise IPCInputError(f"--size {text!r}: expected N or NYxNX") from None
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2:
        raise IPCInputError(f"--size {text!r}: expected N or NYxNX")
    return tuple(parts)


def run_simulate_lab(args):
    import numpy as np

    from ..discover.labdata import simulate_lab

    check_output_path(args.output, args.overwrite)
    effects = _parse_effects(args.effect)
    if args.oversample < 1:
        raise IPCInputError(f"--oversample {args.oversample}: must be an integer >= 1")
    coupling = document = None
    if args.model is not None:
        from ..model import CouplingModel

        if args.law is not None:
            raise IPCInputError(f"--model {args.model} holds the law; do not also give --law")
        coupling, document = CouplingModel.load(args.model, with_document=True)
    _init(args)
    simulate_lab(args.output, effects, readnoise=args.readnoise, seed=args.seed,
                 law=args.law or "donlon2018", pairs=args.pairs, shape=_parse_size(args.size),
                 shot_noise=not args.no_shot_noise, nan_fraction=args.nan_fraction,
                 dtype=np.float32 if args.float32 else np.float64, overwrite=args.overwrite,
                 oversample=args.oversample, coupling=coupling, document=document)
    lab_law = _ipclaw_written(args.output)
    print(f"wrote {args.output}: {args.pairs} SCENE/MEASURED pairs, IPCLAW {lab_law}, "
          f"READNOIS {args.readnoise:g}"
          + (f", OVERSAMP {args.oversample}" if args.oversample > 1 else ""))
    return 0

"""Validation run: ``calibrate`` beside solid-waffle's own analysis, on flat
ramps made by solid-waffle's own flat simulator (docs/calibrate_validation.md).

A script, not part of the library (CI does not run it; the tests run the same
sets through ``calibrate`` in tests/test_calibrate_waffle.py)::

    PYTHONPATH=. python analysis/validate_waffle.py OUT [--side both|waffle|ours]
        [--nramps 8] [--nreads 20] [--level 42000]

For each set (constant IPC 1 %; plus the simulator's infrared brighter-fatter
kernel; plus a quadratic non-linearity 1.5 ppm/e-; tests/independent/waffle.py)
it simulates the flat ramps (and, for solid-waffle, as many dark ramps: its
analysis pairs every flat with a dark), runs

- ours: ``ipc_taichi.calibrate.calibrate([], [ramps], refpix=4,
  collection_steps=2)`` (the simulator's SUBSTEPS), the gain from the file's
  GAIN keyword (timed);
- solid-waffle's: ``correlation_run.Config`` with the steps of its
  ``run_ir_all`` (advanced characterisation with the brighter-fatter
  correction, methods 2a, 2b and 3), on the simulator's own per-ramp files,
  the configuration of solid-waffle's own test of its simulator (timed);

and writes ``OUT/validation.json`` and a Markdown table on standard output.
solid-waffle's numbers are means over its 4 x 4 super-pixels (128 x 128 px);
the error is the standard deviation of the super-pixels over sqrt(number).
"""

import argparse
import contextlib
import json
import os
import sys
import time

import numpy as np
from scipy.signal import convolve

from tests.independent import waffle

NEAREST = {"x": [(2, 1), (2, 3)], "y": [(1, 2), (3, 2)]}
"""The kernels' nearest cells [2+dy][2+dx] per axis."""


def nearest(kernel):
    """Mean of the two nearest-neighbour cells of a 5x5 kernel, per axis."""
    k = np.asarray(kernel, dtype=float)
    return {axis: float(np.mean([k[i, j] for i, j in cells])) for axis, cells in NEAREST.items()}


def ipc_squared_kernel(a, alpha=waffle.ALPHA):
    """``K * K * a`` on the 5x5 grid (the brighter-fatter kernel seen through
    the IPC kernel ``K`` twice, what solid-waffle's flat correlations measure)."""
    k = np.zeros((3, 3))
    k[1, 0] = k[0, 1] = k[1, 2] = k[2, 1] = alpha
    k[1, 1] = 1.0 - 4.0 * alpha
    return convolve(convolve(np.asarray(a, float), k), k)[2:7, 2:7]


# ---- solid-waffle's own analysis -------------------------------------------------------

def _waffle_config(made, darks, nreads, outstem, options=()):
    half = nreads // 2
    times = f"1 {half} {half + 2} {nreads}"
    lines = ["DETECTOR: solid-waffle_flat_simulator", "LIGHT:"]
    lines += [f"    {f}" for f in made["ramps"]]
    lines += ["DARK:"] + [f"    {f}" for f in darks]
    lines += [f"FORMAT: {waffle.FORMAT}", "CHAR: Advanced 1 3 3 bfe", "NBIN: 4 4",
              f"TIME: {times}", f"TIME2A: 1 2 4 {nreads}", f"TIME2B: 1 2 4 {nreads}",
              f"TIME3: 1 2 4 {nreads}", f"OUTPUT: {outstem}", *options]
    return "\n".join(lines) + "\n"


def _mean_error(values, good):
    v = values[good]
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size))


def waffle_analysis(made, darks, nreads, outstem, options=()):
    """solid-waffle's characterisation of one set: the steps of ``run_ir_all``
    (its figures, summary and log written under ``outstem``), hot pixels left
    out (the simulator makes none); ``options``: more configuration lines
    (e.g. ``FULLNL: True True False``)."""
    from solid_waffle import correlation_run

    start = time.perf_counter()
    with open(outstem + "_config.txt", "w") as f:
        f.write(_waffle_config(made, darks, nreads, outstem, options))
    with open(outstem + "_config.txt") as f, open(outstem + "_log.txt", "w") as log, \
            contextlib.redirect_stdout(log):
        cf = correlation_run.Config(f.readlines(), verbose=True)
        cf.fit_parameters(verbose=True)
        cf.generate_nonlinearity(write_to_file=True)
        cf.write_basic_figure()
        cf.alt_methods(verbose=True)
        cf.method_23_plot()
    with open(outstem + "_summary.txt", "w") as f:
        f.write(cf.text_output())
    seconds = time.perf_counter() - start

    info, swi, good = cf.full_info, cf.swi, cf.is_good > 0.5
    cells = np.array([[info[:, :, swi.ker0 + 5 * dy + dx] for dx in range(-2, 3)]
                      for dy in range(-2, 3)])  # (5, 5, ny, nx): [2+dy][2+dx] per super-pixel
    kernel = np.array([[_mean_error(cells[i, j], good)[0] for j in range(5)] for i in range(5)])
    per_axis = {axis: _mean_error(np.mean([cells[i, j] for i, j in where], axis=0), good)
                for axis, where in NEAREST.items()}
    column = {"gain": swi.g, "gain_raw": swi.graw, "alpha_x": swi.alphaH,
              "alpha_y": swi.alphaV, "beta": swi.beta}
    out = {name: _mean_error(info[:, :, c], good) for name, c in column.items()}
    slopes = {}
    for method, used, values, bfe, nlipc in (
            ("2a", cf.used_2a, "Method2a_slopes", "slope_2a_BFE", "slope_2a_NLIPC"),
            ("2b", cf.used_2b, "Method2b_slopes", "slope_2b_BFE", "slope_2b_NLIPC"),
            ("3", cf.used_3, "Method3_slopes", "slope_3_BFE", "slope_3_NLIPC")):
        if used:
            slopes[method] = {"measured": _mean_error(getattr(cf, values), good),
                              "predicted_bfe": float(getattr(cf, bfe)),
                              "predicted_nlipc": float(getattr(cf, nlipc))}
    return {**out, "k2a_kernel": kernel.tolist(), "k2a_nearest": per_axis,
            "k2a_center": float(kernel[2, 2]), "superpixels_good": int(good.sum()),
            "methods_2_3": slopes, "seconds": seconds}


# ---- ours ----------------------------------------------------------------------------

def ours_analysis(made, report_path, nreads, level):
    """``calibrate`` on the set's one ramp file; alpha(S, S) of the model at
    every read's level."""
    import ipc_taichi
    from ipc_taichi.calibrate import calibrate

    ipc_taichi.init()
    start = time.perf_counter()
    result = calibrate([], [made["path"]], gain=None, refpix=made["refpix"],
                       collection_steps=waffle.SUBSTEPS, report_path=report_path,
                       overwrite=True)
    seconds = time.perf_counter() - start
    model, report = result["model"], result["report"]
    levels = level * np.arange(1, nreads) / (nreads - 1)
    alpha = {axis: [model.geometry.weight(*d) * float(model.law.alpha(s, s)) for s in levels]
             for axis, d in (("x", (0, 1)), ("y", (1, 0)))}
    bf = report["brighter_fatter"]
    return {"seconds": seconds, "levels": levels.tolist(), "alpha": alpha,
            "law": report["law_choice"]["chosen"],
            "constant_fits_as_well": report["law_choice"]["constant_fits_as_well"],
            "gain": [report["gain"]["measured"], report["gain"]["error"]],
            "gain_source": report["gain"]["source"],
            "beta": [report["classical_nonlinearity"]["beta"],
                     report["classical_nonlinearity"]["error"]],
            "nonlinearity_detected": report["classical_nonlinearity"]["detected"],
            "bf_detected": bf["detected"], "bf_significance": bf["significance"],
            "bf_kernel": bf["kernel"],
            "bf_nearest": nearest(bf["kernel"]) if bf["kernel"] is not None else None,
            "bf_nearest_error": (nearest(bf["kernel_error"])
                                 if bf["kernel_error"] is not None else None),
            "nonlinear_ipc_detected": report["nonlinear_ipc"]["detected"],
            "nonlinear_ipc_significance": report["nonlinear_ipc"]["significance"]}


# ---- the run ---------------------------------------------------------------------------

def truth_of(made):
    t = dict(made["truth"])
    if t["bf_kernel"] is not None:
        t["bf_nearest"] = nearest(t["bf_kernel"])
        t["k2a_nearest"] = nearest(ipc_squared_kernel(t["bf_kernel"]))
    return t


def run_set(out, kind, side, nramps, nreads, level, options=()):
    folder = os.path.join(out, kind)
    os.makedirs(folder, exist_ok=True)
    start = time.perf_counter()
    made = waffle.flat_ramps(folder, kind, nramps=nramps, nreads=nreads, level=level,
                             keep_ramps=side != "ours")
    row = {"kind": kind, "simulation_seconds": time.perf_counter() - start,
           "truth": truth_of(made), "path": made["path"]}
    if side != "ours":
        darks = waffle.dark_ramps(folder, kind, nramps=nramps, nreads=nreads)
        row["solid_waffle"] = waffle_analysis(made, darks, nreads,
                                              os.path.join(folder, "solid_waffle"), options)
    if side != "waffle":
        row["ours"] = ours_analysis(made, os.path.join(folder, "report.json"), nreads, level)
    return row


def _pm(pair, scale=1.0, digits=4):
    if pair is None or pair[0] is None:
        return "-"
    value, error = pair
    text = f"{value * scale:.{digits}f}"
    return text + (f" ± {error * scale:.{digits}f}" if error is not None else "")


def markdown(rows):
    """The side-by-side table (alpha in %, beta and kernels in ppm/e-)."""
    lines = ["| set | quantity | truth | solid-waffle | ours |", "|---|---|---|---|---|"]
    for row in rows:
        t, w, o = row["truth"], row.get("solid_waffle"), row.get("ours")
        cells = [
            ("alpha x (%)", f"{100 * t['alpha']:.3f}", _pm(w and w["alpha_x"], 100, 3),
             o and f"{100 * min(o['alpha']['x']):.3f} .. {100 * max(o['alpha']['x']):.3f}"),
            ("alpha y (%)", f"{100 * t['alpha']:.3f}", _pm(w and w["alpha_y"], 100, 3),
             o and f"{100 * min(o['alpha']['y']):.3f} .. {100 * max(o['alpha']['y']):.3f}"),
            ("gain (e-/DN)", f"{waffle.GAIN:.3f}", _pm(w and w["gain"], 1, 4),
             o and _pm(o["gain"], 1, 4)),
            ("beta (ppm/e-)", f"{1e6 * t['beta']:.3f}", _pm(w and w["beta"], 1e6, 4),
             o and _pm(o["beta"], 1e6, 4)),
        ]
        for axis in ("x", "y"):
            truth_bf = (f"a {1e6 * t['bf_nearest'][axis]:.3f}; K²a "
                        f"{1e6 * t['k2a_nearest'][axis]:.3f}") if "bf_nearest" in t else "0"
            ours_bf = None
            if o:
                ours_bf = ("not detected" if not o["bf_detected"] else
                           f"a {1e6 * o['bf_nearest'][axis]:.3f}"
                           + (f" ± {1e6 * o['bf_nearest_error'][axis]:.3f}"
                              if o["bf_nearest_error"] else ""))
            cells.append((f"BF nearest {axis} (ppm/e-)", truth_bf,
                          w and "K²a " + _pm(w["k2a_nearest"][axis], 1e6, 3), ours_bf))
        for name, truth, sw, us in cells:
            lines.append(f"| {row['kind']} | {name} | {truth} | {sw or '-'} | "
                         f"{us if us is not None else '(not run)'} |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out")
    parser.add_argument("--side", choices=("both", "waffle", "ours"), default="both")
    parser.add_argument("--nramps", type=int, default=8)
    parser.add_argument("--nreads", type=int, default=20)
    parser.add_argument("--level", type=float, default=42000.0)
    parser.add_argument("--kinds", nargs="+", choices=list(waffle.KINDS),
                        default=list(waffle.KINDS))
    parser.add_argument("--waffle-option", action="append", default=[],
                        help="one more line of solid-waffle's configuration (repeatable)")
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    rows = [run_set(args.out, kind, args.side, args.nramps, args.nreads, args.level,
                    args.waffle_option) for kind in args.kinds]
    with open(os.path.join(args.out, "validation.json"), "w") as f:
        json.dump({"nramps": args.nramps, "nreads": args.nreads, "level": args.level,
                   "waffle_options": args.waffle_option, "sets": rows}, f, indent=1)
    print(markdown(rows))
    for row in rows:
        times = [f"simulation {row['simulation_seconds']:.1f} s"]
        times += [f"{side} {row[side]['seconds']:.1f} s" for side in ("solid_waffle", "ours")
                  if side in row]
        print(f"{row['kind']}: " + ", ".join(times), file=sys.stderr)


if __name__ == "__main__":
    main()

"""The calibration report (JSON), its console summary and its figures.

The report holds everything measured and how the law was chosen, so a reader
can check the model file against the data: the inputs as read (ramp or frames,
units, gain), the gain measured by flat ramps, classical non-linearity, the
brighter-fatter kernel, the evidence on non-linear IPC, the hot-pixel bins
(alpha(S, 0) per direction), the flat levels (alpha(S, S) per axis with
brighter-fatter removed where ramps allowed), the held-out law choice and
the law's band, the transfer check on held-out hot pixels, the fit per point
(measured, model, pull) and the lists ``not_measured``, ``notes`` and
``assumed``. :func:`summary_lines` is what the command line prints.
"""

import os

import numpy as np

from ..fitsio import write_json
from .hotpixels import DIRECTIONS

__all__ = ["write_report", "write_figures", "json_ready", "summary_lines", "map_lines",
           "reference_lines"]


def json_ready(value):
    """A copy with NaN and infinities as None (JSON has no NaN) and tuples as lists."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def _pm(value, error, scale=1.0, fmt=".3g", unit=""):
    if value is None:
        return "not measured"
    err = "" if error is None else f" +- {scale * error:{fmt.lstrip('+')}}"
    return f"{scale * value:{fmt}}{err}{unit}"


def _bf_line(bf):
    if not bf.get("measured"):
        return f"brighter-fatter: not measured: {bf.get('note') or 'no flat ramps'}"
    k, e = bf.get("kernel"), bf.get("kernel_error")
    nearest = ""
    if k is not None:
        ax = 0.5 * (k[2][1] + k[2][3])
        ay = 0.5 * (k[1][2] + k[3][2])
        ex = 0.5 * (e[2][1] ** 2 + e[2][3] ** 2) ** 0.5 if e else None
        ey = 0.5 * (e[1][2] ** 2 + e[3][2] ** 2) ** 0.5 if e else None
        nearest = (f"; kernel a(0,+-1) {_pm(ax, ex, 1e7, '.3f')}e-7, a(+-1,0) "
                   f"{_pm(ay, ey, 1e7, '.3f')}e-7, a(0,0) {1e7 * k[2][2]:.3f}e-7 per e-")
    state = "DETECTED" if bf.get("detected") else "not detected"
    sig = bf.get("significance")
    sig = f" ({sig:.1f} sigma)" if sig is not None else ""
    return (f"brighter-fatter: {state}{sig}{nearest}; kept in the model file, never removed "
            "by decouple")


def summary_lines(document, model):
    """What ``ipc-taichi calibrate`` prints: the inputs as read, each effect
    measured or not, the law chosen (and whether a constant does as well),
    the held-out check, what was assumed or not measured."""
    lines = []
    for item in document.get("inputs", []):
        what = "; ".join(x for x in (item.get("stack_reason"), item.get("units_note"),
                                     item.get("dq_note")) if x)
        lines.append(f"input ({item['role']}): {item['file']}: {what}")
    g = document.get("gain") or {}
    if g.get("measured") is not None:
        used = "none" if g.get("used") is None else f"{g['used']:.4g} e-/DN ({g.get('source')})"
        lines.append(f"gain: used {used}; measured by the flat ramps "
                     f"{_pm(g['measured'], g.get('error'), fmt='.4g')} e-/DN")
    lines.append(_bf_line(document.get("brighter_fatter") or {}))
    nl = document.get("classical_nonlinearity") or {}
    if nl.get("measured"):
        lines.append(f"classical non-linearity: beta {_pm(nl['beta'], nl.get('error'), 1e6)}"
                     f"e-6 per e- ({'detected' if nl.get('detected') else 'not detected'})")
    nli = document.get("nonlinear_ipc") or {}
    lines.append(f"non-linear IPC: {'DETECTED' if nli.get('detected') else 'not detected'}: "
                 f"{nli.get('note', '')}")
    lines.append(f"law: {model.describe()}")
    lines += _alpha_lines(document.get("fit") or {})
    choice = document.get("law_choice") or {}
    if choice.get("constant_fits_as_well"):
        lines.append("law: a constant fits the held-out data as well as any signal-dependent "
                     "law")
    t = document.get("transfer")
    if t:
        parts = []
        for key, name in (("chosen", f"chosen law ({t['form']})"), ("constant", "best constant"),
                          ("uncorrected", "not decoupled")):
            r = t[key]
            parts.append(f"{name} {_pm(r['residual'], r['error'], 100, '+.3f', ' %')}")
        lines.append(f"held-out hot pixels ({t['chosen']['n_pixels']}), neighbour residual: "
                     + "; ".join(parts))
    lines += reference_lines(document.get("reference"), model, bool(document.get("fit", {})
                                                                   .get("points")))
    lines += map_lines(document.get("bond_map"))
    lines += [f"assumption tested: {a['note']}" for a in document.get("assumptions") or []]
    for line in document.get("not_measured", []):
        lines.append(f"not measured: {line}")
    for line in (document.get("fit") or {}).get("assumed") or []:
        lines.append(f"assumed: {line}")
    for line in document.get("notes", []):
        lines.append(f"note: {line}")
    return lines


def _alpha_lines(fit):
    """alpha and the geometry weights of the law written, with their errors
    (a constant: its weighted mean; a law that changes with signal: its 1-sigma
    band at the middle and the top of the measured range)."""
    lines = []
    row = (fit.get("forms") or {}).get(fit.get("chosen")) or {}
    band, held = fit.get("band") or {}, fit.get("held_outside") or {}
    if row.get("alpha") is not None and "alpha_error" in row:
        lines.append(f"alpha (nearest neighbours, constant): "
                     f"{_pm(row['alpha'], row['alpha_error'], 100, '.4f', ' %')}")
    elif band.get("signal") and held.get("total_signal_range"):
        grid = np.asarray(band["signal"], float)
        lo, hi = held["total_signal_range"]
        at = []
        for s in (np.sqrt(max(lo, 1.0) * hi) / 2, hi / 2):  # S at (S, 0) inside S + N's range
            i = int(np.argmin(np.abs(np.log(grid / s))))
            at.append(f"{_pm(band['alpha_s0'][i], band['alpha_s0_error'][i], 100, '.4f', ' %')}"
                      f" at S = {grid[i]:.3g} e-")
        lines.append(f"alpha(S,0) ({fit.get('chosen')}, 1-sigma band): {'; '.join(at)}")
    weights, errors = fit.get("weights") or {}, fit.get("weight_errors") or {}
    if weights:
        lines.append("geometry weights (x and y average 1): " + ", ".join(
            f"{axis} {_pm(w, errors.get(axis), 1.0, '.3f')}" for axis, w in weights.items()))
    return lines


def reference_lines(ref, model, measured):
    """The console's comparison of a reference file with what was measured
    (a DUMMY reference named as such)."""
    if not ref:
        return []
    pedigree = str(ref.get("pedigree") or "").upper()
    name = (f"DUMMY reference (PEDIGREE = {ref['pedigree']!r}: a placeholder, not a "
            "measurement)" if pedigree.startswith("DUMMY") else "reference")
    x = ref.get("coupling_x")
    if x is None:
        return [f"{name}: {ref['file']}: {ref.get('law')}"]
    if not measured:
        return [f"{name}: {ref['file']}: nearest coupling (x) {100 * x:.3f} %; nothing "
                "measured: the model is the reference's"]
    m = float(model.law.alpha(1e4, 0.0) * model.geometry.weight(0, 1))
    return [f"{name}: {ref['file']}: nearest coupling (x) {100 * x:.3f} % against "
            f"{100 * m:.3f} % measured at (10 ke-, 0) ({100 * (m / x - 1):+.1f} %)"]


def map_lines(section):
    """The console's lines on the IPC map across the detector (:mod:`.maps`)."""
    if not section:
        return []
    if section.get("x") is None:
        return [f"IPC map: not measured: {section.get('reason')}"]
    t = section.get("test") or {}

    def z(part, what):
        r = t.get(part)
        return f"{what} {r['z']:+.1f} SE (n = {r['n']})" if r else f"{what}: not tested"

    x = np.array(section["x"], float)
    err = np.array(section["x_error"], float)
    state = "WRITTEN" if section.get("written") else "not written (the model is uniform)"
    flat = t.get("flat_superpixel")
    return [f"IPC map: {state}: {section['reason']}",
            f"IPC map: {section['superpixel'][0]} px super-pixels, x bonds {x.min():.3f}.."
            f"{x.max():.3f} of the law (median error {np.nanmedian(err):.3f}); held-out: "
            + z("hot", "hot pixels") + "; "
            + z("flat", f"flats ({flat} px)" if flat else "flats")]


def write_report(document, path, overwrite=False):
    """Write the report ``document`` to ``path`` atomically (NaN written as null)."""
    return write_json(path, json_ready(document), overwrite)


def _nearest_points(fit, source):
    pts = [p for p in (fit or {}).get("points", []) if p["source"] == source]
    return ([p["signal"] for p in pts], [100 * p["alpha_measured"] for p in pts],
            [100 * p["error"] for p in pts])


def _law_figure(ax, fit, law):
    """Nearest-neighbour alpha: points at (S, 0) and (S, S), the law and its band."""
    band = (fit or {}).get("band")
    for source, key, label, marker in (("hot", "alpha_s0", "(S, 0)", "o"),
                                       ("flat", "alpha_ss", "(S, S)", "s")):
        s, a, e = _nearest_points(fit, source)
        if s:
            ax.errorbar(s, a, e, fmt=marker, ms=4,
                        label=f"measured {label}: {'hot pixels' if source == 'hot' else 'flats'}")
        if band:
            grid = np.array(band["signal"])
            centre = 100 * np.array(band[key], float)
            err = 100 * np.array([np.nan if v is None else v for v in band[key + "_error"]],
                                 float)
            line, = ax.plot(grid, centre, "-" if source == "hot" else "--",
                            label=f"law at {label}")
            ax.fill_between(grid, centre - err, centre + err, color=line.get_color(),
                            alpha=0.25, lw=0)
    held = (fit or {}).get("held_outside")
    if held:
        lo, hi = held["total_signal_range"]
        left, right = ax.get_xlim()
        ax.axvspan(hi, max(right, 1.5 * hi), color="0.9", label="not measured (law held)")
        if left < lo:
            ax.axvspan(left, lo, color="0.9")
    ax.set_xscale("log")
    ax.set_xlabel("signal S [e-]")
    ax.set_ylabel("nearest-neighbour alpha [%]")
    ax.set_title(f"Calibrated law: {(fit or {}).get('chosen')} (band: 1 sigma, held-out folds)")
    ax.legend(fontsize=7)


def _map_figure(fig, ax, law, top):
    grid = np.linspace(0.0, top, 121)
    s, n = np.meshgrid(grid, grid, indexing="ij")
    im = ax.imshow(100 * law.alpha(s, n).T, origin="lower", extent=(0, top, 0, top),
                   aspect="auto")
    fig.colorbar(im, ax=ax, label="alpha(S, N) [%]")
    ax.set_xlabel("S (pixel) [e-]")
    ax.set_ylabel("N (neighbour) [e-]")
    ax.set_title("The law alpha(S, N)")


def _stamp_figure(fig, axes, transfer):
    stamps = [100 * np.array(transfer[key]["stamp"], float) for key in ("uncorrected", "chosen")]
    lim = max(max(np.max(np.abs(np.delete(s.ravel(), 12))) for s in stamps), 1e-3)
    for ax, stamp, title in zip(axes, stamps, ("hot pixels as measured",
                                               "decoupled (held-out law)")):
        shown = stamp.copy()
        shown[2, 2] = np.nan  # the centre holds ~95 %: shown as a number only
        im = ax.imshow(shown, cmap="RdBu_r", vmin=-lim, vmax=lim, origin="lower",
                       extent=(-2.5, 2.5, -2.5, 2.5))
        for (y, x), v in np.ndenumerate(stamp):
            ax.text(x - 2, y - 2, f"{v:.2f}", ha="center", va="center", fontsize=7)
        ax.set_title(f"mean stamp, {title} [%]", fontsize=9)
        ax.set_xlabel("dx")
        ax.set_ylabel("dy")
    fig.colorbar(im, ax=list(axes), label="fraction of the hot pixel's charge [%]")


def _bond_map_figure(fig, axes, section):
    """The map of the x and y bonds (relative to the law), their errors, and the
    held-out test in the title."""
    lim = max(float(np.nanmax(np.abs(np.array(section[n], float) - 1))) for n in ("x", "y"))
    lim = max(lim, 0.01)
    for row, name in enumerate(("x", "y")):
        value = np.array(section[name], float)
        error = np.array(section[f"{name}_error"], float)
        for col, (data, label, cmap) in enumerate(((value, "map", "coolwarm"),
                                                   (error, "error", "viridis"))):
            ax = axes[row, col]
            im = ax.imshow(data, origin="lower", cmap=cmap,
                           **({"vmin": 1 - lim, "vmax": 1 + lim} if col == 0 else {}))
            fig.colorbar(im, ax=ax, shrink=0.8)
            ax.set_title(f"{name} bonds: {label} (super-pixels of "
                         f"{section['superpixel'][0]} px)", fontsize=9)
    t = section.get("test") or {}
    parts = [f"{k} {t[k]['z']:+.1f} SE" for k in ("hot", "flat") if t.get(k)]
    fig.suptitle(f"IPC map {'written' if section.get('written') else 'NOT written'}; "
                 f"held-out preference for the map: {', '.join(parts) or 'not tested'}",
                 fontsize=10)


def _kernel_figure(fig, ax, bf):
    k = 1e7 * np.array(bf["kernel"], float)
    e = 1e7 * np.array(bf["kernel_error"], float) if bf.get("kernel_error") else None
    lim = np.max(np.abs(k))
    im = ax.imshow(k, cmap="RdBu_r", vmin=-lim, vmax=lim, origin="lower",
                   extent=(-2.5, 2.5, -2.5, 2.5))
    for (y, x), v in np.ndenumerate(k):
        text = f"{v:.2f}" + (f"\n+-{e[y, x]:.2f}" if e is not None else "")
        ax.text(x - 2, y - 2, text, ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax, label="a(dy, dx) [1e-7 per e-]")
    ax.set_xlabel("dx")
    ax.set_ylabel("dy")
    state = "detected" if bf.get("detected") else "not detected"
    ax.set_title(f"Brighter-fatter kernel ({state})")


COVARIANCE_LAGS = ("0,0", "0,1", "1,0", "1,1")
"""Lags drawn in the flat-ramp covariance figure."""


def _covariance_figure(axes, curves):
    """Same-increment covariance of flat ramps against signal per lag (normalised
    by the shot variance of one increment), measured and as each model refitted
    predicts it: IPC only, non-linear IPC, brighter-fatter, all together."""
    level = np.array(curves["level"], float)
    chi2 = curves.get("chi2_per_dof", {})
    for ax, lag in zip(axes, COVARIANCE_LAGS):
        row = curves["lags"][lag]
        err = np.array([np.nan if e is None else e for e in row["error"]], float)
        ax.errorbar(level, row["measured"], err, fmt="o", ms=3, color="k", label="measured")
        for variant in ("ipc_only", "nonlinear_ipc", "brighter_fatter", "full"):
            if variant in row:
                x2 = chi2.get(variant)
                label = variant.replace("_", " ") + (f" (chi2/dof {x2:.2f})" if x2 else "")
                ax.plot(level, row[variant], "-", lw=1, label=label)
        ax.set_title(f"lag (dy, dx) = ({lag})", fontsize=9)
        ax.set_xlabel("signal at the read [e-]")
    axes[0].set_ylabel(curves.get("normalisation", "C / shot variance"))
    axes[1].legend(fontsize=6)


def write_figures(folder, document, law, geometry):
    """The figures of a calibration, PNG, in ``folder``; returns the paths.

    ``calibrate_law.png`` (the nearest-neighbour law with its band against
    the points at (S, 0) and (S, S)), ``calibrate_map.png`` (alpha(S, N)),
    ``calibrate_bond_map.png`` (the IPC map across the detector, its error
    and the held-out test), ``calibrate_stamp.png`` (the mean hot-pixel
    stamp before and after decoupling with the held-out law), ``calibrate_bf_kernel.png`` (the
    brighter-fatter kernel), ``calibrate_covariance.png`` (flat-ramp
    covariances against signal with each model's prediction), and one
    ``calibrate_<direction>.png`` per direction (measured against ``w
    alpha``). A figure whose data were not measured is not written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(folder, exist_ok=True)
    paths = []

    def save(fig, name):
        path = os.path.join(folder, name)
        if fig.get_layout_engine() is None:
            fig.tight_layout()
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)

    fit = document.get("fit") or {}
    hot_rows = (document.get("hot_pixels") or {}).get("bins", [])
    flat_rows = (document.get("flats") or {}).get("levels", [])
    signals = [r["signal"] for r in hot_rows] + [r["level"] for r in flat_rows if r.get("terms")]
    if signals:
        fig, ax = plt.subplots(figsize=(7, 4.5))
        _law_figure(ax, fit, law)
        save(fig, "calibrate_law.png")
        fig, ax = plt.subplots(figsize=(5.5, 4.5))
        _map_figure(fig, ax, law, 1.2 * max(signals))
        save(fig, "calibrate_map.png")
    transfer = document.get("transfer")
    if transfer and transfer["chosen"].get("stamp") and transfer["uncorrected"].get("stamp"):
        fig, axes = plt.subplots(1, 2, figsize=(9, 4), layout="constrained")
        _stamp_figure(fig, axes, transfer)
        save(fig, "calibrate_stamp.png")
    section = document.get("bond_map") or {}
    if section.get("x") is not None:
        fig, axes = plt.subplots(2, 2, figsize=(9, 8), layout="constrained")
        _bond_map_figure(fig, axes, section)
        save(fig, "calibrate_bond_map.png")
    bf = document.get("brighter_fatter") or {}
    if bf.get("measured") and bf.get("kernel") is not None:
        fig, ax = plt.subplots(figsize=(5.5, 4.5))
        _kernel_figure(fig, ax, bf)
        save(fig, "calibrate_bf_kernel.png")
    ramps = (document.get("flats") or {}).get("ramps") or []
    curves = ramps[0].get("covariance_curves") if ramps else None
    if curves and all(lag in curves.get("lags", {}) for lag in COVARIANCE_LAGS):
        fig, axes = plt.subplots(1, len(COVARIANCE_LAGS), figsize=(13, 3.8))
        _covariance_figure(axes, curves)
        save(fig, "calibrate_covariance.png")
    if signals:
        for name, fig in _direction_figures(plt, hot_rows, flat_rows, law, geometry, signals):
            save(fig, f"calibrate_{name}.png")
    return paths


def _direction_figures(plt, hot_rows, flat_rows, law, geometry, signals):
    """``(direction, figure)`` per direction: measured points (hot pixels at (S, B), flats at
    (S, S)) against the fitted ``w alpha``."""
    weights = {"x": geometry.weight(0, 1), "y": geometry.weight(1, 0),
               "diagonal": geometry.weight(1, 1), "second_x": geometry.weight(0, 2),
               "second_y": geometry.weight(2, 0)}
    grid = np.geomspace(max(min(signals) * 0.7, 1.0), max(signals) * 1.3, 200)
    for name in DIRECTIONS:
        fig, ax = plt.subplots(figsize=(6, 4))
        if hot_rows:
            s = [r["signal"] for r in hot_rows]
            ax.errorbar(s, [100 * r[name]["value"] for r in hot_rows],
                        [100 * r[name]["error"] for r in hot_rows], fmt="o", ms=4,
                        label="hot pixels: w alpha(S, 0)")
        flats = [r for r in flat_rows if r.get("terms")]
        if flats:
            ax.errorbar([r["level"] for r in flats],
                        [100 * r["terms"][name]["value"] for r in flats],
                        [100 * r["terms"][name]["error"] for r in flats], fmt="s", ms=4,
                        label="flats: w alpha(S, S)")
        w = weights[name]
        ax.plot(grid, 100 * w * law.alpha(grid, 0.0 * grid), "-", label="law at (S, 0)")
        ax.plot(grid, 100 * w * law.alpha(grid, grid), "--", label="law at (S, S)")
        ax.set_xscale("log")
        ax.set_xlabel("signal S [e-]")
        ax.set_ylabel(f"coupling, {name} [%]")
        ax.set_title(f"Measured coupling ({name}) against the calibrated law")
        ax.legend(fontsize=8)
        yield name, fig

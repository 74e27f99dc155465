"""The calibration report (JSON) and its figures.

The report holds everything measured and how the law was chosen, so a reader
can check the model file against the data: the inputs and their units, the
read noise, the hot-pixel bins (alpha(S, 0) per direction), the flat levels
(alpha(S, S) per axis, the covariances, the Poisson check), the growth of
each flat term with signal (brighter-fatter check), every law form's BIC, the
fit per point (measured, model, pull) and a list ``not_measured`` that says
what could not be measured and why.
"""

import os

import numpy as np

from ..fitsio import write_json
from .hotpixels import DIRECTIONS

__all__ = ["write_report", "write_figures", "json_ready"]


def json_ready(value):
    """A copy with NaN and infinities as None (JSON has no NaN) and tuples as lists."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def write_report(document, path, overwrite=False):
    """Write the report ``document`` to ``path`` atomically (NaN written as null)."""
    return write_json(path, json_ready(document), overwrite)


def write_figures(folder, hot_rows, flat_rows, law, geometry):
    """One PNG per direction: measured points (hot pixels at (S, B), flats at
    (S, S)) against the fitted ``w alpha``; returns the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(folder, exist_ok=True)
    weights = {"x": geometry.weight(0, 1), "y": geometry.weight(1, 0),
               "diagonal": geometry.weight(1, 1), "second_x": geometry.weight(0, 2),
               "second_y": geometry.weight(2, 0)}
    paths = []
    signals = [r["signal"] for r in hot_rows] + [r["level"] for r in flat_rows if r.get("terms")]
    if not signals:
        return paths
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
        fig.tight_layout()
        path = os.path.join(folder, f"calibrate_{name}.png")
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths

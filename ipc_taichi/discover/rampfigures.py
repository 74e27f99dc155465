"""The figure of a ramp discovery (``discover FILE --figures DIR`` on a ramp
file): what a person reads at a glance.

Left, the gap per read (mean square of the whitened increments at each read,
1 for a complete model): the starting model and the model after each named
step, with the final model's floor (the simulations' mean +- 3 scatters) as a
band. Right, the residual neighbour correlation (mean product of the whitened
increments of horizontal, ``x``, and vertical, ``y``, neighbours) at the
start and after each step, with the final floor's band: read noise shared by
rows or columns, or a signal over areas the model lacks, stands above it.
The numbers are the report's (:func:`~.ramp_search.discover_ramps`:
``baseline``, ``steps``, ``gap_per_read_floor``, ``neighbour_floor``).
"""

import os

import numpy as np

from ..fitsio import atomic_output

__all__ = ["write_ramp_figure", "RAMP_FIGURE"]

RAMP_FIGURE = "ramp_gap.png"


def _stages(report):
    """``[(label, stats)]``: the start and each step's model."""
    out = [("start", report["baseline"])]
    out += [(f"+ {s['effect']}", s) for s in report["steps"]]
    return out


def _gap_panel(ax, report, stages):
    floor, sigma = (np.asarray(a, dtype=float) for a in report["gap_per_read_floor"])
    reads = np.arange(len(floor))
    ax.fill_between(reads, floor - 3 * sigma, floor + 3 * sigma, color="0.85",
                    label="floor +- 3 sd", step="mid" if len(reads) > 1 else None)
    if len(reads) == 1:
        ax.errorbar(reads, floor, yerr=3 * sigma, fmt="_", color="0.5", capsize=8)
    for label, stats in stages:
        ax.plot(reads, stats["gap_per_read"], marker="o", label=f"{label}: {stats['gap']:.3f}")
    ax.set_xlabel("read")
    ax.set_ylabel("gap per read (chi-square per increment)")
    ax.set_xticks(reads)
    ax.set_title("gap per read")
    ax.legend(fontsize=7)


def _neighbour_panel(ax, report, stages):
    width = 0.8 / (len(stages) + 1)
    for j, axis in enumerate(("x", "y")):
        m, s = report["neighbour_floor"][axis]
        ax.bar(j, 6 * s, bottom=m - 3 * s, width=0.9, color="0.85",
               label="floor +- 3 sd" if j == 0 else None)
        for i, (label, stats) in enumerate(stages):
            ax.bar(j - 0.4 + width * (i + 1), stats["neighbour_correlation"][axis], width=width,
                   color=f"C{i}", label=label if j == 0 else None)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xticks([0, 1], ["x (rows)", "y (columns)"])
    ax.set_ylabel("mean product of neighbours' whitened increments")
    ax.set_title("residual neighbour correlation")
    ax.legend(fontsize=7)


def write_ramp_figure(report, directory):
    """Write :data:`RAMP_FIGURE` into ``directory`` (created) from a ramp
    discovery ``report`` (module docstring), through a temporary file
    renamed into place; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(directory, exist_ok=True)
    stages = _stages(report)
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    _gap_panel(left, report, stages)
    _neighbour_panel(right, report, stages)
    verdict = "complete" if report["complete"] else "incomplete"
    named = ", ".join(report["missing_effects"]) or "nothing named"
    fig.suptitle(f"{os.path.basename(str(report['input']))}: {named}; {verdict} "
                 f"(gap {report['final_gap']:.3f}, floor {report['gap_floor']:.3f} +- "
                 f"{report['gap_floor_sigma']:.3f})", fontsize=9)
    fig.tight_layout()
    path = os.path.join(directory, RAMP_FIGURE)
    with atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path

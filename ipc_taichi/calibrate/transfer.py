"""Transfer validation: does the calibrated law correct hot pixels it was not fitted on?

The hot pixels are split in two halves by position (:func:`.hotpixels.fold_of`).
For each half, the chosen law form and the best constant are fitted on the
other half's hot pixels (and every flat point, which says nothing about these
pixels), and the darks around this half's hot pixels are decoupled with each.
What is left in the four nearest neighbours, as a fraction of the hot
pixel's charge (:func:`.hotpixels.nn_fraction`), should be zero within its
error; the two halves together give every hot pixel one held-out residual.
The residual is averaged per pixel first and its error is the scatter over
pixels (the hot pixel is the unit, as in :mod:`.hotpixels`).

Only stamps around the hot pixels are decoupled: each (``2 * HALF + 1``
pixels square) is laid into a mosaic, one per group, and the mosaic is
decoupled once; the coupling reaches 2 pixels and a Jacobi solve a few more,
so the stamps do not disturb each other's centres.
"""

import math

import numpy as np

from .. import decouple
from ..model import CouplingModel
from . import hotpixels, lawfit

__all__ = ["HALF", "mosaic", "held_out_residuals"]

HALF = 9
"""Half-width of the stamp around each hot pixel (pixels)."""


def mosaic(groups, positions):
    """Stamps of every group around ``positions`` laid side by side:
    ``(stack (ngroups, H, W), centres (k, 2))``."""
    g, ny, nx = groups.shape
    side = 2 * HALF + 1
    padded = np.full((g, ny + 2 * HALF, nx + 2 * HALF), np.nan)
    padded[:, HALF:HALF + ny, HALF:HALF + nx] = groups
    k = len(positions)
    cols = max(1, int(math.ceil(math.sqrt(k))))
    rows = int(math.ceil(k / cols))
    stack = np.full((g, rows * side, cols * side), np.nan)
    centres = np.zeros((k, 2), int)
    for i, (y, x) in enumerate(positions):
        r, c = divmod(i, cols)
        stack[:, r * side:(r + 1) * side, c * side:(c + 1) * side] = \
            padded[:, y:y + side, x:x + side]
        centres[i] = (r * side + HALF, c * side + HALF)
    return stack, centres


def _residual(mosaics, model, min_signal):
    """Mean neighbour fraction after decoupling with ``model`` (None: as
    measured) at the hot pixels of ``mosaics`` (per integration with hot
    pixels: ``(stack, centres, groups, positions)``, the stamps cut by
    :func:`mosaic` once for every model): ``{"residual", "error", "n_pixels"}``."""
    values, pixels, boxes = [], [], []
    for stack, centres, groups, positions in mosaics:
        if model is not None:
            stack = np.asarray(decouple(stack, model=model))
        ev = hotpixels.measure_events(stack, centres)
        keep = ev["signal"] >= min_signal
        nx = groups.shape[-1]
        ids = positions[ev["event"], 0] * nx + positions[ev["event"], 1]
        values.append(hotpixels.nn_fraction(ev)[keep])
        pixels.append(ids[keep])
        boxes.append(ev["fraction"][keep])
    if not values or not np.concatenate(values).size:
        return {"residual": None, "error": None, "n_pixels": 0, "stamp": None}
    v, ids = np.concatenate(values), np.concatenate(pixels)
    _, cluster = np.unique(ids, return_inverse=True)
    per_pixel = hotpixels.per_pixel_mean(v, cluster)
    n = per_pixel.size
    err = float(per_pixel.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    stamp = np.concatenate(boxes).mean(axis=0).reshape(5, 5)
    return {"residual": float(per_pixel.mean()), "error": err, "n_pixels": int(n),
            "stamp": stamp.tolist()}


def held_out_residuals(integrations, events, bins, flat_rows, chosen, min_signal=1000.0,
                       bin_floor=200.0):
    """Decouple each half of the hot pixels with laws fitted on the other half.

    Parameters
    ----------
    integrations : list of (ndarray, ndarray)
        Per dark integration: its groups ``(ngroups, ny, nx)`` [e-] (masked
        pixels NaN) and the hot-pixel positions found in it ``(k, 2)``.
    events : dict
        The hot-pixel measurements of every integration
        (:func:`.hotpixels.measure_events`, concatenated, with ``pixel``).
    bins : array_like
        The signal bins of the full fit (:func:`.hotpixels.summarise_events`).
    flat_rows : list
        Flat points used in every fit.
    chosen : str
        The law form chosen on all the data (:func:`.lawfit.choose_law`).
    min_signal : float
        Measurements below this charge [e-] are not scored.
    bin_floor : float
        The bins' floor [e-] (:func:`.hotpixels.floors`).

    Returns
    -------
    dict or None
        ``chosen``, ``constant`` and ``uncorrected``: each ``{"residual",
        "error", "n_pixels", "stamp"}`` (``stamp``: the mean 5x5 box of
        fractions, for a figure); ``form``; None when a half has too few hot
        pixels to fit.
    """
    half_of = hotpixels.fold_of(events["pixel"], 2, seed=1)
    scored = {"chosen": [], "constant": [], "uncorrected": []}
    for half in (0, 1):
        train = hotpixels.summarise_events(hotpixels.select_events(events, half_of != half),
                                           bins=bins, min_count=3, min_signal=bin_floor)
        try:
            fitted = lawfit.fit_forms(train, flat_rows)
        except ValueError:  # this half measures no coupling: no check
            fitted = None
        if fitted is None or chosen not in fitted["forms"]:
            return None
        held = set(np.asarray(events["pixel"])[half_of == half].tolist())
        mine = []
        for groups, positions in integrations:
            ids = positions[:, 0] * groups.shape[-1] + positions[:, 1]
            kept = positions[np.isin(ids, list(held))]
            if len(kept):
                mine.append((*mosaic(groups, kept), groups, kept))
        for key, name in (("chosen", chosen), ("constant", "constant")):
            geometry, law = lawfit.model_of(fitted, name)
            scored[key].append(_residual(mine, CouplingModel.resolve(law, geometry, "zero"),
                                         min_signal))
        scored["uncorrected"].append(_residual(mine, None, min_signal))
    return {"form": chosen, **{k: _combine(v) for k, v in scored.items()},
            "min_signal": float(min_signal),
            "note": "neighbour residual (mean of the 4 nearest, fraction of the hot pixel's "
                    "charge) of each half of the hot pixels, decoupled with laws fitted on "
                    "the other half"}


def _combine(halves):
    """Two halves' residuals as one (weighted by pixels; errors in quadrature)."""
    used = [h for h in halves if h["n_pixels"] > 1 and h["residual"] is not None]
    if not used:
        return {"residual": None, "error": None, "n_pixels": 0, "stamp": None}
    n = sum(h["n_pixels"] for h in used)
    value = sum(h["residual"] * h["n_pixels"] for h in used) / n
    error = math.sqrt(sum((h["error"] * h["n_pixels"]) ** 2 for h in used)) / n
    stamp = sum(np.array(h["stamp"]) * h["n_pixels"] for h in used) / n
    return {"residual": value, "error": error, "n_pixels": n, "stamp": stamp.tolist()}

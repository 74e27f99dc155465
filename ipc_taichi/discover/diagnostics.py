"""Where model and data disagree: residuals in noise units and what localises them.

Definitions (used by the search and the report)
-----------------------------------------------
residual
    ``r = (MEASURED - mean) / sqrt(variance)`` with ``mean, variance`` the
    model's prediction of the SCENE (:meth:`DetectorModel.predict`).
gap
    The mean of ``r^2`` over the valid pixels of all pairs (a chi-square per
    pixel): about 1 when the model is complete. Valid pixels are finite in
    MEASURED and SCENE, at least :data:`BORDER` pixels from the frame edge
    (edge conventions differ between simulators and are not what is being
    tested), and at least 2 pixels from a NaN scene pixel (its charge, and
    so its neighbours' coupling, is unknown).
stacked window
    The mean residual in the 5x5 window around bright, isolated scene peaks
    (hot pixels and point sources), in bins of peak signal: IPC, diffusion
    and brighter-fatter leave their fingerprints in the ring around the
    centre; signal dependence shows as a change from bin to bin.
residual vs signal
    The mean residual of pixels binned by their expected signal: dark
    current shows at the low end, non-linearity at the high end.
"""

import numpy as np
from scipy import ndimage

__all__ = ["BORDER", "SIGNAL_BINS", "valid_mask", "fill_scene", "residual", "gap",
           "find_probes", "stacked_windows", "residual_vs_signal"]

BORDER = 3
SIGNAL_BINS = (1000.0, 4000.0, 12000.0, 30000.0, 1e9)  # e-: peak-signal bins of the stacks
WINDOW = 2  # half-size of the stacked window (5x5)


def valid_mask(scene, measured, border=BORDER):
    """Pixels that enter the statistics (see module docstring)."""
    bad_scene = ~np.isfinite(scene)
    near_bad = ndimage.binary_dilation(bad_scene, structure=np.ones((5, 5), bool)) \
        if bad_scene.any() else bad_scene
    valid = np.isfinite(measured) & ~near_bad
    valid[:border, :] = False
    valid[-border:, :] = False
    valid[:, :border] = False
    valid[:, -border:] = False
    return valid


def fill_scene(scene):
    """NaN scene pixels replaced by the median of their finite neighbours, so
    the model can run; those pixels are masked by :func:`valid_mask`."""
    scene = np.array(scene, dtype=np.float64)
    ny, nx = scene.shape
    for _ in range(20):  # grows inwards into clusters of bad pixels
        bad = np.argwhere(~np.isfinite(scene))
        if not len(bad):
            break
        values = []
        for y, x in bad:
            patch = scene[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2]
            finite = patch[np.isfinite(patch)]
            values.append(np.median(finite) if finite.size else np.nan)
        scene[bad[:, 0], bad[:, 1]] = values
    scene[~np.isfinite(scene)] = 0.0
    return scene


def residual(measured, mean, variance, valid):
    """``(measured - mean) / sqrt(variance)`` on valid pixels, NaN elsewhere."""
    r = np.full(mean.shape, np.nan)
    r[valid] = (measured[valid] - mean[valid]) / np.sqrt(variance[valid])
    return r


def gap(residuals):
    """Mean squared residual over the valid pixels of all frames."""
    total = sum(float(np.nansum(r * r)) for r in residuals)
    n = sum(int(np.isfinite(r).sum()) for r in residuals)
    return total / max(n, 1)


def find_probes(scene, valid, threshold=500.0, isolation=5):
    """Bright isolated peaks of the scene: ``(y, x, signal)`` rows.

    A probe is a local maximum ``threshold`` e- above the local background
    (the median of its 11x11 neighbourhood), with no other peak above 5 % of
    its signal within ``isolation`` pixels, and a valid 5x5 window.
    """
    background = ndimage.median_filter(scene, size=11, mode="nearest")
    above = scene - background
    peak = (scene == ndimage.maximum_filter(scene, size=3, mode="nearest")) & (above > threshold)
    ys, xs = np.nonzero(peak)
    ny, nx = scene.shape
    rows = []
    window_ok = ndimage.minimum_filter(valid.astype(np.uint8), size=2 * WINDOW + 1,
                                       mode="constant", cval=0).astype(bool)
    for y, x in zip(ys, xs):
        if not window_ok[y, x] or y < isolation or x < isolation \
                or y >= ny - isolation or x >= nx - isolation:
            continue
        patch = above[y - isolation:y + isolation + 1, x - isolation:x + isolation + 1]
        others = peak[y - isolation:y + isolation + 1, x - isolation:x + isolation + 1].copy()
        others[isolation, isolation] = False
        if np.any(patch[others] > 0.05 * above[y, x]):
            continue
        rows.append((int(y), int(x), float(above[y, x])))
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def stacked_windows(residuals, probes, bins=SIGNAL_BINS):
    """Mean residual in the 5x5 window around probes, per peak-signal bin.

    Parameters
    ----------
    residuals : list of 2-D arrays
    probes : list of (n, 3) arrays from :func:`find_probes`, one per frame
    bins : increasing bin edges (e-), ``len(bins) - 1`` bins

    Returns
    -------
    stacks : (nbins, 5, 5) array (NaN for an empty bin); counts : (nbins,) ints
    """
    nb = len(bins) - 1
    sums = np.zeros((nb, 2 * WINDOW + 1, 2 * WINDOW + 1))
    counts = np.zeros(nb, dtype=int)
    for r, rows in zip(residuals, probes):
        for y, x, s in rows:
            k = np.searchsorted(bins, s, side="right") - 1
            if not 0 <= k < nb:
                continue
            y, x = int(y), int(x)
            sums[k] += r[y - WINDOW:y + WINDOW + 1, x - WINDOW:x + WINDOW + 1]
            counts[k] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        stacks = sums / counts[:, None, None]
    return stacks, counts


def residual_vs_signal(residuals, means, edges=None):
    """Mean residual (and mean squared residual) of pixels binned by expected signal.

    Returns ``(centres, mean_r, mean_r2, counts)``; default log bins 10 e- .. 100 ke-.
    """
    edges = np.geomspace(10.0, 1e5, 17) if edges is None else np.asarray(edges)
    nb = len(edges) - 1
    s1, s2, n = np.zeros(nb), np.zeros(nb), np.zeros(nb, dtype=int)
    for r, m in zip(residuals, means):
        ok = np.isfinite(r)
        k = np.searchsorted(edges, m[ok], side="right") - 1
        inside = (k >= 0) & (k < nb)
        np.add.at(s1, k[inside], r[ok][inside])
        np.add.at(s2, k[inside], r[ok][inside] ** 2)
        np.add.at(n, k[inside], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(edges[:-1] * edges[1:]), s1 / n, s2 / n, n

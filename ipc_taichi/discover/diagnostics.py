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
chi-square vs signal
    The mean squared residual in the same bins: a variance problem (read
    noise, a response map) shows here and not in the mean residual.
residuals by probe type
    Mean residual and chi-square at the centres and rings of hot pixels and
    stars, inside flat patches and along their edges (:func:`probe_masks`).
"""

import math

import numpy as np
from scipy import ndimage

__all__ = ["BORDER", "SIGNAL_BINS", "PROBE_TYPES", "valid_mask", "near_holes", "fill_scene",
           "residual", "gap",
           "find_probes", "stacked_windows", "residual_vs_signal", "probe_masks",
           "residuals_by_probe", "dipoles", "after_images", "pair_correlation", "UNEXPLAINED_Z"]

BORDER = 3
SIGNAL_BINS = (1000.0, 4000.0, 12000.0, 30000.0, 1e9)  # e-: peak-signal bins of the stacks
WINDOW = 2  # half-size of the stacked window (5x5)
UNEXPLAINED_Z = 5.0  # a pattern stands out (is described, refuses a name) at 5 sigma


def valid_mask(scene, measured, border=BORDER):
    """Pixels that enter the statistics (see module docstring)."""
    valid = np.isfinite(measured) & ~near_holes(~np.isfinite(scene))
    valid[:border, :] = False
    valid[-border:, :] = False
    valid[:, :border] = False
    valid[:, -border:] = False
    return valid


def near_holes(bad):
    """The pixels within 2 of a ``bad`` one (a SCENE pixel that is not finite):
    their expected signal depends on the unknown one through the coupling."""
    return ndimage.binary_dilation(bad, structure=np.ones((5, 5), bool)) if bad.any() else bad


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


PROBE_TYPES = ("hot_pixels", "stars", "flat_patches", "flat_edges")


def probe_masks(scene, valid, probes, contrast=1000.0):
    """Pixels of each probe type of one frame: ``{type: (centre, ring)}`` boolean masks.

    hot_pixels
        probes (:func:`find_probes`) holding more than 70 % of the charge
        above background in their 3x3 window; ``centre`` the peak, ``ring``
        its 4 nearest neighbours.
    stars
        the other probes (extended sources), same centre and ring.
    flat_patches
        pixels ``contrast`` e- above the frame's median whose 3x3
        neighbourhood varies by less than 2 %: the interior of flat areas
        (``ring`` is empty).
    flat_edges
        pixels with a neighbour differing by more than ``contrast`` e- and
        30 %, away from probes: the edges of flat areas, inside (``centre``)
        and outside (``ring``).
    """
    shape = scene.shape
    out = {}
    near_probe = np.zeros(shape, bool)
    hot = [np.zeros(shape, bool), np.zeros(shape, bool)]
    star = [np.zeros(shape, bool), np.zeros(shape, bool)]
    background = ndimage.median_filter(scene, size=11, mode="nearest")
    above = scene - background
    for y, x, _ in probes:
        y, x = int(y), int(x)
        win = above[y - 1:y + 2, x - 1:x + 2]
        frac = above[y, x] / max(float(np.clip(win, 0, None).sum()), 1e-9)
        target = hot if frac > 0.7 else star
        target[0][y, x] = True
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            target[1][y + dy, x + dx] = True
        near_probe[max(y - 3, 0):y + 4, max(x - 3, 0):x + 4] = True
    out["hot_pixels"] = (hot[0] & valid, hot[1] & valid)
    out["stars"] = (star[0] & valid, star[1] & valid)
    hi = ndimage.maximum_filter(scene, size=3, mode="nearest")
    lo = ndimage.minimum_filter(scene, size=3, mode="nearest")
    level = float(np.median(scene))
    interior = (scene > level + contrast) & (hi - lo < 0.02 * scene) & ~near_probe
    out["flat_patches"] = (interior & valid, np.zeros(shape, bool))
    step = (hi - lo > contrast) & (hi - lo > 0.3 * hi) & ~near_probe & ~interior
    inside = step & (scene > 0.5 * (hi + lo))
    out["flat_edges"] = (inside & valid, step & ~inside & valid)
    return out


def residuals_by_probe(residuals, masks):
    """Mean residual and mean squared residual by probe type, centre and ring.

    ``masks``: one :func:`probe_masks` result per frame. Returns
    ``{type: {"centre": {...}, "ring": {...}}}`` with ``n``, ``mean``
    (noise units), ``z`` (the mean over its standard error) and ``chi2``
    (mean squared residual).
    """
    out = {}
    for kind in PROBE_TYPES:
        parts = {}
        for i, where in enumerate(("centre", "ring")):
            vals = np.concatenate([r[m[kind][i]] for r, m in zip(residuals, masks)]
                                  or [np.zeros(0)])
            vals = vals[np.isfinite(vals)]
            n = int(vals.size)
            mean = float(vals.mean()) if n else float("nan")
            parts[where] = {"n": n, "mean": mean,
                            "z": mean * math.sqrt(n) if n else float("nan"),
                            "chi2": float(np.mean(vals ** 2)) if n else float("nan")}
        out[kind] = parts
    return out


def dipoles(residuals, probes):
    """Mean antisymmetric residual around probes: ``{"x": (mean, z), "y": (mean, z)}``.

    ``(r[y, x+1] - r[y, x-1]) / 2`` (and along y): a shift between SCENE and
    MEASURED leaves dipoles of one sign around every source.
    """
    out = {}
    for axis, (dy, dx) in (("x", (0, 1)), ("y", (1, 0))):
        vals = []
        for r, rows in zip(residuals, probes):
            for y, x, _ in rows:
                y, x = int(y), int(x)
                vals.append(0.5 * (r[y + dy, x + dx] - r[y - dy, x - dx]))
        vals = np.asarray(vals, float)
        vals = vals[np.isfinite(vals)]
        if vals.size < 3:
            out[axis] = (float("nan"), float("nan"))
            continue
        m = float(vals.mean())
        out[axis] = (m, m / (vals.std(ddof=1) / math.sqrt(vals.size) + 1e-12))
    return out


def after_images(residual_blocks, scene_blocks, valid_blocks, bright=5000.0):
    """Mean residual where the *previous* pair's scene was bright, against the
    other faint pixels of the same pair.

    Returns ``(difference of means, z, n)``: an after-image of earlier
    exposures (persistence) shows as a positive difference. Only pixels faint
    in the current scene, and not next to anything bright now, are compared.
    """
    inside, outside = [], []
    for res, scenes, valid in zip(residual_blocks, scene_blocks, valid_blocks):
        for k in range(1, len(res)):
            prev = scenes[k - 1] - np.median(scenes[k - 1])
            now = scenes[k] - np.median(scenes[k])
            busy = ndimage.binary_dilation(now > 0.02 * bright, structure=np.ones((3, 3), bool))
            faint = ~busy & valid[k] & np.isfinite(res[k])
            inside.append(res[k][faint & (prev > bright)])
            outside.append(res[k][faint & (prev < 0.02 * bright)])
    a = np.concatenate(inside) if inside else np.zeros(0)
    b = np.concatenate(outside) if outside else np.zeros(0)
    if a.size < 3 or b.size < 3:
        return float("nan"), float("nan"), int(a.size)
    diff = float(a.mean() - b.mean())
    se = math.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
    return diff, diff / (se + 1e-12), int(a.size)


def pair_correlation(residual_blocks):
    """Mean product of the residuals of one pixel in two different pairs of a file,
    and its z: a fixed per-pixel pattern (a response map) repeats across pairs."""
    vals = []
    for res in residual_blocks:
        for k in range(len(res)):
            for j in range(k + 1, len(res)):
                p = res[k] * res[j]
                vals.append(p[np.isfinite(p)])
    vals = np.concatenate(vals) if vals else np.zeros(0)
    if vals.size < 3:
        return float("nan"), float("nan")
    m = float(vals.mean())
    return m, m / (vals.std(ddof=1) / math.sqrt(vals.size) + 1e-12)

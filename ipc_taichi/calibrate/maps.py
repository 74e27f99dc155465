"""IPC that varies across the detector: the bond map measured, and tested on held-out data.

The map (:mod:`ipc_taichi.bondmap`) multiplies the law per neighbour pair. It
is measured per super-pixel, for the x bonds ``(0, 1)`` and the y bonds
``(1, 0)`` (the other offsets of the geometry take the mean of the two), from
two sources:

- **Flats** (as solid-waffle does per super-pixel): the noise of flat ramps'
  group differences (each pixel's mean difference over every integration and
  group taken out: the response pattern and the level cancel) or of flat
  frames (each minus the per-pixel mean). Per super-pixel, the nearest-lag
  covariance over the variance, ``r(l) = C(l) / C(0)``, is ``~ 2 w(l) alpha b``;
  divided by the whole array's value it is the super-pixel's map value
  ``b`` (relative to the array, as the law is). The read noise's own
  covariance at each lag (measured on the darks' group differences,
  :func:`read_noise_covariance`) is taken out of ``C(l)`` and ``C(0)`` first.
  Error: the scatter of the products over sqrt(their number).
- **Hot pixels**: each isolated hot pixel's nearest-neighbour fractions
  (mean of the two sides, its largest-charge read per integration) over
  ``w alpha(S, B)`` of the law are the local ``b``; per super-pixel their mean
  weighted by ``(S w alpha / read noise)^2`` (the read noise's share of each
  fraction), the errors scaled by the array's chi^2 per pixel so that they
  are what the pixels' scatter says.

The two are combined per super-pixel by inverse variance; a super-pixel with
neither stays at 1 (the law). The super-pixel size is the smallest of
:data:`SUPERPIXELS` whose median error reaches :data:`MAP_PRECISION` (else the
largest that leaves :data:`MIN_GRID` super-pixels per axis).

**The held-out test** (:func:`held_out_test`). Hot pixels are split in two
halves by position and flat integrations (frames) by parity. For each half, a
map measured without it (the other half's hot pixels and flats) is tested on
it: (i) the half's hot pixels are decoupled with the law alone and with the law
times that map; per pixel ``d = r_uniform^2 - r_map^2`` (``r`` the 4 nearest
neighbours' residual fraction); (ii) per super-pixel of the half's flats,
``d = ((v - 1)^2 - (v - m)^2) / e^2`` (``v`` the held-out value, ``e`` its
error, ``m`` the map). Each gives ``z = mean(d) / its standard error`` (noise
in the map makes ``d`` negative on average, so a map without a cause loses);
the two are combined as ``(z_hot + z_flat) / sqrt(2)``. The map is written
only when ``z >= MAP_MARGIN``; otherwise the model stays uniform (no map: the
decoupling is bit-identical to the law's).
"""

import math

import numpy as np
from scipy import ndimage

from .. import decouple
from ..bondmap import BondMap
from ..model import CouplingModel
from . import hotpixels, stream
from .transfer import mosaic

__all__ = ["SUPERPIXELS", "MAP_PRECISION", "MAP_MARGIN", "MIN_GRID", "NoiseSums",
           "read_noise_covariance", "flat_noise_sums", "hot_pixel_factors",
           "superpixel_map", "held_out_test", "measure_map", "decouple_frame"]

SUPERPIXELS = (8, 16, 32, 64, 128, 256)
"""Super-pixel sizes tried [pixels], smallest first."""
MIN_DOF = 10
"""Fewest degrees of freedom of the hot pixels' scatter within super-pixels
that scale their errors (fewer: the scatter about the array's mean)."""
MAP_PRECISION = 0.10
"""Median relative error per super-pixel the size is chosen for."""
MAP_MARGIN = 3.0
"""Held-out standard errors by which the map must beat the uniform law."""
MIN_GRID = 4
MIN_SPREAD = 0.01
"""Smallest spread of a map across the detector assumed when shrinking (1 %)."""
FLAT_TEST_ERROR = 0.2
"""Largest median error per super-pixel of held-out flats that can test a map."""
"""Fewest super-pixels per axis for a map."""
BASE = SUPERPIXELS[0]
"""The flats' covariance sums are kept on blocks of this many pixels."""
LAGS = ((0, 1), (1, 0))
"""The bonds measured: x ``(0, 1)`` and y ``(1, 0)``."""


class NoiseSums:
    """Sums of noise products at lags (0, 0), (0, 1), (1, 0) on blocks of
    :data:`BASE` pixels (a pair counts in the block of its first pixel), per
    fold (two folds: even and odd integrations / frames); a super-pixel's (or
    the array's) covariance is a sum of blocks."""

    def __init__(self, shape):
        self.shape = tuple(shape)
        grid = (2, -(-self.shape[0] // BASE), -(-self.shape[1] // BASE))
        self.sum = {lag: np.zeros(grid) for lag in ((0, 0),) + LAGS}
        self.sq = {lag: np.zeros(grid) for lag in self.sum}
        self.n = {lag: np.zeros(grid) for lag in self.sum}

    def add(self, image, fold):
        """Add one noise image (NaN: not used) to ``fold`` (0 or 1)."""
        ny, nx = self.shape
        for lag in self.sum:
            dy, dx = lag
            p = np.full(self.shape, np.nan)
            p[:ny - dy, :nx - dx] = image[:ny - dy, :nx - dx] * image[dy:, dx:]
            ok = np.isfinite(p)
            p = np.where(ok, p, 0.0)
            self.sum[lag][fold] += _blocks(p, BASE)
            self.sq[lag][fold] += _blocks(p * p, BASE)
            self.n[lag][fold] += _blocks(ok.astype(np.float64), BASE)

    def covariance(self, s, folds=(0, 1)):
        """Per super-pixel of ``s`` pixels (a multiple of :data:`BASE`; None: the
        whole array): ``{lag: (cov, error)}`` of arrays ``(nj, ni)``."""
        out = {}
        for lag in self.sum:
            tot = [_blocks(getattr(self, name)[lag][list(folds)].sum(axis=0),
                           None if s is None else s // BASE)
                   for name in ("sum", "sq", "n")]
            n = np.maximum(tot[2], 1)
            mean = tot[0] / n
            var = np.clip(tot[1] / n - mean ** 2, 0, None)
            out[lag] = (np.where(tot[2] > 0, mean, np.nan), np.sqrt(var / n))
        return out


def _blocks(a, s):
    """Sums of ``a`` over ``s`` x ``s`` blocks (the last partial ones kept);
    ``s`` None: the whole array, shape (1, 1)."""
    if s is None:
        return np.array([[a.sum()]])
    ny, nx = a.shape
    nj, ni = -(-ny // s), -(-nx // s)
    padded = np.zeros((nj * s, ni * s))
    padded[:ny, :nx] = a
    return padded.reshape(nj, s, ni, s).sum(axis=(1, 3))


def _differences(f):
    """Noise images of one input (ramps: group differences; frames: the
    frames), one at a time as ``(image with NaN masked, integration)``, each
    pixel's mean over the images taken out (scaled to keep the variance)."""
    d, m = f.data, f.mask
    ramp = f.meta.get("stack") == "ramp" and d.shape[1] > 1

    def images():
        for i in range(d.shape[0]):
            if ramp and stream.is_lazy(d):  # NaN where masked; each read once
                reads = (d[i, g] for g in range(d.shape[1]))
                prev = next(reads)
                for read in reads:
                    yield read - prev, i
                    prev = read
            elif ramp:
                for g in range(1, d.shape[1]):
                    yield np.where(m[i, g] | m[i, g - 1], np.nan, d[i, g] - d[i, g - 1]), i
            else:
                for g in range(d.shape[1]):
                    yield np.where(m[i, g], np.nan, d[i, g]), i * d.shape[1] + g

    total, n = np.zeros(d.shape[-2:]), np.zeros(d.shape[-2:])
    for img, _ in images():
        ok = np.isfinite(img)
        total += np.where(ok, img, 0.0)
        n += ok
    mean = np.where(n > 1, total / np.maximum(n, 1), np.nan)
    scale = np.sqrt(n / np.maximum(n - 1.0, 1.0))
    for img, k in images():
        yield (img - mean) * scale, k


def read_noise_covariance(dark_frames, shape):
    """The read noise's covariance at each lag [e-^2], from the darks' group
    differences (hot pixels and their 5x5 neighbourhoods left out): ``{lag:
    (cov, error)}`` and ``correlation`` ``{lag: C(l) / C(0)}``; None when
    the darks have no two reads of ``shape``."""
    sums = NoiseSums(shape)
    used = False
    for f in dark_frames:
        if f.shape2d != tuple(shape) or f.data.shape[1] < 3 or f.meta.get("stack") != "ramp":
            continue
        rise = np.where(f.mask[:, -1] | f.mask[:, 0], np.nan, f.data[:, -1] - f.data[:, 0])
        n = np.sum(np.isfinite(rise), axis=0)
        level = np.where(n > 0, np.nansum(rise, axis=0) / np.maximum(n, 1), np.nan)
        good = level[np.isfinite(level)]
        if good.size < 100:
            continue
        med = np.median(good)
        sig = 1.4826 * np.median(np.abs(good - med))
        hot = ndimage.maximum_filter((~(level <= med + 10 * max(sig, 1e-9))).astype(np.uint8),
                                     size=5) > 0
        for img, i in _differences(f):
            sums.add(np.where(hot, np.nan, img), i % 2)
        used = True
    if not used:
        return None
    cov = sums.covariance(None)
    out = {lag: (float(c[0, 0]), float(e[0, 0])) for lag, (c, e) in cov.items()}
    return {"cov": out, "correlation": {lag: out[lag][0] / out[(0, 0)][0] for lag in LAGS}}


def flat_noise_sums(flat_frames, shape):
    """:class:`NoiseSums` of the flats of ``shape`` (None when there are none)."""
    sums, used = NoiseSums(shape), False
    for f in flat_frames:
        if f.shape2d != tuple(shape):
            continue
        if f.data.shape[0] * f.data.shape[1] < 3:
            continue
        for img, k in _differences(f):
            sums.add(img, k % 2)
        used = True
    return sums if used else None


def _flat_ratio(sums, s, folds, read_cov):
    """Per super-pixel ``(value, error)`` per lag: ``r(l) = C(l) / C(0)`` over the
    array's (read-noise covariance taken out)."""
    cov = sums.covariance(s, folds)
    whole = sums.covariance(None, folds)
    rc = read_cov or {}
    out = {}
    def ratio(c, lag):
        num = c[lag][0] - rc.get(lag, (0.0, 0.0))[0]
        den = c[(0, 0)][0] - rc.get((0, 0), (0.0, 0.0))[0]
        return num / den, c[lag][1] / den

    for lag in LAGS:
        r, e = ratio(cov, lag)
        r0 = ratio(whole, lag)[0][0, 0]
        out[lag] = (r / r0, np.abs(e / r0))
    return out


def hot_pixel_factors(events, nx, law, geometry, noise, min_signal=0.0):
    """Per hot pixel: ``y, x`` and the local map value of the x and y bonds
    with its expected error (``noise``, a neighbour's noise [e-], over the
    charge each neighbour holds).

    Each pixel's measurement of largest charge per integration is used (the
    groups of a ramp share its charge; the last has the least relative
    noise); several integrations are averaged. Measurements below
    ``min_signal`` [e-] are left out."""
    keep = np.asarray(events["signal"], float) >= float(min_signal)
    events = {k: np.asarray(v)[keep] for k, v in events.items()}
    s = np.asarray(events["signal"], float)
    frac = np.asarray(events["fraction"], float).reshape(-1, 5, 5)
    pixel = np.asarray(events["pixel"])
    key = pixel * 4096 + np.asarray(events["event"]) % 4096
    order = np.lexsort((-s, key))
    first = order[np.r_[True, key[order][1:] != key[order][:-1]]]
    rn = float(noise) if noise else 1.0
    out = {}
    for lag, sides in (((0, 1), (frac[:, 2, 3], frac[:, 2, 1])),
                       ((1, 0), (frac[:, 3, 2], frac[:, 1, 2]))):
        wa = geometry.weight(*lag) * law.alpha(s, np.asarray(events["background"], float))
        value = 0.5 * (sides[0] + sides[1]) / wa
        err = rn / np.sqrt(2.0) / np.maximum(s * wa, 1e-30)
        ids, inv = np.unique(pixel[first], return_inverse=True)
        w = 1.0 / err[first] ** 2
        num = np.bincount(inv, weights=w * value[first])
        den = np.bincount(inv, weights=w)
        out[lag] = (num / den, 1.0 / np.sqrt(den))
    return {"y": ids // nx, "x": ids % nx, "pixel": ids, **out}


def _hot_grid(factors, keep, s, grid):
    """Per super-pixel weighted mean of the hot pixels' factors and its error,
    scaled by the array's chi^2 per pixel (at least 1)."""
    j, i = factors["y"][keep] // s, factors["x"][keep] // s
    flat = j * grid[1] + i
    out = {}
    for lag in LAGS:
        v, e = factors[lag][0][keep], factors[lag][1][keep]
        w = 1.0 / e ** 2
        size = grid[0] * grid[1]
        den = np.bincount(flat, weights=w, minlength=size)
        mean = np.bincount(flat, weights=w * v, minlength=size) / np.maximum(den, 1e-300)
        resid = (v - mean[flat]) ** 2 * w
        cnt = np.bincount(flat, minlength=size)
        dof = np.sum(np.maximum(cnt - 1, 0))
        if dof >= MIN_DOF:
            chi2 = float(resid.sum() / dof)
        else:  # too few pixels share a super-pixel: their scatter about the array's mean
            m0 = np.sum(w * v) / np.sum(w)
            chi2 = float(np.sum(w * (v - m0) ** 2) / max(v.size - 1, 1))
        err = np.where(den > 0, np.sqrt(max(chi2, 1.0) / np.maximum(den, 1e-300)), np.inf)
        out[lag] = (mean.reshape(grid), err.reshape(grid))
    return out


def _raw_map(s, shape, flat=None, flat_folds=(0, 1), read_cov=None, factors=None,
             hot_keep=None):
    """The flats' and hot pixels' values on super-pixels of ``s`` combined by
    inverse variance: ``{lag: (value, error)}`` (value 1, error inf where
    nothing measured it)."""
    grid = (-(-shape[0] // s), -(-shape[1] // s))
    parts = []
    if flat is not None:
        parts.append(_flat_ratio(flat, s, flat_folds, read_cov))
    if factors is not None and len(factors["pixel"]):
        keep = np.ones(len(factors["pixel"]), bool) if hot_keep is None else hot_keep
        if keep.any():
            parts.append(_hot_grid(factors, keep, s, grid))
    out = {}
    for lag in LAGS:
        num, den = np.zeros(grid), np.zeros(grid)
        for p in parts:
            v, e = p[lag]
            w = np.where(np.isfinite(v) & np.isfinite(e) & (e > 0), 1.0 / np.square(e), 0.0)
            num += w * np.nan_to_num(v)
            den += w
        value = np.where(den > 0, num / np.maximum(den, 1e-300), 1.0)
        out[lag] = (value, np.where(den > 0, 1.0 / np.sqrt(np.maximum(den, 1e-300)), np.inf))
    return out


def superpixel_map(s, shape, **sources):
    """The map on super-pixels of ``s`` (``sources``: see :func:`_raw_map`):
    ``{lag: (value, error)}``, each super-pixel shrunk (:func:`_shrunk`) towards
    the map of super-pixels twice as large (recursively; the largest towards
    1, the law), so a super-pixel that little measured follows its surroundings."""
    raw = _raw_map(s, shape, **sources)
    grid = raw[LAGS[0]][0].shape
    coarser = 2 * s
    if min(shape) // coarser >= MIN_GRID:
        up = superpixel_map(coarser, shape, **sources)
        prior = {lag: np.repeat(np.repeat(v, 2, 0), 2, 1)[:grid[0], :grid[1]]
                 for lag, (v, _) in up.items()}
    else:
        prior = {lag: np.ones(grid) for lag in LAGS}
    return {lag: _shrunk(*raw[lag], prior[lag]) for lag in LAGS}


def _shrunk(value, error, prior):
    """Each super-pixel pulled towards ``prior`` by its error: ``p + (v - p) t^2 /
    (t^2 + e^2)``, ``t^2`` the spread of ``v - p`` beyond the errors (solved for
    by weighted moments, at least :data:`MIN_SPREAD` ^ 2): a super-pixel measured
    by noise alone (a few flat pixels, no hot pixel) keeps the prior instead of
    taking its noise into the map."""
    ok = np.isfinite(error)
    if not ok.any():
        return prior.copy(), error
    v, e2 = (value - prior)[ok], np.square(error[ok])
    t2 = MIN_SPREAD ** 2
    for _ in range(50):
        w = 1.0 / (e2 + t2) ** 2
        t2 = max(float(np.sum(w * (v * v - e2)) / np.sum(w)), MIN_SPREAD ** 2)
    e = np.where(ok, error, 0.0)
    gain = np.where(ok, t2 / (t2 + np.square(e)), 0.0)
    return prior + (value - prior) * gain, np.where(ok, np.sqrt(gain) * e, np.sqrt(t2))


def _choose_size(shape, **sources):
    """The super-pixel size (:data:`SUPERPIXELS`) and why: the smallest whose
    median raw error reaches :data:`MAP_PRECISION`, then one size finer (its
    super-pixels shrunk towards it), where the frame allows."""
    sizes = [s for s in SUPERPIXELS if min(shape) // s >= MIN_GRID]
    if not sizes:
        return None, f"the frame {shape[0]}x{shape[1]} is too small for {MIN_GRID} super-pixels"
    for k, s in enumerate(sizes):
        m = _raw_map(s, shape, **sources)
        med = float(np.median(np.concatenate([m[lag][1].ravel() for lag in LAGS])))
        if med <= MAP_PRECISION:
            finer = sizes[k - 1] if k else s
            return finer, (f"{s} px is the smallest super-pixel whose median error "
                           f"({100 * med:.1f} %) reaches {100 * MAP_PRECISION:.0f} %; the map "
                           f"is given at {finer} px, each super-pixel shrunk towards the "
                           "coarser map by its own error")
    return sizes[-1], (f"no size reaches a median error of {100 * MAP_PRECISION:.0f} % "
                       f"({100 * med:.1f} % at {sizes[-1]} px): the largest is used")


def to_bonds(coarse, s, geometry, shape):
    """A :class:`BondMap` of the x and y super-pixel maps (other offsets: their mean)."""
    mean = 0.5 * (coarse[(0, 1)] + coarse[(1, 0)])
    stack = [coarse.get(u, mean) for u, _ in geometry.half_stencil()]
    return BondMap.superpixels(geometry, np.clip(np.array(stack), 0.0, None), (s, s), shape)


def decouple_frame(frame, model):
    """Decouple one 2-D frame with ``model`` (with or without a map):
    :func:`ipc_taichi.decouple`."""
    return np.asarray(decouple(frame, model=model), float)


def _hot_residuals(integrations, keep_ids, model, nx):
    """Per held-out hot pixel: the 4 nearest neighbours' residual fraction after
    decoupling its stamp (largest-charge read) with ``model``: ``{pixel: r}``
    (the mean over integrations)."""
    out = {}
    for groups, positions in integrations:
        ids = positions[:, 0] * nx + positions[:, 1]
        kept = positions[np.isin(ids, keep_ids)]
        if not len(kept):
            continue
        stack, centres = mosaic(groups[-1:], kept)
        local = model
        if model.bonds is not None:
            values, _ = mosaic(np.asarray(model.bonds.values), kept)
            bonds = BondMap(model.bonds.offsets, np.nan_to_num(values, nan=1.0))
            local = CouplingModel(model.law, model.geometry, model.edge, bonds)
        frame = decouple_frame(stack[0], local)
        ev = hotpixels.measure_events(frame, centres)
        others = np.delete(ev["fraction"], 12, axis=1)
        good = np.all(np.abs(others) <= 0.1, axis=1)
        r = hotpixels.nn_fraction(ev)
        for e, ok, value in zip(ev["event"], good, r):
            if ok:
                pid = int(kept[e, 0] * nx + kept[e, 1])
                out.setdefault(pid, []).append(value)
    return {k: float(np.mean(vals)) for k, vals in out.items()}


def _paired_z(d):
    """``{mean, error, z, n}`` of paired differences ``d``."""
    d = np.asarray(d, float)
    if d.size < 3:
        return None
    mean = float(d.mean())
    err = float(d.std(ddof=1) / math.sqrt(d.size))
    return {"mean": mean, "error": err, "z": mean / err if err > 0 else 0.0, "n": int(d.size)}


def _flat_test_size(flat, s, shape, read_cov):
    """The grid of the flats' held-out test: the smallest size >= ``s`` whose
    held-out half has a median error <= :data:`FLAT_TEST_ERROR` (None and why
    when none has)."""
    med = None
    for size in (t for t in SUPERPIXELS if t >= s and min(shape) // t >= MIN_GRID):
        held = _flat_ratio(flat, size, (0,), read_cov)
        med = float(np.median(np.concatenate([held[lag][1].ravel() for lag in LAGS])))
        if med <= FLAT_TEST_ERROR:
            return size, None
    return None, ("the held-out flats are too noisy per super-pixel (median error "
                  + (f"{100 * med:.0f} %" if med is not None else "unknown")
                  + f" > {100 * FLAT_TEST_ERROR:.0f} %): more flat integrations or groups "
                  "would let them test the map")


def held_out_test(s, shape, law, geometry, *, flat=None, read_cov=None, factors=None,
                  integrations=(), nx=None, read_noise=None):
    """Does a map measured without each half beat the uniform law on that half?
    (module docstring). Returns ``hot`` and ``flat`` (``mean``, ``error``, ``z``,
    ``n``, or None), ``z`` (the decision's), RMS residuals, ``notes``."""
    uniform = CouplingModel.resolve(law, geometry, "zero")
    half = (hotpixels.fold_of(factors["pixel"], 2, seed=2) if factors is not None
            else np.zeros(0, int))
    notes = []
    flat_size = None
    if flat is not None:
        flat_size, why = _flat_test_size(flat, s, shape, read_cov)
        if why:
            notes.append(why)
    d_hot, d_flat, rms = [], [], {"uniform": [], "map": []}
    for h in (0, 1):
        train = superpixel_map(s, shape, flat=flat, flat_folds=(1 - h,), read_cov=read_cov,
                               factors=factors, hot_keep=None if factors is None else half != h)
        coarse = {lag: v for lag, (v, _) in train.items()}
        bonds = to_bonds(coarse, s, geometry, shape)
        mapped = CouplingModel.resolve(law, geometry, "zero", bonds=bonds)
        if factors is not None and integrations:
            ids = factors["pixel"][half == h]
            ru = _hot_residuals(integrations, ids, uniform, nx)
            rm = _hot_residuals(integrations, ids, mapped, nx)
            for pid in set(ru) & set(rm):
                d_hot.append(ru[pid] ** 2 - rm[pid] ** 2)
                rms["uniform"].append(ru[pid])
                rms["map"].append(rm[pid])
        if flat_size is not None:
            held = _flat_ratio(flat, flat_size, (h,), read_cov)
            for k, lag in enumerate(LAGS):
                v, e = held[lag]
                m = _blocks(bonds.values[k], flat_size) / _blocks(np.ones(shape), flat_size)
                ok = np.isfinite(v) & np.isfinite(e) & (e > 0)
                d_flat += list(((v[ok] - 1) ** 2 - (v[ok] - m[ok]) ** 2) / e[ok] ** 2)
    hot, flats = _paired_z(d_hot), _paired_z(d_flat)
    if factors is not None and hot is None:
        notes.append("fewer than 3 held-out hot pixels could be decoupled")
    zs = [t["z"] for t in (hot, flats) if t is not None]
    out = {"hot": hot, "flat": flats, "flat_superpixel": flat_size, "margin": MAP_MARGIN,
           "z": (None if not zs else float(min(zs)) if min(zs) <= -MAP_MARGIN
                 else float(max(zs))), "notes": notes,
           "rule": "the map is written when one held-out set prefers it by >= "
                   f"{MAP_MARGIN:g} standard errors and none prefers the uniform law by as much"}
    if rms["map"]:
        out["hot_rms"] = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in rms.items()}
    if not zs:
        notes.append("no held-out data: the map cannot be tested and is not written")
    return out


def measure_map(dark_frames, flat_frames, hot, law, geometry, read_noise, shape=None):
    """The map, its errors and the held-out test; ``bonds`` is the
    :class:`BondMap` to write, or None (with ``reason``)."""
    frames = list(dark_frames) + list(flat_frames)
    if not frames:
        return {"bonds": None, "written": False, "reason": "no darks or flats"}
    shape = tuple(shape or frames[0].shape2d)
    read_cov = read_noise_covariance(dark_frames, shape)
    rc = read_cov["cov"] if read_cov else None
    flat = flat_noise_sums(flat_frames, shape)
    factors, nx = None, shape[1]
    same = all(f.shape2d == shape for f in dark_frames)
    if hot.events is not None and same:
        factors = hot_pixel_factors(hot.events, nx, law, geometry,
                                    hot.floors["bins"] / hotpixels.BIN_FLOOR_READ_NOISE,
                                    min_signal=hot.floors["score"])
        if not len(factors["pixel"]):
            factors = None
    out = {"bonds": None, "written": False, "shape": list(shape), "read_cov": read_cov,
           "read_noise_correlation": (None if read_cov is None else
                                      {f"{dy},{dx}": c for (dy, dx), c
                                       in read_cov["correlation"].items()}),
           "sources": {"flats": flat is not None,
                       "hot_pixels": 0 if factors is None else int(len(factors["pixel"]))}}
    if flat is None and factors is None:
        out["reason"] = ("no flats of the darks' shape and no hot pixels: nothing measures "
                         "a map (give flat ramps, or darks with hot pixels)")
        return out
    sources = {"flat": flat, "read_cov": rc, "factors": factors}
    s, why = _choose_size(shape, **sources)
    if s is None:
        out["reason"] = why
        return out
    test = held_out_test(s, shape, law, geometry, flat=flat, read_cov=rc, factors=factors,
                         integrations=[(g, p) for g, p in hot.integrations
                                       if g.shape[-2:] == shape] if factors is not None else (),
                         nx=nx, read_noise=read_noise)
    final = superpixel_map(s, shape, **sources)
    coarse = {lag: v for lag, (v, _) in final.items()}
    out.update(superpixel=[s, s], superpixel_reason=why, test=test,
               x=coarse[(0, 1)].tolist(), x_error=final[(0, 1)][1].tolist(),
               y=coarse[(1, 0)].tolist(), y_error=final[(1, 0)][1].tolist())
    if test["z"] is not None and test["z"] >= MAP_MARGIN:
        out.update(bonds=to_bonds(coarse, s, geometry, shape), written=True,
                   reason=f"held-out data prefer the map by {test['z']:.1f} standard errors "
                          f"(>= {MAP_MARGIN:g})")
    else:
        out["reason"] = ("; ".join(test["notes"]) if test["z"] is None else
                         f"held-out data do not prefer the map ({test['z']:+.1f} standard "
                         f"errors; {test['rule']}): the model stays uniform")
    return out

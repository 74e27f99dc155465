"""Exact tiled decoupling: a frame decoupled tile by tile equals the whole frame.

Why it is exact
---------------
One Jacobi iteration updates a pixel from its neighbours up to ``reach``
pixels away (``reach`` = the geometry's furthest offset, 1 for nearest
neighbours). A tile cut out with a **halo** of ``h`` pixels has a false edge
where the halo ends; after ``q`` iterations the error that false edge causes
has travelled at most ``q * reach`` pixels inwards. With ``h >= n * reach``
the tile's core is therefore, after ``n`` iterations, bit for bit what the
whole-frame decoupler computes. Where a tile touches the real frame edge there
is no halo and the edge rule applies exactly as for the whole frame.

The stopping rule
-----------------
The paper's rule stops at the first ``q`` with ``max|S_q - S_(q-1)| <= tol *
max|S_q|``, the maxima taken over the *whole frame*, so a tile cannot decide
alone. Every tile reports the two maxima over its core for each iteration
(exact, by the argument above); the maximum over tiles is the whole-frame
maximum. The tiles are run in rounds of ``n = 4, 8, 16, ... max_iter``
iterations (halo ``n * reach``); the first round in which the global rule is met
at some ``q* <= n`` decides the count. If ``q* == n`` the round's results are the
answer; otherwise the tiles are run once more for exactly ``q*`` iterations.
On typical frames the rule stops after 4 iterations, so this costs one round
of 4 (the answer) or, at worst, about twice the whole-frame work. With
``tol=0`` a single round of ``max_iter`` iterations is run.

Frames larger than memory
-------------------------
:func:`decouple_blocks` takes ``read(window)`` and ``write(core, values)``
callables, so a frame can be read from memory-mapped file sections tile by
tile (the product pipeline does this for FITS) or its tiles decoupled on Dask
workers (``mapper``, :mod:`ipc_taichi.cluster`). This module holds arrays only.
"""

import dataclasses
import math
import sys

import numpy as np

from . import iteration, runtime
from .decoupling import DecoupleInfo, decouple
from .errors import IPCInputError
from .model import CouplingModel

__all__ = ["tiles", "halo_for", "tile_maxima", "decouple_blocks", "decouple_tiled",
           "window_model"]

FIRST_ROUND = 4


def halo_for(iterations, geometry):
    """The halo that makes ``iterations`` Jacobi iterations exact: ``iterations * reach``."""
    return int(iterations) * int(geometry.reach)


def window_model(model, window):
    """``model`` for the sub-frame ``window`` (a tuple of slices, a tile with
    its halo): its bond map cropped there (:meth:`~ipc_taichi.bondmap.BondMap.crop`);
    a uniform model as it is. The bonds leaving the window are those of the
    window's edge (the map's edge rule), which only its halo sees."""
    if model.bonds is None:
        return model
    ys, xs = window
    crop = model.bonds.crop(ys.start, xs.start, ys.stop - ys.start, xs.stop - xs.start)
    return dataclasses.replace(model, bonds=crop)


def tiles(shape, tile):
    """Core slices ``(ys, xs)`` covering a frame of ``shape`` with tiles of ``tile``
    (an int or ``(ty, tx)``), row by row."""
    ty, tx = (tile, tile) if np.isscalar(tile) else tile
    ty, tx = int(ty), int(tx)
    if ty < 1 or tx < 1:
        raise IPCInputError(f"tile size must be >= 1, got {tile!r}")
    ny, nx = shape
    for y0 in range(0, ny, ty):
        for x0 in range(0, nx, tx):
            yield slice(y0, min(ny, y0 + ty)), slice(x0, min(nx, x0 + tx))


def _with_halo(core, shape, halo):
    ys, xs = core
    outer = (slice(max(0, ys.start - halo), min(shape[0], ys.stop + halo)),
             slice(max(0, xs.start - halo), min(shape[1], xs.stop + halo)))
    inner = (slice(ys.start - outer[0].start, ys.stop - outer[0].start),
             slice(xs.start - outer[1].start, xs.stop - outer[1].start))
    return outer, inner


def tile_maxima(read, shape, core, halo, n, model, arch=None, precision=None, read_mask=None):
    """Decouple one tile for ``n`` iterations (tol 0); return its core result
    and the per-iteration maxima of ``|S_q - S_(q-1)|`` and ``|S_q|`` over the core.

    ``read(window)`` returns the measured values of a window of the frame;
    ``read_mask(window)``, if given, the boolean mask of untrusted pixels."""
    outer, inner = _with_halo(core, shape, halo)
    deltas, signals = [], []
    last = {}

    def record(q, estimate):
        now = np.asarray(estimate[inner], dtype=np.float64)
        change = np.abs(now - last["core"])
        # maxima over the pixels that have values (NaN pixels of the input
        # stay NaN in S_0; a core may have none at all)
        deltas.append(float(change.max(initial=0.0, where=~np.isnan(change))))
        signals.append(float(np.abs(now).max(initial=0.0, where=~np.isnan(now))))
        last["core"] = now.copy()

    measured = np.asarray(read(outer), dtype=np.float64)
    mask = None if read_mask is None else np.asarray(read_mask(outer), dtype=bool)
    # S_0 as the kernel sees it: bad pixels hold zero and never change
    good = np.isfinite(measured[inner])
    if mask is not None:
        good &= ~mask[inner]
    last["core"] = np.where(good, measured[inner], np.where(np.isfinite(measured[inner]), 0.0,
                                                            np.nan))
    signal = decouple(measured, model=window_model(model, outer), max_iter=n, tol=0, arch=arch,
                      precision=precision, callback=record, mask=mask)
    return signal[inner], deltas, signals


def decouple_blocks(read, write, shape, tile, model, max_iter=iteration.MAX_ITER,
                    tol=iteration.TOL, arch=None, precision=None, progress=False, mapper=None,
                    read_mask=None):
    """Decouple a frame tile by tile through ``read``/``write``; returns DecoupleInfo.

    The round logic shared by in-memory, file-backed and Dask tiling (see the
    module docstring). ``read(window)`` gives the measured values of a window
    (a tuple of slices), ``write(core, values)`` stores a core tile's result
    (``None``: count the iterations only), ``read_mask(window)`` the untrusted
    pixels, if any. ``mapper(n, halo, cores)`` decouples each core tile (``n``
    iterations, ``halo``) and yields ``(core result, deltas, signals)`` in order
    (default: :func:`tile_maxima` one tile after the other in this process;
    :mod:`ipc_taichi.cluster` runs them on Dask workers, ``read`` unused).
    Does not warn when the rule was not met (callers do, once per frame).
    """
    model = CouplingModel.resolve(model=model)
    if model.bonds is not None:
        model.bonds.check(model.geometry, shape)
    max_iter, tol = iteration.check_arguments(max_iter, tol)
    core_tiles = list(tiles(shape, tile))
    rounds = [max_iter] if tol == 0 else sorted(
        {min(max_iter, FIRST_ROUND * 2 ** k) for k in range(1 + math.ceil(math.log2(
            max(1, max_iter / FIRST_ROUND))))})
    info = DecoupleInfo(law=model.law.describe(), geometry=model.geometry.describe(),
                        edge=model.edge)
    bar = _progress_bar(progress, len(core_tiles))
    try:
        for n in rounds:
            stop, deltas, signals = _round(read, write, shape, core_tiles, n, model, tol,
                                           arch, precision, bar, mapper, read_mask)
            if stop is None and n < max_iter:
                continue
            if stop is not None and stop < n:
                # the answer is S_stop: run the tiles once more for exactly that many
                if write is not None:
                    _round(read, write, shape, core_tiles, stop, model, 0, arch, precision,
                           bar, mapper, read_mask)
                n = stop
            info.iterations = n
            info.converged = stop is not None
            info.max_delta, info.max_signal = deltas[:n], signals[:n]
            break
    finally:
        if bar is not None:
            bar.close()
    rt = runtime.current()  # None where only workers ran Taichi
    info.arch = rt.arch if rt else (arch or "")
    info.precision = rt.precision if rt else (precision or "")
    for q in range(1, len(info.max_delta) + 1):
        iteration.check_divergence(info.max_delta[:q], info.max_signal[:q])
    return info


def _round(read, write, shape, core_tiles, n, model, tol, arch, precision, bar, mapper=None,
           read_mask=None):
    halo = halo_for(n, model.geometry)
    deltas = np.zeros(n)
    signals = np.zeros(n)
    if mapper is None:
        results = (tile_maxima(read, shape, core, halo, n, model, arch, precision, read_mask)
                   for core in core_tiles)
    else:
        results = mapper(n, halo, core_tiles)
    for core, (result, d, s) in zip(core_tiles, results):
        if write is not None:
            write(core, result)
        deltas = np.maximum(deltas, d)
        signals = np.maximum(signals, s)
        if bar is not None:
            bar.update(1)
    return (iteration.first_met(deltas, signals, tol), list(map(float, deltas)),
            list(map(float, signals)))


def _progress_bar(progress, total):
    """A tqdm bar on stderr when asked for and stderr is a terminal."""
    if not progress or total <= 1 or not sys.stderr.isatty():
        return None
    from tqdm import tqdm  # here: a run without a bar does not load it (tqdm: ~20 ms)

    return tqdm(total=total, unit="tile", desc="decouple", file=sys.stderr, leave=False)


def decouple_tiled(measured, tile=512, law=None, geometry=None, edge=None,
                   max_iter=iteration.MAX_ITER, tol=iteration.TOL, arch=None, precision=None,
                   full_output=False, progress=False, *, model=None, mask=None):
    """Decouple a 2-D frame tile by tile; equal to :func:`ipc_taichi.decouple`.

    Parameters
    ----------
    measured : array_like, shape (ny, nx)
        The frame (may be a ``np.memmap``; only one tile plus halo is read at a time).
    tile : int or (int, int)
        Core tile size; each tile is read with a halo of ``iterations * reach``.
    law, geometry, edge, max_iter, tol, arch, precision, model, mask :
        As for :func:`ipc_taichi.decouple` (same stopping rule, decided on the
        whole frame: see the module docstring).
    full_output : bool
        Also return a :class:`DecoupleInfo`.
    progress : bool
        Show a progress bar (only when stderr is a terminal).

    Returns
    -------
    signal : ndarray (float64), and info with ``full_output``.
    """
    frame = measured if isinstance(measured, np.ndarray) else np.asarray(measured)
    if isinstance(frame, np.ma.MaskedArray):
        own = np.ma.getmaskarray(frame)
        mask = own if mask is None else own | np.asarray(mask, dtype=bool)
        frame = frame.data
    if frame.ndim != 2 or frame.size == 0:
        raise IPCInputError(f"decouple_tiled: expected a non-empty 2-D frame, got shape "
                            f"{frame.shape}")
    if mask is not None:
        mask = np.broadcast_to(np.asarray(mask, dtype=bool), frame.shape)
    model = CouplingModel.resolve(law, geometry, edge, model=model)
    out = np.empty(frame.shape, dtype=np.float64)

    def read(window):
        return frame[window]

    def write(core, values):
        out[core] = values

    read_mask = None if mask is None else mask.__getitem__
    info = decouple_blocks(read, write, frame.shape, tile, model, max_iter, tol, arch,
                           precision, progress, read_mask=read_mask)
    iteration.warn_unconverged(info, max_iter, tol)
    return (out, info) if full_output else out

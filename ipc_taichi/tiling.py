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
:func:`decouple_fits_tiled` reads the input through memory-mapped FITS
sections tile by tile and writes the result into a memory-mapped output file
created at a temporary path beside the destination and renamed into place
only when complete (nothing partial at the output path).
"""

import math
import os

import numpy as np

from ._engine import resolve_model
from .decoupling import DecoupleInfo, decouple
from .errors import ConvergenceWarning, DivergenceError, IPCInputError

__all__ = ["tiles", "decouple_tiled", "decouple_fits_tiled", "halo_for"]

FIRST_ROUND = 4


def halo_for(iterations, geometry):
    """The halo that makes ``iterations`` Jacobi iterations exact: ``iterations * reach``."""
    return int(iterations) * int(geometry.reach)


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


def _core_maxima(read, shape, core, halo, n, model, arch, precision):
    """Decouple one tile for ``n`` iterations (tol 0); return its core result
    and the per-iteration maxima of ``|S_q - S_(q-1)|`` and ``|S_q|`` over the core."""
    outer, inner = _with_halo(core, shape, halo)
    law, geometry, edge = model
    deltas, signals = [], []
    last = {}

    def record(q, estimate):
        now = np.asarray(estimate[inner], dtype=np.float64)
        before = last.get("core")
        deltas.append(float(np.nanmax(np.abs(now - before))) if np.isfinite(now).any() else 0.0)
        signals.append(float(np.nanmax(np.abs(now))) if np.isfinite(now).any() else 0.0)
        last["core"] = now.copy()

    measured = np.asarray(read(outer), dtype=np.float64)
    good = np.where(np.isfinite(measured[inner]), measured[inner], np.nan)
    last["core"] = good
    signal = decouple(measured, law=law, geometry=geometry, edge=edge, max_iter=n, tol=0,
                      arch=arch, precision=precision, callback=record)
    return signal[inner], deltas, signals


def _run(read, write, shape, tile, law, geometry, edge, max_iter, tol, arch, precision,
         progress, mapper=None):
    """The round logic shared by in-memory, FITS and Dask tiling; returns DecoupleInfo.

    ``mapper(n, halo, cores)`` decouples each core tile (``n`` iterations,
    ``halo``) and yields ``(core result, deltas, signals)`` in order (default:
    :func:`_core_maxima` one tile after the other in this process;
    :mod:`ipc_taichi.cluster` runs them on Dask workers, ``read`` unused).
    ``write`` may be ``None`` (count the iterations only)."""
    model = resolve_model(law, geometry, edge)
    max_iter = int(max_iter)
    if max_iter < 1:
        raise IPCInputError(f"max_iter must be >= 1, got {max_iter}")
    core_tiles = list(tiles(shape, tile))
    rounds = [max_iter] if tol == 0 else sorted(
        {min(max_iter, FIRST_ROUND * 2 ** k) for k in range(1 + math.ceil(math.log2(
            max(1, max_iter / FIRST_ROUND))))})
    info = DecoupleInfo(law=model[0].describe(), geometry=model[1].describe(), edge=edge)
    bar = _progress_bar(progress, len(core_tiles))
    try:
        for n in rounds:
            stop, deltas, signals = _round(read, write, shape, core_tiles, n, model, tol,
                                           arch, precision, bar, mapper)
            if stop is None and n < max_iter:
                continue
            if stop is not None and stop < n:
                # the answer is S_stop: run the tiles once more for exactly that many
                if write is not None:
                    _round(read, write, shape, core_tiles, stop, model, 0, arch, precision,
                           bar, mapper)
                n = stop
            info.iterations = n
            info.converged = stop is not None
            info.max_delta, info.max_signal = deltas[:n], signals[:n]
            break
    finally:
        if bar is not None:
            bar.close()
    from . import runtime

    rt = runtime.current()  # None where only workers ran Taichi
    info.arch = rt.arch if rt else (arch or "")
    info.precision = rt.precision if rt else (precision or "")
    _check_divergence(info)
    return info


def _round(read, write, shape, core_tiles, n, model, tol, arch, precision, bar, mapper=None):
    halo = halo_for(n, model[1])
    deltas = np.zeros(n)
    signals = np.zeros(n)
    if mapper is None:
        results = (_core_maxima(read, shape, core, halo, n, model, arch, precision)
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
    stop = None
    if tol > 0:
        for q in range(n):
            if deltas[q] <= tol * signals[q]:
                stop = q + 1
                break
    return stop, list(map(float, deltas)), list(map(float, signals))


def _check_divergence(info):
    d = info.max_delta
    if not all(np.isfinite(d)) or not all(np.isfinite(info.max_signal)):
        raise DivergenceError("decouple diverged: non-finite values; the law/geometry is too "
                              "strong for this data")
    rising = 0
    for q in range(1, len(d)):
        rising = rising + 1 if d[q] > d[q - 1] else 0
        if rising >= 3:
            raise DivergenceError(f"decouple diverged: max|dS| grew 3 iterations running "
                                  f"({', '.join(f'{v:.3g}' for v in d[q - 3:q + 1])})")


def _progress_bar(progress, total):
    """A tqdm bar on stderr when asked for and stderr is a terminal."""
    import sys

    if not progress or total <= 1 or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="tile", desc="decouple", file=sys.stderr, leave=False)


def decouple_tiled(measured, tile=512, law="donlon2018", geometry=None, edge="zero",
                   max_iter=20, tol=1e-5, arch=None, precision=None, full_output=False,
                   progress=False):
    """Decouple a 2-D frame tile by tile; equal to :func:`ipc_taichi.decouple`.

    Parameters
    ----------
    measured : array_like, shape (ny, nx)
        The frame (may be a ``np.memmap``; only one tile plus halo is read at a time).
    tile : int or (int, int)
        Core tile size; each tile is read with a halo of ``iterations * reach``.
    law, geometry, edge, max_iter, tol, arch, precision :
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
    if frame.ndim != 2 or frame.size == 0:
        raise IPCInputError(f"decouple_tiled: expected a non-empty 2-D frame, got shape "
                            f"{frame.shape}")
    out = np.empty(frame.shape, dtype=np.float64)

    def read(window):
        return frame[window]

    def write(core, values):
        out[core] = values

    info = _run(read, write, frame.shape, tile, law, geometry, edge, max_iter, tol, arch,
                precision, progress)
    _warn_unconverged(info, max_iter, tol)
    return (out, info) if full_output else out


def _warn_unconverged(info, max_iter, tol):
    if tol > 0 and not info.converged:
        import warnings

        warnings.warn(f"decouple did not meet the stopping rule in {max_iter} iterations "
                      f"(last max|dS| = {info.max_delta[-1]:.3g})", ConvergenceWarning,
                      stacklevel=3)


def decouple_fits_tiled(input_path, output_path, hdu=None, tile=1024, overwrite=False,
                        law="donlon2018", geometry=None, edge="zero", max_iter=20, tol=1e-5,
                        arch=None, precision=None, progress=False, keywords=None, history=()):
    """Decouple a FITS image larger than memory, tile by tile.

    The input HDU is memory-mapped and read one tile plus halo at a time
    (a 3-D cube frame by frame); the float64 result is written into a
    memory-mapped primary HDU at a temporary path beside ``output_path``,
    renamed into place when complete. The input header is kept (minus
    structural and scaling keywords); ``keywords`` and ``history`` are added.

    Returns the list of :class:`DecoupleInfo`, one per frame.
    """
    from astropy.io import fits

    from .fitsio import atomic_output, parse_hdu

    if not os.path.exists(input_path):
        raise IPCInputError(f"{input_path}: no such file")
    try:
        hdul = fits.open(input_path, memmap=True)
    except Exception as exc:
        raise IPCInputError(f"{input_path}: not a readable FITS file ({type(exc).__name__})") \
            from None
    with hdul:
        hdu = parse_hdu(hdu)
        if hdu is None:
            hdu = next((k for k, h in enumerate(hdul) if h.is_image
                        and h.header.get("NAXIS", 0) > 0), None)
            if hdu is None:
                raise IPCInputError(f"{input_path}: no HDU holds image data")
        try:
            src = hdul[hdu]
        except (KeyError, IndexError):
            raise IPCInputError(f"{input_path}[{hdu}]: no such HDU") from None
        if not src.is_image or src.header.get("NAXIS", 0) not in (2, 3):
            raise IPCInputError(f"{input_path}[{hdu}]: expected a 2-D image or 3-D cube")
        shape = tuple(src.header[f"NAXIS{k}"] for k in range(src.header["NAXIS"], 0, -1))
        header = _output_header(src.header, shape, keywords, history)
        infos = []
        with atomic_output(output_path, overwrite) as tmp:
            _allocate_fits(tmp, header, shape)
            with fits.open(tmp, mode="update", memmap=True) as out_hdul:
                out = out_hdul[0].data
                frames = shape[0] if len(shape) == 3 else 1
                for k in range(frames):
                    def read(window, k=k):
                        sec = src.section[(k,) + window] if len(shape) == 3 else \
                            src.section[window]
                        return np.asarray(sec, dtype=np.float64)

                    def write(core, values, k=k):
                        (out[k] if len(shape) == 3 else out)[core] = values

                    infos.append(_run(read, write, shape[-2:], tile, law, geometry, edge,
                                      max_iter, tol, arch, precision, progress))
                    _warn_unconverged(infos[-1], max_iter, tol)
                out_hdul.flush()
    return infos


def _output_header(header, shape, keywords, history):
    from astropy.io import fits

    from .fitsio import output_header

    out = fits.Header([("SIMPLE", True), ("BITPIX", -64), ("NAXIS", len(shape))]
                      + [(f"NAXIS{k + 1}", n) for k, n in enumerate(reversed(shape))])
    out.extend(output_header(header, keywords, history), end=True)
    return out


def _allocate_fits(path, header, shape):
    """Create a FITS file of ``header`` and zero data of ``shape`` without
    holding the data in memory (the file is extended, not written)."""
    text = header.tostring()
    nbytes = int(np.prod(shape)) * 8
    padded = -(-nbytes // 2880) * 2880
    with open(path, "wb") as f:
        f.write(text.encode("ascii"))
        f.truncate(len(text) + padded)

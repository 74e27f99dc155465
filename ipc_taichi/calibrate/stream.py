"""Flat ramps too large for memory, read by sections.

A Roman-size flat set (8 ramps of 4096 x 4096 x 20 reads) is 21 GB as
float64 electrons. Flat ramps whose float64 charge, all the flats together,
would exceed :data:`STREAM_BYTES` are therefore not read whole:
:class:`LazyCharge` reads the stored values of the section asked for (a
memory map of the file opened for that section only; BSCALE, BZERO and BLANK
applied here, as astropy applies them, e.g. to uint16 stored as int16 +
32768) and gives the same float64 electrons and mask as the whole-file reader
(:func:`.inputs.read_frames`): the value times the gain, the first read
subtracted from a raw integer ramp, NaN where masked (the DQ bits, SATURATE,
non-finite values, the reference border). The measuring code reads such a
ramp by row strips (:func:`row_strips`); :mod:`.rampsums` accumulates its
block sums strip by strip, so no whole cube is held in float64. Smaller sets
are read whole, as before. Compressed files are read whole.
"""

import itertools

import numpy as np

from ..fitsio import parse_hdu
from ..products import conventions as cv
from ..products.fitsfile import (
    RawImage,
    compression,
    is_compressed,
    open_fits,
    science_indices,
    shape_of,
)

__all__ = ["STREAM_BYTES", "STRIP_BYTES", "LazyCharge", "RampSource", "is_lazy",
           "concatenate", "row_strips", "flats_by_sections", "readable_by_sections",
           "increment_variances"]

STREAM_BYTES = 1 << 30
"""Flat ramps whose float64 charge, all files together, exceeds this many bytes
are read by sections."""

STRIP_BYTES = 1 << 27
"""Float64 bytes of one row strip (all integrations and reads of its rows)."""


def flats_by_sections(paths, hdu=None):
    """Whether the flats ``paths`` are read by sections: their science arrays
    (by their headers; a file that cannot be read counts nothing here and is
    refused by the reader) hold more than :data:`STREAM_BYTES` as float64."""
    total = 0
    for path in paths:
        try:
            with open_fits(path) as hdul:
                index = science_indices(path, hdul, parse_hdu(hdu), raw_ok=True)[0][0]
                total += 8 * int(np.prod(shape_of(hdul[index].header)))
        except Exception:  # not FITS (ASDF), unreadable: the reader says why
            continue
    return total > STREAM_BYTES


def row_strips(ny, row_bytes, budget=None):
    """Row slices of ``ny`` rows, each of at most ``budget`` bytes (default
    :data:`STRIP_BYTES`) at ``row_bytes`` a row; one slice when all fit."""
    budget = STRIP_BYTES if budget is None else budget
    rows = max(1, int(budget // max(int(row_bytes), 1)))
    return [slice(y, min(y + rows, ny)) for y in range(0, ny, rows)]


def is_lazy(array):
    """Whether ``array`` is read on indexing (a :class:`LazyCharge`)."""
    return isinstance(array, LazyCharge)


def concatenate(arrays):
    """``np.concatenate`` along integrations, kept lazy for lazy inputs."""
    if any(is_lazy(a) for a in arrays):
        return LazyCharge([s for a in arrays for s in _sources_of(a)], arrays[0].kind)
    return np.concatenate(arrays)


def _sources_of(a):
    if is_lazy(a):
        return a.sources
    raise TypeError("cannot stack a lazy ramp with one held in memory")


class RampSource:
    """One FITS science array (nints, ngroups, ny, nx), read by sections.

    Each section is copied out of a memory map opened for it and closed
    after it, so the process holds no more of the file than the section
    (a map kept open would count every page read in the resident memory).

    Parameters
    ----------
    path : str
    hdul : HDUList
        The open file (its headers and data offsets are read here).
    index : int
        The science HDU.
    scale : float or ndarray (ny, nx)
        e- per data unit.
    flags : list of int
        Bit-flag HDUs (DQ, PIXELDQ, GROUPDQ) of the science array.
    bits, saturated_bits : int
        DQ bits left out; those that say saturated.
    inside : ndarray (ny, nx) of bool or None
        Reference-flagged pixels inside the science region.
    region : (slice, slice)
        The science region (outside it: masked).
    level : float or None
        Saturation [e-]: reads at or above it are saturated.
    raw : bool
        A raw integer ramp: its first read is subtracted.
    """

    def __init__(self, path, hdul, index, scale, flags, bits, saturated_bits, inside, region,
                 level, raw):
        self.path = path
        self._images = {k: RawImage(path, hdul, k) for k in [index] + list(flags)}
        self._index, self._flags = index, list(flags)
        self.shape = self._images[index].shape
        self._scale = scale
        self._bits, self._sat_bits, self._inside = bits, saturated_bits, inside
        self._outside = np.ones(self.shape[-2:], dtype=bool)
        self._outside[region] = False
        self._level, self._raw = level, raw
        self._number = next(_NUMBERS)  # names it in the first-read slot (an id is reused)

    def _values(self, index, key):
        """Values of HDU ``index`` at ``key`` (its trailing axes), scaled as
        astropy scales them (:class:`~ipc_taichi.products.fitsfile.RawImage`);
        bit flags as integers."""
        image = self._images[index]
        part = image[key[len(key) - len(image.shape):]]
        return np.asarray(part, dtype=np.int64 if index != self._index else np.float64)

    def _read(self, key):
        """Charge [e-] as stored (before the first read is subtracted), the mask
        of the DQ bits, inside pixels and gain, and the saturated reads."""
        rows, cols = key[-2:]
        scale = self._scale[rows, cols] if np.ndim(self._scale) == 2 else self._scale
        data = self._values(self._index, key) * scale
        flags = [self._values(k, key) for k in self._flags]
        inside = None if self._inside is None else self._inside[rows, cols]
        mask = cv.untrusted(flags, self._bits, data.shape, inside,
                            gain=scale if np.ndim(scale) == 2 else None)
        mask = np.zeros(data.shape, bool) if mask is None else mask
        sat = cv.untrusted(flags, self._sat_bits, data.shape)
        sat = np.zeros(data.shape, bool) if sat is None else sat
        if self._level is not None:
            with np.errstate(invalid="ignore"):
                sat |= data >= self._level
        return data, mask, sat

    def _first_read(self, i, rows, cols):
        """The first read of integration ``i`` (charge, mask), kept for the next
        call (one for all sources: a frame each would add up over a set)."""
        tag = (self._number, i, rows.start, rows.stop, rows.step, cols.start, cols.stop, cols.step)
        if _FIRST[0] != tag:
            _FIRST[:] = [None, None]  # the old one goes before the new one is read
            data, mask, sat = self._read((i, slice(0, 1), rows, cols))
            _FIRST[:] = [tag, (data, mask | sat)]
        return _FIRST[1]

    def section(self, i, groups, rows, cols, kind):
        """``kind`` ("data", "mask" or "saturated") of integration ``i``,
        ``groups`` (a slice), ``rows``, ``cols`` (slices): (groups, rows, cols)."""
        data, mask, sat = self._read((i, groups, rows, cols))
        if kind == "saturated":
            return sat
        if self._raw:
            first, first_mask = self._first_read(i, rows, cols)
            mask |= sat
            mask |= first_mask
            data -= first
        mask |= ~np.isfinite(data)
        mask |= self._outside[rows, cols]
        if kind == "mask":
            return mask
        data[mask] = np.nan
        return data


class LazyCharge:
    """Charge [e-] (or its mask) of ramps (nints, ngroups, ny, nx), read on
    indexing: integers and slices on every axis; one integer alone gives the
    integration (ngroups, ny, nx), still lazy.

    Parameters
    ----------
    sources : list of (RampSource, int)
        Each source with the integrations it holds, stacked in order.
    kind : {"data", "mask", "saturated"}
    """

    def __init__(self, sources, kind="data", fixed=None):
        self.sources, self.kind, self._fixed = list(sources), kind, fixed
        first = self.sources[0][0].shape
        self._nints = sum(n for _, n in self.sources)
        full = (self._nints,) + tuple(first[1:])
        self.shape = full if fixed is None else full[1:]
        self.dtype = np.dtype(bool) if kind != "data" else np.dtype(np.float64)

    @property
    def ndim(self):
        return len(self.shape)

    def like(self, kind):
        """The same ramps' ``kind``."""
        return LazyCharge(self.sources, kind, self._fixed)

    def __array__(self, dtype=None, copy=None):
        raise TypeError(f"{self.sources[0][0].path}: a ramp read by sections is never "
                        "held whole; index it (rows, blocks)")

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        if self._fixed is not None:
            key = (self._fixed,) + key
        elif len(key) == 1 and isinstance(key[0], (int, np.integer)):
            return LazyCharge(self.sources, self.kind, range(self._nints)[key[0]])
        if len(key) > 4 or any(k is Ellipsis or k is None for k in key):
            raise IndexError(f"lazy ramps take integers and slices, got {key!r}")
        key = key + (slice(None),) * (4 - len(key))
        ints = key[0]
        squeeze = tuple(n for n, k in enumerate(key) if isinstance(k, (int, np.integer)))
        wanted = [ints] if isinstance(ints, (int, np.integer)) else list(
            range(self._nints)[ints])
        wanted = [range(self._nints)[i] for i in wanted]
        groups, rows, cols = (slice(range(n)[k], range(n)[k] + 1)
                              if isinstance(k, (int, np.integer)) else k
                              for k, n in zip(key[1:], self.shape[-3:], strict=True))
        g = range(self.shape[-3])[groups]
        rows = _positive(rows, self.shape[-2])
        cols = _positive(cols, self.shape[-1])
        groups = _positive(groups, self.shape[-3])
        parts = [self._source(i)[0].section(self._source(i)[1], groups, rows, cols, self.kind)
                 for i in wanted]
        if not parts:
            return np.zeros((0, len(g), len(range(self.shape[-2])[rows]),
                             len(range(self.shape[-1])[cols])), self.dtype)
        out = np.stack(parts)
        return out.reshape(tuple(s for n, s in enumerate(out.shape) if n not in squeeze))

    def _source(self, i):
        for source, n in self.sources:
            if i < n:
                return source, i
            i -= n
        raise IndexError(i)


_NUMBERS = itertools.count()

_FIRST = [None, None]
"""The last first read given (its tag, (charge, mask)): one frame, whatever the source."""

def readable_by_sections(path, hdul, index):
    """Whether HDU ``index`` is stored plainly (not compressed) and can be read
    by sections."""
    return compression(path) is None and not any(is_compressed(h) for h in hdul)


def _positive(s, n):
    """A slice with explicit non-negative bounds (memmap reads, cache keys)."""
    start, stop, step = s.indices(n)
    if step < 0:
        raise IndexError("lazy ramps are read forwards")
    return slice(start, max(start, stop), step)


def increment_variances(data, mask):
    """The variance across pixels of each increment (nints, ngroups - 1) of
    ramps [e-^2], NaN and masked pixels left out, and the mean absolute
    increment [e-]; one increment at a time."""
    nints, ngroups = data.shape[:2]
    m = None if is_lazy(data) else np.asarray(mask, bool)  # lazy charge is NaN where masked
    var = np.full((nints, max(ngroups - 1, 0)), np.nan)
    total, count = 0.0, 0
    for i in range(nints):
        prev = None
        for g in range(ngroups):
            frame = data[i, g]
            if m is not None:
                frame = np.where(m if m.ndim == 2 else m[i, g], np.nan, frame)
            if prev is not None:
                inc = (frame - prev).ravel()
                ok = np.isfinite(inc)
                if ok.any():
                    var[i, g - 1] = np.nanvar(inc)
                    total += float(np.abs(inc[ok]).sum())
                    count += int(ok.sum())
            prev = frame
    return var, (total / count if count else float("nan"))

"""The two ways a FITS science array goes through the correction: whole, or
tile by tile through memory maps (frames larger than memory).

Both apply the same rules (:mod:`ipc_taichi.products.conventions`); the
tiled result equals the whole-frame one (see :mod:`ipc_taichi.tiling`).
"""

import warnings

import numpy as np

from ..interrupts import check_stop
from ..tiling import decouple_blocks, tiles
from . import conventions as cv
from .checks import FrameLost, LostFrames
from .correction import correct_frames, named
from .fitsfile import RawImage, read_array

__all__ = ["Flags", "whole", "tiled"]


class Flags:
    """The bit-flag arrays of one science HDU, whole or as windows, and the
    pixels they (and the other rules) leave out."""

    def __init__(self, path, hdul, indices, bits, plan, saturation, tile):
        """``plan``: the array's :class:`~ipc_taichi.products.plan.ArrayPlan`
        (its frames' shape, reference pixels inside the region, arrangement)."""
        self.shape = plan.science_shape
        self.bits = bits
        self.inside = plan.inside
        self.saturation = saturation
        indices = indices if bits else []
        ndim = len(self.shape)
        if tile:
            self.sources = [(RawImage(path, hdul, k), ndim - hdul[k].header["NAXIS"])
                            for k in indices]
        else:
            science = plan.arrangement.to_science
            self.sources = [(science(read_array(path, hdul, k)), ndim - hdul[k].header["NAXIS"])
                            for k in indices]

    def whole(self, region, data):
        """The mask of the whole array (None when nothing is left out)."""
        inside = None
        if self.inside is not None:
            inside = np.zeros(self.shape[-2:], dtype=bool)
            inside[region] = self.inside
        return cv.untrusted([src for src, _ in self.sources], self.bits, self.shape, inside,
                            values=data, saturation=self.saturation)

    def window(self, lead, region, window, values):
        """The mask of frame ``lead`` (leading indices), window ``window`` of
        the science region (None when nothing is left out)."""
        full = tuple(slice(r.start + w.start, r.start + w.stop) for r, w in zip(region, window))
        shape = tuple(s.stop - s.start for s in full)
        flags = [np.asarray(src[tuple(lead[n:]) + full]) for src, n in self.sources]
        inside = None if self.inside is None else self.inside[window]
        return cv.untrusted(flags, self.bits, shape, inside, values=values,
                            saturation=self.saturation)


def whole(path, hdul, plan, out, flags, settings, record=None, noise=None, written=None):
    """Correct the science HDU of ``plan`` (its
    :class:`~ipc_taichi.products.plan.ArrayPlan`) in memory into ``out`` (a
    memory map of the output), by
    :func:`~ipc_taichi.products.correction.correct_frames` with the run's
    ``settings``; ``record``: the
    :class:`~ipc_taichi.products.conventions.Unphysical` of this HDU; an
    interleaved frame is corrected in its contiguous image, every other sample
    copied (``noise``: in the contiguous image); ``written(frame)`` is called
    with each frame of ``out`` once it is written (its writeback started:
    :meth:`~ipc_taichi.products.pages.OutputPages.written`)."""
    original = read_array(path, hdul, plan.index)
    arrangement = plan.arrangement
    data = arrangement.to_science(original)
    target = out if arrangement.identity else np.empty(data.shape, out.dtype)
    _, infos = correct_frames(data, plan, settings, mask=flags.whole(plan.region, data),
                              out=target, noise=noise, record=record,
                              written=written if arrangement.identity else None)
    if not arrangement.identity:
        out[...] = arrangement.from_science(target, np.asarray(original))
    return infos


def tiled(path, hdul, plan, out, flags, settings, record=None, written=None):
    """Decouple every frame of the science HDU of ``plan`` tile by tile (read
    and write through memory maps; ``settings.tile``); ``record`` as for
    :func:`whole`. A frame of a stack with nothing to decouple is left as it
    came and said once, as :func:`whole` leaves it
    (:class:`~ipc_taichi.products.checks.LostFrames`); ``written`` as for
    :func:`whole`."""
    record = record if record is not None else cv.Unphysical(settings.unphysical)
    region, label, tile = plan.region, plan.label, settings.tile
    source = RawImage(path, hdul, plan.index)
    shape = source.shape
    ny, nx = region[0].stop - region[0].start, region[1].stop - region[1].start
    s = np.asarray(plan.scale, dtype=np.float64)
    infos = []
    leads = list(np.ndindex(*shape[:-2])) if len(shape) > 2 else [()]
    lost = LostFrames(len(leads))
    # pixels outside the region (reference pixels) are copied unchanged
    for lead in leads:
        for ys, xs in _strips(shape[-2:]):
            out[lead + (ys, xs)] = source[lead + (ys, xs)]
    for k, lead in enumerate(leads):
        where = f"{label} frame {k}" if len(leads) > 1 else label

        def full(window):
            return tuple(slice(r.start + w.start, r.start + w.stop)
                         for r, w in zip(region, window))

        def factor(window):
            return s[full(window)] if s.ndim == 2 else s

        # NaN pixels travel as masked pixels holding zero (the same rule: neither
        # gives nor takes charge), so that no tile is ever all NaN
        def read(window, lead=lead):
            values = source[lead + full(window)] * factor(window)
            return np.where(np.isfinite(values), values, 0.0)

        def flagged(window, lead=lead):
            """Pixels of ``window`` left out by the flags and the gain."""
            values = source[lead + full(window)]
            m = np.zeros(values.shape, dtype=bool)
            by_flags = flags.window(lead, region, window, values)
            if by_flags is not None:
                m |= by_flags
            if s.ndim == 2:
                m |= cv.unusable_gain(factor(window))
            return values, m

        def read_mask(window, flagged=flagged):
            values, m = flagged(window)
            m |= ~np.isfinite(values)
            if record.action == "mask":
                m |= cv.unphysical(values * factor(window))
            return m

        def write(core, values, lead=lead):
            check_stop()  # a SIGINT/SIGTERM swallowed by a library stops the run here
            with np.errstate(divide="ignore", invalid="ignore"):  # no gain: masked below
                result = values / factor(core)
            out[lead + full(core)] = np.where(read_mask(core), source[lead + full(core)],
                                              result)

        try:
            _scan(flagged, factor, (ny, nx), tile, where, record,
                  (region[0].start, region[1].start))  # one read pass
        except FrameLost as exc:  # one frame of a stack: left as it came, said
            infos.append(lost.keep(exc, "decouple"))
            _copy(out, source, lead, region)
        else:
            with named(where):
                infos.append(decouple_blocks(read, write, (ny, nx), tile, plan.model,
                                             max_iter=settings.max_iter, tol=settings.tol,
                                             arch=settings.arch, precision=settings.precision,
                                             progress=settings.progress, read_mask=read_mask))
        if written is not None:
            written(out[lead])
    record.warn(label)
    if lost.said():
        warnings.warn(lost.said(), cv.ProductWarning, stacklevel=2)
    return infos


def _strips(shape, rows=256):
    for y0 in range(0, shape[0], rows):
        yield slice(y0, min(shape[0], y0 + rows)), slice(0, shape[1])


def _copy(out, source, lead, box, rows=256):
    """``out = source`` in ``box`` of frame ``lead``, ``rows`` rows at a time."""
    ys, xs = box
    for y0 in range(ys.start, ys.stop, rows):
        part = lead + (slice(y0, min(ys.stop, y0 + rows)), xs)
        out[part] = source[part]


def _scan(flagged, factor, shape, tile, where, record, origin):
    """One pass over the core tiles: count the unphysical pixels into
    ``record``; :class:`~ipc_taichi.products.checks.FrameLost` for a frame with
    no finite pixel left to decouple."""
    usable = False
    for core in tiles(shape, tile):
        values, m = flagged(core)
        with np.errstate(invalid="ignore"):
            charge = values * factor(core)
        bad = record.add(charge, m, where, (origin[0] + core[0].start,
                                            origin[1] + core[1].start))
        if bad is not None:
            m |= bad
        usable = usable or bool((np.isfinite(values) & ~m).any())
    if not usable:
        raise FrameLost(f"{where}: no finite, unmasked pixel to decouple (all NaN, flagged "
                        "or unphysical)")

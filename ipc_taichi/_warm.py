"""Warm starts for the frames of a stack (``decouple(stack, warm_start=True)``).

:class:`WarmStart` is used by :func:`ipc_taichi._engine.run_decouple`: after
each frame it keeps the frame's correction ``S - M`` and the shift the next
frame starts from; on the host path the engine adds that shift while it loads
the next frame, on the device path :meth:`WarmStart.apply` does with a kernel.
On the CPU's ``lanes`` layout both are one vector pass each
(:func:`lanes_warm_kernels`): the keep writes ``c`` alone, the start
``S_0 = M + (c_1 + (c_1 - c_2))`` is written from the padded measured frame.
"""

import collections

import numpy as np

from . import runtime
from ._lanes import lane_count

__all__ = ["WarmStart", "warm_kernels", "lanes_warm_kernels"]


class WarmStart:
    """The start of frame ``k`` from the answers of the frames before it.

    With ``c_k = S_k - M_k`` the correction of frame ``k`` (its answer minus
    its measured frame), frame ``k`` starts from ``S_0 = M_k + c_(k-1)`` (the
    previous solution plus the new charge ``M_k - M_(k-1)``) at the second
    frame, and from ``S_0 = M_k + 2 c_(k-1) - c_(k-2)`` (the correction
    extrapolated linearly) from the third on. Up a ramp the correction grows
    about linearly with the accumulated charge, so the extrapolated start is
    off only by the change in the charge's rate (noise, non-linearity), the
    first by the coupling of the new charge, the start from scratch by the
    coupling of all of it. Bad pixels of frame ``k`` start at zero, as from
    scratch.

    The stopping rule is unchanged and judges only the last update, whatever
    the start, so the answer meets the same tolerance as one from scratch (see
    :func:`ipc_taichi.decouple`); it is not bit-identical to it.

    Cost per frame: ``keep`` (three NumPy passes on the host, one kernel on the
    device) over the answer, the measured frame and ``c``, writing ``c`` and
    the shift to add; on the host path the shift is added while the frame is
    loaded (the pass of the copy it replaces), on the device by one more kernel.
    On the host with the ``lanes`` layout (the CPU's default) two vector
    passes in all: ``keep`` reads the padded answer and measured frame and
    writes ``c`` (two corrections kept, in turn), and the start is written
    from the padded measured frame and the two corrections after the load
    placed the frame (:class:`LaneShift`).
    """

    def __init__(self, run):
        self.run = run
        ws = run.ws
        # c_(k-1) and the shift the next frame starts with, for this call only
        # (not counted in the workspace's cached bytes)
        self.lanes = ws.measured is not None and not ws.device_buffers
        if self.lanes:  # padded like the step's arrays: c_(k-1) and c_(k-2), in turn
            self.lane_pair = [ws.layout.host_zeros(ws.prev.shape, ws.dtype) for _ in range(2)]
            self.kept = 0
            return
        self.correction, self.shift = (_frame_buffer(ws) for _ in range(2))
        self._spare = None if ws.device_buffers else np.empty_like(self.correction)
        self.kept = 0

    def keep(self, answer, base):
        """Remember the correction of the frame just solved (before its result
        is stored) and the shift the next frame starts from."""
        ws = self.run.ws
        if self.lanes:  # c_k = S_k - M_k over the padded arrays (borders: 0 - 0)
            lanes = _lane_width(ws)
            newest = self.lane_pair[self.kept % 2]
            lanes_warm_kernels(self.run.info.precision, lanes).keep(
                *(a.reshape(-1, lanes) for a in (answer, ws.measured, newest)))
        elif ws.device_buffers:
            warm_kernels(self.run.info.precision).keep(answer, base, self.correction,
                                                       self.shift, ws.reach, self.kept)
        else:  # NumPy's vectorised passes: several times faster than Taichi's scalar loop
            new = np.subtract(ws.estimate(answer), base, out=self._spare)  # a view
            if self.kept:
                np.subtract(new, self.correction, out=self.shift)
                self.shift += new
            else:
                self.shift[...] = new
            self.correction, self._spare = new, self.correction
        self.kept += 1

    def host_shift(self):
        """The shift for the host path's load, ``None`` before the first answer
        or on the device path: a frame to add, or on the ``lanes`` layout a
        :class:`LaneShift` that writes the start once the frame is placed."""
        if not self.kept or self.run.ws.device_buffers:
            return None
        return LaneShift(self) if self.lanes else self.shift

    def apply(self, shift):
        """Shift the loaded start on the device path (the host path's load did
        it: ``shift`` is what it got); whether the start is a warm one."""
        if not self.kept:
            return False
        ws = self.run.ws
        if shift is None:
            warm_kernels(self.run.info.precision).add(ws.prev, self.shift, ws.ok, ws.reach)
        return True


class LaneShift:
    """The warm start on the host's ``lanes`` layout, written by
    :meth:`add_to` after the load placed the measured frame ``M`` (padded) in
    ``ws.measured``: ``S_0 = M + (c_1 + (c_1 - c_2))`` from the third frame
    on, ``M + c_1`` at the second, into ``ws.prev`` (bad pixels: the load
    zeroes them after)."""

    def __init__(self, warm):
        self.warm = warm

    def add_to(self, ws):
        warm = self.warm
        lanes = _lane_width(ws)
        newest, older = warm.lane_pair[(warm.kept - 1) % 2], warm.lane_pair[warm.kept % 2]
        lanes_warm_kernels(warm.run.info.precision, lanes).start(
            *(a.reshape(-1, lanes) for a in (ws.prev, ws.measured, newest, older)),
            1 if warm.kept > 1 else 0)


def _lane_width(ws):
    """Pixels per vector of a ``lanes`` workspace's arrays."""
    return lane_count("f64" if ws.dtype == np.float64 else "f32")


def _frame_buffer(ws):
    """A zeroed frame of the workspace's shape and dtype, where its arrays live."""
    if not ws.device_buffers:
        return np.zeros(ws.shape, dtype=ws.dtype)
    import taichi as ti

    kind = ti.f64 if ws.dtype == np.float64 else ti.f32
    arr = ti.ndarray(dtype=kind, shape=ws.shape)
    arr.fill(0)
    return arr


_warm_kernels = {}


def warm_kernels(precision):
    """The two device-path kernels of :class:`WarmStart` (compiled once per precision)."""
    hit = _warm_kernels.get(precision)
    if hit is not None:
        return hit
    import taichi as ti

    real = ti.f64 if precision == "f64" else ti.f32
    frame = ti.types.ndarray(dtype=real, ndim=2)
    mask = ti.types.ndarray(dtype=ti.u8, ndim=2)

    @ti.kernel
    def keep(src: frame, base: frame, correction: frame, shift: frame, r: ti.i32,
             kept: ti.i32):
        for i, j in base:
            new = src[i + r, j + r] - base[i, j]
            shift[i, j] = ti.select(kept > 0, new + (new - correction[i, j]), new)
            correction[i, j] = new

    @ti.kernel
    def add(start: frame, shift: frame, ok: mask, r: ti.i32):
        for i, j in shift:
            good = ok[i + r, j + r] != 0
            start[i + r, j + r] = ti.select(good, start[i + r, j + r] + shift[i, j], 0.0)

    hit = _warm_kernels[precision] = collections.namedtuple("WarmKernels", "keep add")(keep, add)
    return hit


def lanes_warm_kernels(precision, lanes):
    """The two vector kernels of :class:`WarmStart` on the host's ``lanes``
    layout (padded frames seen as vectors of ``lanes`` pixels; compiled once
    per precision and width): ``keep(src, measured, c)`` writes
    ``c = src - measured``; ``start(dst, measured, c1, c2, two)`` writes
    ``dst = measured + (c1 + (c1 - c2))`` (``two``: 1) or ``measured + c1`` (0)."""
    key = ("lanes", precision, lanes)
    hit = _warm_kernels.get(key)
    if hit is not None:
        return hit
    import taichi as ti

    real = ti.f64 if precision == "f64" else ti.f32
    vectors = ti.types.ndarray(dtype=ti.types.vector(lanes, real), ndim=1)

    @ti.kernel
    def keep(src: vectors, measured: vectors, c: vectors):
        for q in range(c.shape[0]):
            c[q] = src[q] - measured[q]

    @ti.kernel
    def start(dst: vectors, measured: vectors, c1: vectors, c2: vectors, two: ti.i32):
        for q in range(dst.shape[0]):
            new = c1[q]
            shift = new
            if two:
                shift = new + (new - c2[q])
            dst[q] = measured[q] + shift

    hit = _warm_kernels[key] = collections.namedtuple("LaneWarmKernels", "keep start")(keep,
                                                                                      start)
    return hit


runtime.on_reset(_warm_kernels.clear)

"""The kernels that bring a frame in and out of the padded working arrays of
the step (:mod:`ipc_taichi._kernels`): ``load`` (unpadded frame -> padded
estimate, bad pixels zeroed, ``ok`` written, one flag set if any pixel is bad)
and ``store`` (padded estimate -> unpadded frame), so that padding and
initialisation happen where the arrays live (on the GPU for CUDA). On the CPU
the engine does the same with NumPy (:func:`ipc_taichi._engine._load_host`),
its finiteness test by :func:`finite_sum`.
"""

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["FrameKernels", "get_frame_kernels", "finite_sum", "MAX_FINITE"]

MAX_FINITE = {"f64": 1.7976931348623157e308, "f32": 3.4028234663852886e38}


@dataclass(frozen=True)
class FrameKernels:
    """The kernels that move a frame in and out of the padded working arrays."""

    load: object
    store: object


@functools.cache
def get_frame_kernels(precision):
    """Build (once per precision) the ``load`` and ``store`` kernels.

    ``load(src, io, copy_in, mask, use_mask, prev, ok, r, flag)``: for every
    pixel of the unpadded frame ``src``, a pixel is *bad* when it is not finite
    or (with ``use_mask`` != 0) ``mask`` is non-zero there. The frame with bad
    pixels set to 0 goes into ``io`` (the measured frame the Jacobi step reads
    as ``base``; with ``copy_in`` == 0, ``src`` is ``io`` and only bad pixels
    are written) and into the padded estimate ``prev`` (S_0 = M); ``ok`` is 1
    for good pixels and 0 for bad ones, and ``flag[0]`` (0 before the launch)
    becomes 1 if any pixel is bad (a plain store of the same value by every bad
    pixel: no atomic). ``r`` is the border width of ``prev`` and ``ok``; their
    borders are not touched. One parallel loop: a serial task more would cost
    a thread-pool wake-up on the CPU.

    ``store(src, io, r)``: the frame inside the padded ``src`` into ``io``.
    """
    import taichi as ti

    real = ti.f64 if precision == "f64" else ti.f32
    frame = ti.types.ndarray(dtype=real, ndim=2)
    vector = ti.types.ndarray(dtype=real, ndim=1)
    mask = ti.types.ndarray(dtype=ti.u8, ndim=2)
    biggest = MAX_FINITE[precision]

    @ti.kernel
    def load(src: frame, io: frame, copy_in: ti.i32, bad_in: mask, use_mask: ti.i32,
             prev: frame, ok: mask, r: ti.i32, flag: vector):
        for i, j in ti.ndrange(io.shape[0], io.shape[1]):
            v = src[i, j]
            good = ti.abs(v) <= biggest  # False for NaN and +-inf
            if use_mask != 0:
                if bad_in[i, j] != 0:
                    good = False
            if not good:
                v = ti.cast(0.0, real)
                flag[0] = 1.0
            if copy_in != 0 or not good:
                io[i, j] = v
            prev[i + r, j + r] = v
            ok[i + r, j + r] = ti.cast(ti.select(good, 1, 0), ti.u8)

    @ti.kernel
    def store(src: frame, io: frame, r: ti.i32):
        for i, j in ti.ndrange(io.shape[0], io.shape[1]):
            io[i, j] = src[i + r, j + r]

    return FrameKernels(load, store)


def finite_sum(frame):
    """Whether the sum of a NumPy ``frame`` is finite: then so is every pixel
    (NaN and inf propagate), found in one read and no temporary. Summed in
    float64 for types narrower than float32 (a float16 sum overflows); an
    overflowing sum is no warning, only ``False`` (the caller then tests
    each pixel)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return bool(np.isfinite(frame.sum(dtype=np.float64 if frame.itemsize < 4 else None)))

"""Input preparation and the runner of the shared step kernel.

Public functions validate and prepare arrays here (native-endian, contiguous,
the runtime's float type, bad pixels masked, a zero border of ``reach``
pixels around the frame; see :mod:`ipc_taichi._kernels`), then call the kernel
through a :class:`Stepper`. On the CPU the NumPy arrays are handed to Taichi
without a copy; on CUDA they are uploaded once and stay on the device between
iterations, only the two stopping-rule numbers come back per iteration.
"""

import numpy as np

from . import runtime
from ._kernels import KernelConfig, get_step_kernel
from .errors import IPCInputError

# rows per task of the CPU sweep: a strip re-evaluates the dy-row pairs above
# it (1/STRIP_ROWS extra work for nearest neighbours) and 2 cores need a few
# dozen tasks to balance when other processes share them
STRIP_ROWS = 32


def as_stack(data, what, mask=None):
    """Validate ``data`` (and ``mask``) as a 2-D frame or a 3-D stack.

    Returns ``(array, mask, was_2d)``: the array as a stack ``(n, ny, nx)`` and
    the boolean mask (True = pixel not trusted) broadcast to it, or ``None``.
    A NumPy masked array contributes its own mask.
    """
    if isinstance(data, np.ma.MaskedArray):
        own = np.ma.getmaskarray(data)
        mask = own if mask is None else (own | np.asarray(mask, dtype=bool))
        data = data.data
    try:
        arr = np.asarray(data)
    except Exception as exc:  # ragged lists and the like
        raise IPCInputError(f"{what}: cannot be read as an array ({exc})") from None
    if arr.dtype.kind not in "iuf":
        raise IPCInputError(f"{what}: dtype {arr.dtype} is not a real number type")
    if arr.ndim not in (2, 3):
        raise IPCInputError(f"{what}: expected a 2-D frame (ny, nx) or a 3-D stack "
                            f"(n, ny, nx), got {arr.ndim}-D shape {arr.shape}")
    if arr.size == 0:
        raise IPCInputError(f"{what}: empty array of shape {arr.shape}")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.dtype != bool:
            raise IPCInputError(f"{what}: mask must be boolean (True = not trusted), got "
                                f"dtype {mask.dtype}")
        try:
            mask = np.broadcast_to(mask, arr.shape)
        except ValueError:
            raise IPCInputError(f"{what}: mask of shape {mask.shape} does not fit data of "
                                f"shape {arr.shape}") from None
        if not mask.any():
            mask = None
    was_2d = arr.ndim == 2
    if was_2d:
        arr = arr[np.newaxis]
        mask = None if mask is None else mask[np.newaxis]
    return arr, mask, was_2d


def prepare_frame(frame, dtype, reach=0, mask=None):
    """The frame in ``dtype`` inside a zero border of ``reach`` pixels, bad
    pixels (non-finite, or True in ``mask``) zeroed, and the validity mask of
    the frame (``None`` when every pixel is good). Returns ``(padded, valid)``;
    one copy of the frame."""
    ny, nx = frame.shape
    padded = np.zeros((ny + 2 * reach, nx + 2 * reach), dtype=dtype)
    inner = interior(padded, reach)
    inner[...] = frame
    valid = np.isfinite(inner)
    if mask is not None:
        valid &= ~mask
    if valid.all():
        return padded, None
    inner[~valid] = 0.0
    return padded, valid


def restore_bad(out, frame, valid):
    """Put the bad pixels back into a result frame: masked pixels keep their
    input value, non-finite pixels become NaN."""
    if valid is None:
        return out
    bad = ~valid
    kept = np.asarray(frame)[bad].astype(out.dtype)
    kept[~np.isfinite(kept)] = np.nan
    out[bad] = kept
    return out


def as_result(stack, was_2d, like):
    """The result stack shaped and typed as the input was given: a frame for a
    2-D input, a masked array (with the input's mask) for a masked input."""
    result = stack[0] if was_2d else stack
    if isinstance(like, np.ma.MaskedArray):
        result = np.ma.MaskedArray(result, mask=np.ma.getmaskarray(like).copy())
    return result


def interior(padded, reach):
    """The frame inside a padded array (a view)."""
    if reach == 0:
        return padded
    return padded[reach:-reach, reach:-reach]


def default_layout(arch):
    """The kernel layout that suits ``arch`` (see :mod:`ipc_taichi._kernels`)."""
    return "pixel" if arch == "cuda" else "sweep"


class Stepper:
    """Runs ``dst = base + sign * flow(src)`` for one law/geometry/edge on
    padded arrays (see :func:`prepare_frame`)."""

    def __init__(self, model, masked, info, layout=None):
        law, geometry, edge = model.law, model.geometry, model.edge
        half = geometry.half_stencil()
        self.info = info
        self.dtype = info.dtype
        self.config = KernelConfig(
            offsets=tuple(u for u, _ in half), law_kind=law.kind, edge=edge,
            masked=masked, precision=info.precision,
            layout=layout or default_layout(info.arch))
        self.kernel = get_step_kernel(self.config)
        self.reach = self.config.reach
        dtype = self.dtype
        self.on_device = info.arch == "cuda"
        self.p = self.to_runtime(law.kernel_params().astype(dtype))
        self.w = self.to_runtime(np.array([wts for _, wts in half], dtype=dtype))
        table = law.table if law.kind == "table" else np.zeros((2, 2))
        self.table = self.to_runtime(np.ascontiguousarray(table, dtype=dtype))
        self.stats = self.to_runtime(np.zeros(2, dtype=dtype))
        self.all_ok = self.to_runtime(np.ones((1, 1), dtype=np.uint8))
        self.rings = {}

    def ok_array(self, padded_shape, valid):
        """The ``ok`` byte array for the kernel: 1 where a pixel may couple.
        Border pixels may couple with the zero edge (they take charge), not
        with the isolated edge; bad pixels never do."""
        if not self.config.uses_ok:
            return None
        ok = np.full(padded_shape, 1 if self.config.edge == "zero" else 0, dtype=np.uint8)
        interior(ok, self.reach)[...] = True if valid is None else valid
        return self.to_runtime(ok)

    def to_runtime(self, array):
        """A NumPy array as the kernel will take it (device ndarray on CUDA)."""
        if not self.on_device:
            return array
        import taichi as ti

        kind = {np.dtype(np.float64): ti.f64, np.dtype(np.float32): ti.f32,
                np.dtype(np.uint8): ti.u8}[array.dtype]
        nd = ti.ndarray(dtype=kind, shape=array.shape)
        nd.from_numpy(array)
        return nd

    def zeros(self, shape):
        if not self.on_device:
            return np.zeros(shape, dtype=self.dtype)
        import taichi as ti

        nd = ti.ndarray(dtype=ti.f64 if self.dtype == np.float64 else ti.f32, shape=shape)
        nd.fill(0)
        return nd

    def to_numpy(self, array):
        return array.to_numpy() if self.on_device else array

    def ring(self, padded_shape):
        """Scratch rows of the CPU sweep for frames of this padded shape."""
        cfg = self.config
        if cfg.layout != "sweep":
            shape = (1, 1, 1, 1)
        else:
            strips = -(-(padded_shape[0] - 2 * self.reach) // STRIP_ROWS)
            shape = (strips, max(1, len(cfg.vertical)), cfg.ring_depth, padded_shape[1])
        if shape not in self.rings:
            self.rings = {shape: self.zeros(shape)}  # one frame size at a time
        return self.rings[shape]

    def __call__(self, src, base, dst, ok, sign):
        """One step on padded arrays; returns ``(max|dst - src|, max|dst|)``
        over good pixels."""
        if self.on_device:
            self.stats.fill(0)
        else:
            self.stats[:] = 0
        ring = self.ring(src.shape)
        self.kernel(src, base, dst, self.all_ok if ok is None else ok, self.p, self.w,
                    self.table, float(sign), self.stats, ring, STRIP_ROWS)
        stats = self.to_numpy(self.stats)
        return float(stats[0]), float(stats[1])


def start(arch, precision):
    return runtime.init(arch, precision)


__all__ = ["as_stack", "prepare_frame", "restore_bad", "as_result", "interior", "Stepper",
           "start", "STRIP_ROWS", "default_layout"]

"""Input preparation and the runner of the shared step kernel.

Public functions validate and prepare arrays here (native-endian, contiguous,
the runtime's float type, bad pixels masked), then call the kernel through a
:class:`Stepper`. On the CPU the NumPy arrays are handed to Taichi without a
copy; on CUDA they are uploaded once and stay on the device between
iterations, only the two stopping-rule numbers come back per iteration.
"""

import numpy as np

from . import runtime
from ._kernels import KernelConfig, get_step_kernel
from .errors import IPCInputError
from .geometry import Geometry
from .laws import check_convergence, get_law

EDGES = ("zero", "isolated")


def as_stack(data, what):
    """Validate ``data`` as a 2-D frame or a 3-D stack; return (array, was_2d)."""
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
    if arr.ndim == 2:
        return arr[np.newaxis], True
    return arr, False


def prepare_frame(frame, dtype):
    """Native-endian contiguous copy in ``dtype``, bad pixels zeroed, and the
    validity mask (``None`` when every pixel is finite)."""
    work = np.array(frame, dtype=dtype, order="C", copy=True)
    valid = np.isfinite(work)
    if valid.all():
        return work, None
    work[~valid] = 0.0
    return work, valid


def resolve_model(law, geometry, edge):
    law = get_law(law)
    if geometry is None:
        geometry = Geometry.nearest()
    elif not isinstance(geometry, Geometry):
        geometry = Geometry.parse(geometry) if isinstance(geometry, str) else Geometry(geometry)
    if edge not in EDGES:
        raise IPCInputError(f"edge must be one of {', '.join(EDGES)}, got {edge!r}")
    check_convergence(law, geometry)
    return law, geometry, edge


class Stepper:
    """Runs ``dst = base + sign * flow(src)`` for one law/geometry/edge."""

    def __init__(self, law, geometry, edge, masked, info):
        half = geometry.half_stencil()
        self.info = info
        self.dtype = info.dtype
        self.kernel = get_step_kernel(KernelConfig(
            offsets=tuple(u for u, _ in half), law_kind=law.kind, edge=edge,
            masked=masked, precision=info.precision))
        dtype = self.dtype
        self.on_device = info.arch == "cuda"
        self.p = self.to_runtime(law.kernel_params().astype(dtype))
        self.w = self.to_runtime(np.array([wts for _, wts in half], dtype=dtype))
        table = law.table if law.kind == "table" else np.zeros((2, 2))
        self.table = self.to_runtime(np.ascontiguousarray(table, dtype=dtype))
        self.stats = self.to_runtime(np.zeros(2, dtype=dtype))
        self.no_mask = self.to_runtime(np.ones((1, 1), dtype=np.uint8))

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

    def empty_like(self, shape):
        if not self.on_device:
            return np.empty(shape, dtype=self.dtype)
        import taichi as ti

        return ti.ndarray(dtype=ti.f64 if self.dtype == np.float64 else ti.f32, shape=shape)

    def to_numpy(self, array):
        return array.to_numpy() if self.on_device else array

    def __call__(self, src, base, dst, mask, sign):
        """One step; returns ``(max|dst - src|, max|dst|)`` over good pixels."""
        if self.on_device:
            self.stats.fill(0)
        else:
            self.stats[:] = 0
        self.kernel(src, base, dst, self.no_mask if mask is None else mask,
                    self.p, self.w, self.table, float(sign), self.stats)
        stats = self.to_numpy(self.stats)
        return float(stats[0]), float(stats[1])


def start(arch, precision):
    return runtime.init(arch, precision)

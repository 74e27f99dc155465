"""Where arrays live: array kinds, DLPack conversion, device pointers, host pinning.

:func:`ipc_taichi.couple` and :func:`ipc_taichi.decouple` return the kind of
array they were given, on the device it was on:

``numpy``
    NumPy arrays and anything :func:`numpy.asarray` reads (lists, memmaps).
    On CUDA the frame is copied to the GPU once and the result copied back
    once, both through the CUDA driver (:class:`CudaDriver`): memory the
    caller keeps page-locked (:func:`pinned_empty`, a pinned tensor's) is
    copied directly at DMA speed; pageable memory goes through a page-locked
    staging frame that the workspace keeps, in chunks, by a few threads, so
    that the host copies and the DMA overlap (:mod:`ipc_taichi._copies`; locking the
    caller's memory per call costs more than it saves, see
    :func:`copy_policy`).
``torch``
    PyTorch tensors. Taichi takes a tensor as a kernel argument without a copy
    (on the CPU and on CUDA), so the result is computed into a new tensor on the
    tensor's device and nothing crosses the PCIe bus.
``cupy``, ``jax``, ``dlpack``
    CuPy and JAX arrays, and any other object with ``__dlpack__``: wrapped as a
    PyTorch tensor through DLPack (no copy), computed as above, and handed
    back through DLPack as the input's kind. PyTorch is then required; without
    it a one-line :class:`~ipc_taichi.errors.IPCInputError` says what to install.

Nothing here imports PyTorch, CuPy or JAX unless such an array is given.
"""

import contextlib
import ctypes
import sys
import threading
import weakref

import numpy as np

from . import runtime
from .errors import IPCInputError
from .gpus import CUDA_DRIVER

__all__ = ["kind_of", "to_torch", "from_torch", "torch_dtype", "check_torch_device",
           "ndarray_pointer", "CudaDriver", "cuda_driver", "pinned_for_call", "pinned_empty",
           "PIN_MIN_BYTES", "DEVICE_KINDS", "torch_stream_order", "shares_memory",
           "pageable_copies", "copy_policy", "COPY_POLICIES", "register_per_call"]

DEVICE_KINDS = ("torch", "cupy", "jax", "dlpack")

PIN_MIN_BYTES = 4 << 20
"""Host arrays at least this large are staged (or, under the ``register``
policy, page-locked for the duration of a CUDA call); smaller ones are copied
from pageable memory directly (the driver stages those itself)."""

COPY_POLICIES = ("staged", "register", "pageable")
"""How large pageable host frames cross the bus on CUDA (:func:`copy_policy`)."""

_INSTALL = {
    "cupy": "CuPy arrays reach Taichi through PyTorch (DLPack): pip install torch "
            "(a CUDA build matching your CuPy)",
    "jax": "JAX arrays reach Taichi through PyTorch (DLPack): pip install torch "
           "(a CUDA build matching your jaxlib)",
    "dlpack": "DLPack arrays reach Taichi through PyTorch: pip install torch",
}


def kind_of(data):
    """The kind of array ``data`` is: ``numpy``, ``torch``, ``cupy``, ``jax``
    or ``dlpack`` (see the module docstring). Decided from the type's module,
    so no optional package is imported."""
    if isinstance(data, np.ndarray):
        return "numpy"
    root = type(data).__module__.split(".", 1)[0]
    if root == "torch":
        return "torch"
    if root in ("cupy", "cupyx"):
        return "cupy"
    if root in ("jax", "jaxlib"):
        return "jax"
    if hasattr(data, "__dlpack__"):
        return "dlpack"
    return "numpy"


def _torch(kind):
    try:
        import torch
    except ImportError:
        raise IPCInputError(f"ipc_taichi: {_INSTALL[kind]}") from None
    return torch


def to_torch(data, kind):
    """``data`` (of ``kind``) as a PyTorch tensor sharing its memory."""
    if kind == "torch":
        return data
    torch = _torch(kind)
    try:
        return torch.from_dlpack(data)
    except Exception as exc:  # the producer refused (e.g. an unsupported dtype)
        raise IPCInputError(f"{kind} array: DLPack hand-over to PyTorch failed ({exc})") \
            from None


def from_torch(tensor, kind, like):
    """``tensor`` handed back as the kind of ``like`` (no copy)."""
    if kind == "torch":
        return tensor
    if kind == "cupy":
        import cupy

        return cupy.from_dlpack(tensor)
    if kind == "jax":
        import jax.dlpack

        return jax.dlpack.from_dlpack(tensor)
    module = sys.modules.get(type(like).__module__.split(".", 1)[0])
    back = getattr(module, "from_dlpack", None)
    return back(tensor) if back is not None else tensor


def torch_dtype(dtype):
    """The PyTorch dtype of a NumPy float dtype."""
    import torch

    return {np.dtype(np.float64): torch.float64, np.dtype(np.float32): torch.float32}[
        np.dtype(dtype)]


def check_torch_device(tensor, arch, what):
    """Refuse a tensor that Taichi cannot reach where it runs: a GPU tensor
    while Taichi runs on the CPU, a host tensor while it runs on CUDA (which
    would silently cross the bus twice per kernel), or a GPU other than the
    first visible one (the one Taichi uses)."""
    dev = tensor.device
    if arch == "cpu" and dev.type != "cpu":
        raise IPCInputError(f"{what}: the array is on {dev} but Taichi runs on the CPU "
                            "(arch='cpu'); use arch='cuda' or move the array to the host")
    if arch == "cuda":
        if dev.type != "cuda":
            raise IPCInputError(f"{what}: the array is on {dev} but Taichi runs on CUDA; pass "
                                "a CUDA array, or a NumPy array for a host round trip")
        if (dev.index or 0) != 0:
            raise IPCInputError(f"{what}: the array is on {dev}; Taichi uses the first visible "
                                "GPU (cuda:0): select the GPU with CUDA_VISIBLE_DEVICES "
                                "(see ipc_taichi.gpus)")


def shares_memory(a, b):
    """Whether two arrays of the same kind (NumPy, or PyTorch tensors) may
    share memory (``out=`` given as the input itself, or a view of it)."""
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return bool(np.may_share_memory(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return False
    return a.untyped_storage().data_ptr() == b.untyped_storage().data_ptr()


class torch_stream_order:
    """Context manager: order a call's GPU work with the caller's PyTorch stream.

    Taichi launches its kernels, and the engine issues its driver copies, on
    the legacy default stream; PyTorch may run the caller's work on another
    stream (``with torch.cuda.stream(s):``), which the default stream does not
    wait for, nor it for the default stream. Inside this context the default
    stream first waits for the caller's stream (the input is ready), the
    engine's own PyTorch operations run on the default stream (ordered with
    Taichi), and on leaving the caller's stream waits for the default stream
    (the result is ready) and the result's memory is marked as used by the
    caller's stream (:meth:`adopt`). No host synchronisation. A no-op for CPU
    tensors and on the default stream. (CuPy and JAX hand their arrays over
    through DLPack, which orders the streams itself.)

    Parameters
    ----------
    tensor : torch.Tensor or None
        The input (its device is the one ordered); ``None``: a no-op.
    cuda : module, optional
        ``torch.cuda`` (tests pass a stand-in).
    """

    def __init__(self, tensor, cuda=None):
        self.device = None if tensor is None else tensor.device
        self.cuda = cuda
        self.caller = self.default = self._inside = None

    def __enter__(self):
        if self.device is None or self.device.type != "cuda":
            return self
        if self.cuda is None:
            import torch

            self.cuda = torch.cuda
        caller = self.cuda.current_stream(self.device)
        default = self.cuda.default_stream(self.device)
        if caller == default:
            return self
        self.caller, self.default = caller, default
        default.wait_stream(caller)
        self._inside = self.cuda.stream(default)
        self._inside.__enter__()
        return self

    def adopt(self, tensor):
        """Mark ``tensor`` (made inside the context) as used by the caller's stream."""
        if self.caller is not None and tensor is not None:
            tensor.record_stream(self.caller)

    def __exit__(self, *exc):
        if self._inside is not None:
            self._inside.__exit__(*exc)
            self.caller.wait_stream(self.default)
            self._inside = None
        return False


def ndarray_pointer(nd):
    """The address of a Taichi ndarray's data (device memory on CUDA, host
    memory on the CPU): Taichi's LLVM backends allocate ndarrays as plain
    memory, and its program object reports the address."""
    import taichi as ti

    return int(ti.lang.impl.get_runtime().prog.get_ndarray_data_ptr_as_int(nd.arr))


# --------------------------------------------------------------------------- CUDA driver

CUDA_SUCCESS = 0
CUDA_ERROR_HOST_MEMORY_ALREADY_REGISTERED = 712
CUDA_ERROR_HOST_MEMORY_NOT_REGISTERED = 713
CU_MEMHOSTREGISTER_PORTABLE = 1
CU_POINTER_ATTRIBUTE_MEMORY_TYPE = 2
CU_MEMORYTYPE_HOST = 1


class CudaDriver:
    """The few CUDA driver calls the engine needs, through ctypes (``libcuda.so.1``
    ships with the NVIDIA driver, so this adds no dependency).

    Every call runs in the primary context of device 0, the context Taichi's
    CUDA backend uses, and copies are issued on the legacy default stream that
    Taichi launches its kernels on, so they are ordered with the kernels.

    Parameters
    ----------
    lib : ctypes library, optional
        The driver (default: ``libcuda.so.1``); tests pass a stand-in.
    """

    def __init__(self, lib=None):
        self.lib = lib if lib is not None else ctypes.CDLL(CUDA_DRIVER)
        self._ctx = None

    def _check(self, code, what):
        if code != CUDA_SUCCESS:
            name = ctypes.c_char_p()
            try:
                self.lib.cuGetErrorName(code, ctypes.byref(name))
                label = (name.value or b"").decode()
            except Exception:  # a stand-in driver without error names
                label = ""
            raise RuntimeError(f"CUDA driver: {what} failed with error {code} {label}".strip())

    def _context(self):
        if self._ctx is None:
            self._check(self.lib.cuInit(0), "cuInit")
            dev = ctypes.c_int()
            self._check(self.lib.cuDeviceGet(ctypes.byref(dev), 0), "cuDeviceGet")
            ctx = ctypes.c_void_p()
            self._check(self.lib.cuDevicePrimaryCtxRetain(ctypes.byref(ctx), dev),
                        "cuDevicePrimaryCtxRetain")
            self._ctx = ctx
        return self._ctx

    def _in_context(self, fn, *args):
        self._check(self.lib.cuCtxPushCurrent_v2(self._context()), "cuCtxPushCurrent")
        try:
            return fn(*args)
        finally:
            self.lib.cuCtxPopCurrent_v2(ctypes.byref(ctypes.c_void_p()))

    def register(self, address, nbytes):
        """Page-lock host memory. Returns True if this call locked it, False if
        it was already locked (by the caller or an earlier registration)."""
        code = self._in_context(self.lib.cuMemHostRegister_v2, ctypes.c_void_p(address),
                                ctypes.c_size_t(nbytes),
                                ctypes.c_uint(CU_MEMHOSTREGISTER_PORTABLE))
        if code == CUDA_ERROR_HOST_MEMORY_ALREADY_REGISTERED:
            return False
        self._check(code, "cuMemHostRegister")
        return True

    def unregister(self, address):
        code = self._in_context(self.lib.cuMemHostUnregister, ctypes.c_void_p(address))
        if code != CUDA_ERROR_HOST_MEMORY_NOT_REGISTERED:
            self._check(code, "cuMemHostUnregister")

    def upload(self, device_address, host_address, nbytes):
        """Host -> device copy (synchronous with respect to the host memory)."""
        self._check(self._in_context(self.lib.cuMemcpyHtoD_v2, ctypes.c_uint64(device_address),
                                     ctypes.c_void_p(host_address), ctypes.c_size_t(nbytes)),
                    "cuMemcpyHtoD")

    def download(self, host_address, device_address, nbytes):
        """Device -> host copy; returns when the data is on the host."""
        self._check(self._in_context(self.lib.cuMemcpyDtoH_v2, ctypes.c_void_p(host_address),
                                     ctypes.c_uint64(device_address), ctypes.c_size_t(nbytes)),
                    "cuMemcpyDtoH")

    def upload_async(self, device_address, host_address, nbytes):
        """Host -> device copy on the legacy default stream (ordered with the
        kernels); the host memory must be page-locked and left alone until
        the stream has passed it."""
        self._check(self._in_context(self.lib.cuMemcpyHtoDAsync_v2,
                                     ctypes.c_uint64(device_address),
                                     ctypes.c_void_p(host_address), ctypes.c_size_t(nbytes),
                                     ctypes.c_void_p(None)), "cuMemcpyHtoDAsync")

    def download_async(self, host_address, device_address, nbytes):
        """Device -> host copy on the legacy default stream, into page-locked
        memory; complete once an event recorded after it has passed."""
        self._check(self._in_context(self.lib.cuMemcpyDtoHAsync_v2, ctypes.c_void_p(host_address),
                                     ctypes.c_uint64(device_address), ctypes.c_size_t(nbytes),
                                     ctypes.c_void_p(None)), "cuMemcpyDtoHAsync")

    def memset_async(self, device_address, value, nbytes):
        """Set ``nbytes`` bytes of device memory to ``value`` (a byte), on the
        legacy default stream."""
        self._check(self._in_context(self.lib.cuMemsetD8Async, ctypes.c_uint64(device_address),
                                     ctypes.c_ubyte(value), ctypes.c_size_t(nbytes),
                                     ctypes.c_void_p(None)), "cuMemsetD8Async")

    def event(self):
        """A new CUDA event (without timing)."""
        ev = ctypes.c_void_p()
        self._check(self._in_context(self.lib.cuEventCreate, ctypes.byref(ev),
                                     ctypes.c_uint(2)), "cuEventCreate")
        return ev

    def record(self, event):
        """Record ``event`` on the legacy default stream."""
        self._check(self._in_context(self.lib.cuEventRecord, event, ctypes.c_void_p(None)),
                    "cuEventRecord")

    def wait(self, event):
        """Block the host until the stream has passed ``event``."""
        self._check(self._in_context(self.lib.cuEventSynchronize, event), "cuEventSynchronize")

    def destroy_event(self, event):
        self._in_context(self.lib.cuEventDestroy_v2, event)

    def host_alloc(self, nbytes):
        """``nbytes`` of page-locked host memory (its address); see :meth:`free_host`."""
        ptr = ctypes.c_void_p()
        self._check(self._in_context(self.lib.cuMemHostAlloc, ctypes.byref(ptr),
                                     ctypes.c_size_t(nbytes),
                                     ctypes.c_uint(CU_MEMHOSTREGISTER_PORTABLE)),
                    "cuMemHostAlloc")
        return int(ptr.value)

    def free_host(self, address):
        self._in_context(self.lib.cuMemFreeHost, ctypes.c_void_p(address))

    def is_pinned(self, address):
        """Whether host ``address`` is page-locked memory the driver knows
        (registered, or allocated page-locked by any CUDA library)."""
        kind = ctypes.c_uint()
        code = self._in_context(self.lib.cuPointerGetAttribute, ctypes.byref(kind),
                                ctypes.c_int(CU_POINTER_ATTRIBUTE_MEMORY_TYPE),
                                ctypes.c_uint64(address))
        return code == CUDA_SUCCESS and kind.value == CU_MEMORYTYPE_HOST

    def device_name(self):
        """The name of device 0."""
        self._context()
        name = ctypes.create_string_buffer(256)
        self._check(self.lib.cuDeviceGetName(name, 256, 0), "cuDeviceGetName")
        return name.value.decode(errors="replace")

    def memory(self):
        """``(free, total)`` device memory in bytes."""
        free, total = ctypes.c_size_t(), ctypes.c_size_t()
        self._check(self._in_context(self.lib.cuMemGetInfo_v2, ctypes.byref(free),
                                     ctypes.byref(total)), "cuMemGetInfo")
        return free.value, total.value


_driver = None
_driver_lock = threading.Lock()


def cuda_driver():
    """The process's :class:`CudaDriver` (loaded on first use)."""
    global _driver
    with _driver_lock:
        if _driver is None:
            _driver = CudaDriver()
        return _driver


def _contiguous(host):
    if not host.flags.c_contiguous:
        raise ValueError("upload source must be C-contiguous")
    return host


def _span(array):
    """``(address, nbytes)`` of the memory from ``array``'s first to its last
    element (a view: its own span, not its parent buffer's). Not rounded to
    pages: the driver locks whole pages itself, and a rounded span could
    overlap a neighbouring array's registration."""
    from numpy.lib.array_utils import byte_bounds

    low, high = byte_bounds(array)
    return low, high - low


_pinning = [True]  # switched off by pageable_copies()
_policy = ["staged"]


@contextlib.contextmanager
def copy_policy(name):
    """Within this context large pageable host frames cross the bus on CUDA by
    policy ``name``: ``staged`` (the default: through the workspace's
    page-locked staging frame, in chunks, by a few threads, see
    :class:`~ipc_taichi._copies.HostCopies`), ``register`` (the caller's memory page-locked for
    the duration of the call, :class:`pinned_for_call`: locking costs about
    as much as the copy) or ``pageable`` (plain driver copies from pageable
    memory: the driver stages them itself, on one thread). The benchmark
    times each."""
    if name not in COPY_POLICIES:
        raise ValueError(f"copy policy: one of {COPY_POLICIES}, got {name!r}")
    _policy.append(name)
    _pinning.append(name != "pageable")
    try:
        yield
    finally:
        _pinning.pop()
        _policy.pop()


def register_per_call():
    """Whether the engine page-locks the caller's frames for a call
    (the ``register`` policy of :func:`copy_policy`)."""
    return _policy[-1] == "register"


def pageable_copies():
    """Within this context no host array is page-locked or staged by the
    engine (its copies run from pageable memory): how the benchmark times what
    staging saves. Memory already locked (:func:`pinned_empty`) stays locked."""
    return copy_policy("pageable")


class pinned_for_call:
    """Context manager: page-lock host arrays (at least :data:`PIN_MIN_BYTES`)
    for the duration of a CUDA call, so that the engine's copies run at DMA
    speed; memory that is already locked (e.g. from :func:`pinned_empty`) is
    left as it is. A no-op off CUDA or with ``enabled=False``.

    Each array's own span is locked (a frame that is a view of a larger
    stack locks the frame, not the stack); a span overlapping one locked
    already (by this call or earlier) is refused by the driver and left
    pageable. An interruption (Ctrl-C) while locking unlocks what was locked.
    """

    def __init__(self, arrays, arch, enabled=True, driver=None):
        self.arrays = [a for a in arrays if a is not None]
        self.active = enabled and arch == "cuda" and _pinning[-1]
        self.driver = driver
        self.locked = []

    def __enter__(self):
        if not self.active:
            return self
        driver = self.driver or cuda_driver()
        self.driver = driver
        try:
            for array in self.arrays:
                address, nbytes = _span(array)
                if nbytes < PIN_MIN_BYTES:
                    continue
                try:
                    if driver.register(address, nbytes):
                        self.locked.append(address)
                except RuntimeError:
                    # e.g. read-only or file-backed memory the driver will not lock:
                    # the copies of this array then run from pageable memory
                    continue
        except BaseException:  # KeyboardInterrupt, SystemExit: no lock outlives the call
            self.__exit__()
            raise
        finally:
            self.arrays = []  # keep addresses only, not the arrays alive
        return self

    def __exit__(self, *exc):
        while self.locked:
            self.driver.unregister(self.locked.pop())
        return False


def pinned_empty(shape, dtype=np.float64, arch=None, driver=None):
    """An uninitialised NumPy array in page-locked host memory (on CUDA), for
    frames that are decoupled again and again (pass it as the input, or as
    ``out=``): the engine's copies then need no locking of their own. The
    memory is unlocked when the array is garbage collected. Off CUDA it is a
    plain :func:`numpy.empty`.
    """
    if arch is None:
        info = runtime.current()
        arch = info.arch if info is not None else "cpu"
    array = np.empty(shape, dtype=dtype)
    if arch == "cuda" and array.nbytes:
        driver = driver or cuda_driver()
        address = array.ctypes.data
        if driver.register(address, array.nbytes):
            weakref.finalize(array, driver.unregister, address)
    return array

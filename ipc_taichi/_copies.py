"""Copies between host NumPy frames and Taichi ndarrays (:class:`HostCopies`):
on CUDA through the driver (:class:`~ipc_taichi._device.CudaDriver`), a large
pageable frame staged through a page-locked frame in chunks by a few threads;
on the CPU by ``memmove``."""

import concurrent.futures
import ctypes
import os
import threading
import weakref

import numpy as np

from . import _device
from ._device import PIN_MIN_BYTES, _contiguous, cuda_driver, ndarray_pointer

__all__ = ["HostCopies", "STAGE_CHUNK"]

STAGE_CHUNK = 4 << 20
"""Bytes per chunk of a staged copy (one worker thread copies a chunk between
the caller's memory and the page-locked staging frame, and DMAs it)."""

class HostCopies:
    """Copies between host NumPy arrays and Taichi ndarrays by address.

    On CUDA through :class:`CudaDriver`; on the CPU (where a Taichi ndarray is
    host memory) by ``memmove``, which is how the tests run the GPU engine's
    code path without a GPU.

    On CUDA a pageable host frame of at least :data:`PIN_MIN_BYTES` is staged
    (the ``staged`` policy, the default, :func:`~ipc_taichi._device.copy_policy`): cut into
    :data:`STAGE_CHUNK` chunks, each copied by one of a few worker threads
    between the caller's memory and a page-locked staging frame kept here
    (allocated once, on first use) and DMA'd by that thread, so that the
    threads' host copies overlap each other and the DMA. Page-locked host
    memory (:func:`pinned_empty`, a pinned tensor's) is copied directly.
    Every copy is complete when the method returns.
    """

    def __init__(self, arch, driver=None):
        self.arch = arch
        self.driver = driver if driver is not None or arch != "cuda" else cuda_driver()
        self._stage = None  # (address, nbytes) of the page-locked staging frame

    def upload(self, nd, host):
        host = _contiguous(host)
        if self.arch == "cuda":
            if self._staged(host):
                self._copy_staged(ndarray_pointer(nd), host, up=True)
            else:
                self.driver.upload(ndarray_pointer(nd), host.ctypes.data, host.nbytes)
        else:
            ctypes.memmove(ndarray_pointer(nd), host.ctypes.data, host.nbytes)

    def download(self, host, nd):
        if not (host.flags.c_contiguous and host.flags.writeable):
            raise ValueError("download target must be a writeable C-contiguous array")
        if self.arch == "cuda":
            if self._staged(host):
                self._copy_staged(ndarray_pointer(nd), host, up=False)
            else:
                self.driver.download(host.ctypes.data, ndarray_pointer(nd), host.nbytes)
        else:
            ctypes.memmove(host.ctypes.data, ndarray_pointer(nd), host.nbytes)

    def _staged(self, host):
        return (_device._policy[-1] == "staged" and host.nbytes >= PIN_MIN_BYTES
                and not self.driver.is_pinned(host.ctypes.data))

    def _staging(self, nbytes):
        """The address of the staging frame, at least ``nbytes`` long."""
        if self._stage is None or self._stage[1] < nbytes:
            self._stage = None
            address = self.driver.host_alloc(nbytes)
            self._stage = (address, nbytes)
            done = weakref.finalize(self, self.driver.free_host, address)
            done.atexit = False  # the driver may be gone at exit; the process frees it
        return self._stage[0]

    def _copy_staged(self, device, host, up):
        stage = self._staging(host.nbytes)
        nbytes = host.nbytes
        view = host.reshape(-1).view(np.uint8)
        driver = self.driver

        def chunk(lo):
            hi = min(nbytes, lo + STAGE_CHUNK)
            staged = np.ctypeslib.as_array((ctypes.c_uint8 * (hi - lo)).from_address(stage + lo))
            if up:
                np.copyto(staged, view[lo:hi])
                driver.upload(device + lo, stage + lo, hi - lo)
            else:
                driver.download(stage + lo, device + lo, hi - lo)
                np.copyto(view[lo:hi], staged)

        # list() re-raises the first failure of any chunk
        list(_copy_workers().map(chunk, range(0, nbytes, STAGE_CHUNK)))


_workers = None
_workers_lock = threading.Lock()


def _copy_workers():
    """The process's pool of copy threads (NumPy's copies and the driver's
    calls release the GIL, so they run in parallel)."""
    global _workers
    with _workers_lock:
        if _workers is None:
            # measured on a 16-core host with an H200: 8 threads, 4 MiB chunks moved
            # 25-28 GB/s (pinned DMA alone: 52 GB/s); 16 threads, 2 MiB: 14-15 GB/s
            n = max(1, min(8, (os.cpu_count() or 2) // 2))
            _workers = concurrent.futures.ThreadPoolExecutor(n, thread_name_prefix="ipc-copy")
        return _workers

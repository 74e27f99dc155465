"""The pages of a memory-mapped output: written to disk while the next frames
are computed.

A product's science HDU is written through a memory map of the temporary
output (:func:`ipc_taichi.products.fitsfile.write_skeleton` places it, the
correction stores each frame's answer into it). Before the file is renamed
into place its pages are synchronised to disk (``msync``), which reports an
I/O error the writes themselves cannot (a memory map has no ``write`` call
to fail). Left to the end, that wait is the disk's time for the whole array
(a Roman-like 4096x4096 x 12 float32 ramp, 805 MB: 0.21-0.37 s on a 2-core
AMD EPYC VM, about a seventh of the whole command's time). :class:`OutputPages` starts
each frame's writeback as soon as the frame is written (Linux's
``sync_file_range(SYNC_FILE_RANGE_WRITE)``: the kernel queues the I/O and
returns), so the disk works while the next frame is computed and the final
``msync`` waits for the last frame only (0.02 s in the case above): the same
guarantee, the same error report, the wait overlapped.

Where the call is missing (not Linux), the writeback is the final ``msync``
alone, as before.

Tried and not kept: mapping the input's and the output's pages ahead, in a
thread, while Taichi is imported and started (``MADV_POPULATE_READ`` /
``_WRITE``, 4 MB per call). The pages cost as much to map in one call as one
fault at a time, and the thread slowed the main one (``import taichi`` 0.12
-> 0.28-0.55 s, ``ti.init`` 0.10 -> 0.15-0.22 s: the process's memory map is
locked while pages are mapped); the ramp above took longer with it.
"""

import ctypes
import functools
import os

import numpy as np

__all__ = ["OutputPages", "byte_range"]

_SYNC_FILE_RANGE_WRITE = 2  # <fcntl.h>: start writeback of the range's dirty pages, no wait


@functools.cache
def _sync_file_range():
    """libc's ``sync_file_range`` (Linux), or None."""
    try:
        call = ctypes.CDLL(None, use_errno=True).sync_file_range
    except (AttributeError, OSError, TypeError):  # not in this libc; Windows: no CDLL(None)
        return None
    call.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]
    call.restype = ctypes.c_int
    return call


def byte_range(view, base):
    """``(start, stop)``: the bytes of ``base`` (a C-contiguous array) that
    ``view`` (a view of it) spans, first to last element."""
    start = view.ctypes.data - base.ctypes.data
    if view.size == 0:
        return start, start
    low = sum((n - 1) * s for n, s in zip(view.shape, view.strides) if s < 0)
    high = sum((n - 1) * s for n, s in zip(view.shape, view.strides) if s > 0)
    return start + low, start + high + view.itemsize


class OutputPages:
    """The memory map of one HDU's data in a temporary output file (``array``,
    big-endian ``dtype`` at byte ``offset``, ``shape``), whose finished frames
    go to disk while the next ones are computed (:meth:`written`);
    :meth:`close` synchronises the rest (``msync``) and unmaps it."""

    def __init__(self, path, dtype, offset, shape):
        self.array = np.memmap(path, dtype=np.dtype(dtype).newbyteorder(">"), mode="r+",
                               offset=offset, shape=shape)
        self.offset = offset
        self._call = _sync_file_range()
        self._fd = os.open(path, os.O_RDONLY) if self._call is not None else None

    def written(self, view):
        """Start the writeback of the pages under ``view`` (a view of
        :attr:`array` its caller has finished writing); returns at once."""
        if self._fd is None:
            return
        start, stop = byte_range(view, self.array)
        if stop > start and self._call(self._fd, self.offset + start, stop - start,
                                       _SYNC_FILE_RANGE_WRITE) != 0:
            self._release()  # an error here is reported by close's msync; stop kicking

    def close(self, sync=True):
        """``msync`` the map when ``sync`` (the rest of its writeback, and any
        I/O error as :class:`OSError`), then unmap it."""
        try:
            if sync:
                self.array.flush()
        finally:
            self._release()
            del self.array

    def _release(self):
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


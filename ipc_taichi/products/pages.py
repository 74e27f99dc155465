"""The pages of a memory-mapped output: written to disk while the next frames
are computed.

A product's science HDU is written through a memory map of the temporary
output (:func:`ipc_taichi.products.fitsfile.write_skeleton` places it, the
correction stores each frame's answer into it). Before the file is renamed
into place its pages are synchronised to disk (``msync``), which reports an
I/O error the writes themselves cannot (a memory map has no ``write`` call
to fail). Left to the end, that wait is the disk's time for the whole array
(a Roman-like 4096x4096 x 12 float32 ramp, 805 MB: 0.21-0.37 s on a 2-core
AMD EPYC VM, a quarter of the ramp's correction). :class:`OutputPages` starts
each frame's writeback as soon as the frame is written (Linux's
``sync_file_range(SYNC_FILE_RANGE_WRITE)``: the kernel queues the I/O and
returns), so the disk works while the next frame is computed and the final
``msync`` waits for the last frame only (0.02 s in the case above): the same
guarantee, the same error report, the wait overlapped.

Where the call is missing (not Linux), the writeback is the final ``msync``
alone, as before.
"""

import ctypes
import functools
import mmap
import os
import threading

import numpy as np

__all__ = ["OutputPages", "byte_range"]

_MADV_WILLNEED = 3  # <sys/mman.h>: read ahead
_MADV_POPULATE_READ = 22  # Linux 5.14: fault the range in (read from disk if need be)
_MADV_POPULATE_WRITE = 23  # Linux 5.14: fault the range in, writeable
_PIECE = 1 << 22  # bytes per madvise call of the pager (see _map_pages)
_SYNC_FILE_RANGE_WRITE = 2  # <fcntl.h>: start writeback of the range's dirty pages, no wait


@functools.cache
def _madvise():
    """libc's ``madvise``, or None."""
    try:
        call = ctypes.CDLL(None, use_errno=True).madvise
    except (AttributeError, OSError):
        return None
    call.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    call.restype = ctypes.c_int
    return call


@functools.cache
def _sync_file_range():
    """libc's ``sync_file_range`` (Linux), or None."""
    try:
        call = ctypes.CDLL(None, use_errno=True).sync_file_range
    except (AttributeError, OSError):
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
        self._pager = None

    def prefetch(self, source):
        """Start mapping, in a thread, the pages of ``source`` (the input
        array, as read: a memory map of the input file, or memory) and of
        :attr:`array`, frame by frame, input then output (Linux >= 5.14's
        ``MADV_POPULATE_READ`` / ``_WRITE``; an older kernel: the input's
        read-ahead asked, ``MADV_WILLNEED``; elsewhere nothing). For a
        correction that reads and writes the whole array anyway: its pages are
        read from disk (a file not in the page cache) and mapped while the
        runtime starts and the first frames are computed, not one page fault
        at a time in the frame loop; the thread holds no lock the loop needs
        (``madvise`` runs without the GIL)."""
        if _madvise() is None or source.shape != self.array.shape or self.array.size == 0:
            return
        pairs = [(source[k], self.array[k]) for k in np.ndindex(self.array.shape[:-2])]
        self._pager = threading.Thread(target=_map_pages, args=(pairs,), daemon=True,
                                       name="ipc_taichi pages")
        self._pager.start()

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
        if self._pager is not None:  # never unmap pages a thread is still mapping
            self._pager.join()
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


def _page_span(view):
    """``(address, length)``: the whole pages under ``view``."""
    low, high = byte_range(view, view)
    low, high = view.ctypes.data + low, view.ctypes.data + high
    start = low - low % mmap.PAGESIZE
    return start, high - start


def _map_pages(pairs):
    """Map each ``(input, output)`` frame's pages in turn (see
    :meth:`OutputPages.prefetch`); an old kernel's ``EINVAL`` falls back to
    read-ahead of the inputs alone."""
    call = _madvise()
    populate = True

    def advise(view, advice):
        """``madvise`` in pieces of :data:`_PIECE` bytes: the process's memory
        map stays locked for one piece at a time (the main thread's own
        ``mmap`` calls, e.g. the runtime's, wait for no more than that)."""
        start, length = _page_span(view)
        for at in range(start, start + length, _PIECE):
            if call(at, min(_PIECE, start + length - at), advice) != 0:
                return False
        return True

    for source, target in pairs:
        if source.size == 0:
            continue
        if populate:
            populate = advise(source, _MADV_POPULATE_READ)  # False: not Linux 5.14
            if populate:
                advise(target, _MADV_POPULATE_WRITE)
        if not populate:
            advise(source, _MADV_WILLNEED)

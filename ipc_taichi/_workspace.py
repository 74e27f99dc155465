"""The working arrays of the engine (:mod:`ipc_taichi._engine`) for frames of
one shape: :class:`Workspace`, allocated once per shape and reused by every
frame of a stack and by later calls, and :func:`interior`, the frame inside a
padded array.
"""

import numpy as np

from ._copies import HostCopies
from ._device import ndarray_pointer, pinned_empty
from ._layouts import kernel_layout

__all__ = ["Workspace", "interior", "MAXIMA_SLOTS"]

# steps whose maxima may be on their way to the host at once (two are: the
# step the host waits for and the one launched ahead of it)
MAXIMA_SLOTS = 4


def interior(padded, reach, shape):
    """The ``shape`` frame inside a padded array (a view): rows and columns
    from ``reach`` on (a ``lanes`` row has more border on the right)."""
    return padded[reach:reach + shape[0], reach:reach + shape[1]]


class Workspace:
    """The working arrays for frames of one shape, allocated once and reused.

    ``prev`` and ``nxt`` (padded by ``reach``, zero border never written), the
    padded ``ok`` byte array (border 1 for the ``zero`` edge, 0 for
    ``isolated``; interior written by ``load``), the per-thread ``partials``
    of the stopping-rule maxima, the sweep's ring rows, and on the device path
    the unpadded ``io`` frame and ``mask`` bytes. On the CPU they are NumPy
    arrays (Taichi reads them in place); on CUDA Taichi ndarrays in device
    memory. The ``lanes`` layout's arrays (:mod:`ipc_taichi._lanes`) are
    64-byte aligned, their rows rounded up to whole vectors; it adds
    ``measured`` (the padded measured frame its step reads) and holds ``ok``
    as reals, made only when a step gates alphas (:meth:`ok_array`).
    """

    def __init__(self, info, shape, config, device_buffers):
        ny, nx = shape
        r = config.reach
        self.shape = shape
        self.reach = r
        self.layout = layout = kernel_layout(config.layout)
        layout.check(device_buffers)
        self.device_buffers = device_buffers
        self.dtype = np.dtype(info.dtype)
        padded = layout.padded_shape(shape, r, info.precision)
        self.strip = layout.rows_per_task(ny, nx)
        self.n_partials = layout.partials(ny, nx, self.strip)
        self._made = []
        self.prev = self._zeros(padded, self.dtype)
        self.nxt = self._zeros(padded, self.dtype)
        # the measured frame, padded as the step reads it (lanes)
        self.measured = self._zeros(padded, self.dtype) if layout.padded_base else None
        self.start = self.prev  # where the frame's S_0 is (see place_measured)
        self._padded, self._edge = padded, config.edge
        self.ok = None
        if layout.real_ok:  # reals (1.0 = may couple), made when first needed (see ok_array)
            self.no_ok = self._zeros((1, padded[1]), self.dtype)  # what a step without gating gets
            if config.edge == "isolated":
                self.ok_array()
        elif device_buffers:
            self.ok = self._zeros(padded, np.uint8)
            self.ok.from_numpy(self._ok_values(np.uint8))
        else:
            self.ok = self._ok_values(np.uint8)
            self._made.append(self.ok.nbytes)
        self.partials = self._zeros((self.n_partials, 2), self.dtype)
        self.ring = self._zeros(layout.ring_shape(config, ny, padded[1]), self.dtype)
        self.flag = self._zeros((1,), self.dtype)
        self.flag_bytes = self.dtype.itemsize
        self.no_mask = self._zeros((1, 1), np.uint8)
        self._io = None
        self._mask = None
        self.ok_clean = True  # the interior of ``ok`` is all 1
        self._staging = None
        self.copies = HostCopies(info.arch) if device_buffers else None
        self._slots = self._events = None  # maxima_start's page-locked slots and events
        self._slot = 0

    def _ok_values(self, dtype):
        """``ok`` for a frame without bad pixels: border 1 (``zero`` edge) or 0
        (``isolated``), interior 1 (see ``ok_clean``)."""
        fill = 1 if self._edge == "zero" else 0
        ok = self.layout.host_zeros(self._padded, dtype, fill)
        interior(ok, self.reach, self.shape)[...] = 1
        return ok

    def ok_array(self):
        """The padded ``ok`` array, made on the first call of a ``lanes``
        workspace (a frame's worth of reals: only steps that gate alphas read
        it, those with the ``isolated`` edge or bad pixels)."""
        if self.ok is None:
            self.ok = self._ok_values(self.dtype)
            self._made.append(self.ok.nbytes)
        return self.ok

    def place_measured(self, base, warm):
        """Where the frame's ``S_0`` is, after a host load of the measured
        frame ``base`` (unpadded): ``prev`` (which the load fills), unless the
        step reads the measured frame padded (``lanes``): then ``base`` goes
        into ``measured``, and without a warm start the first step reads it
        as ``S_0`` (no step writes it)."""
        self.start = self.prev
        if self.measured is not None:
            interior(self.measured, self.reach, self.shape)[...] = base
            if not warm:
                self.start = self.measured
        return self.start

    def holding(self, q):
        """The padded array holding ``S_q`` of the frame's Jacobi iterations:
        ``start`` for ``S_0``, then ``nxt`` and ``prev`` in turn (the two
        working arrays swap roles every iteration; their borders stay zero)."""
        if q == 0:
            return self.start
        return self.nxt if q % 2 else self.prev

    def _zeros(self, shape, dtype, fill=0):
        if not self.device_buffers:
            arr = self.layout.host_zeros(shape, dtype, fill)
        else:
            import taichi as ti

            kind = {np.dtype(np.float64): ti.f64, np.dtype(np.float32): ti.f32,
                    np.dtype(np.uint8): ti.u8}[np.dtype(dtype)]
            arr = ti.ndarray(dtype=kind, shape=shape)
            arr.fill(fill)
        self._made.append(int(np.prod(shape)) * np.dtype(dtype).itemsize)
        return arr

    @property
    def nbytes(self):
        """Bytes of every buffer this workspace has allocated."""
        return sum(self._made)

    @property
    def io(self):
        """The unpadded frame on the device (device path, NumPy input)."""
        if self._io is None:
            self._io = self._zeros(self.shape, self.dtype)
        return self._io

    def mask_buffer(self):
        if self._mask is None:
            self._mask = self._zeros(self.shape, np.uint8)
        return self._mask

    def staging(self, arch):
        """A host frame in the runtime dtype, page-locked on CUDA, for inputs
        that must be converted before the upload (other dtype, strided)."""
        if self._staging is None:
            self._staging = pinned_empty(self.shape, self.dtype, arch=arch)
        return self._staging

    def read(self, array, n):
        """The first ``n`` values of a small buffer (maxima, flag) as floats."""
        if not self.device_buffers:
            return [float(v) for v in array.reshape(-1)[:n]]
        host = np.empty(n, dtype=self.dtype)
        self.copies.download(host, array)  # copies host.nbytes from the start
        return [float(v) for v in host]

    def clear_flag(self):
        if self.device_buffers and self.copies.arch == "cuda":
            # ordered on the stream like a kernel: no wait for the work before it
            self.copies.driver.memset_async(ndarray_pointer(self.flag), 0, self.flag_bytes)
        elif self.device_buffers:
            self.copies.upload(self.flag, np.zeros(1, dtype=self.dtype))
        else:
            self.flag[0] = 0

    def maxima_start(self):
        """After a step's launch: its maxima on their way to the host. On CUDA
        an asynchronous copy of the rows the tree leaves into one of
        :data:`MAXIMA_SLOTS` page-locked slots, then an event; the next step
        may be launched at once (the copy is ordered before it on the stream).
        Elsewhere the maxima themselves. Returns a handle for :meth:`maxima_wait`."""
        if not (self.device_buffers and self.copies.arch == "cuda"):
            return ("now", self.maxima())
        n = self.layout.maxima_rows(self.n_partials)
        driver = self.copies.driver
        if self._slots is None:
            self._slots = pinned_empty((MAXIMA_SLOTS, n, 2), self.dtype, arch="cuda",
                                       driver=driver)
            self._events = [driver.event() for _ in range(MAXIMA_SLOTS)]
            self._partials_at = ndarray_pointer(self.partials)
        slot = self._slot = (self._slot + 1) % MAXIMA_SLOTS
        driver.download_async(self._slots[slot].ctypes.data, self._partials_at,
                              self._slots[slot].nbytes)
        driver.record(self._events[slot])
        return ("slot", slot)

    def maxima_wait(self, handle):
        """``(max|dst - src|, max|dst|)`` of the step of ``handle``
        (:meth:`maxima_start`), waiting for it if it is still on its way."""
        kind, value = handle
        if kind == "now":
            return value
        self.copies.driver.wait(self._events[value])
        d, s = self._slots[value].max(axis=0)
        return float(d), float(s)

    def maxima(self):
        """``(max|dst - src|, max|dst|)`` of the last step: the maximum over the
        rows the tree leaves (``pixel``: row 0 unless the frame is wider than
        the tree's capacity) or over the strips' rows (``sweep``)."""
        n = self.layout.maxima_rows(self.n_partials)
        if self.device_buffers:
            rows = np.empty((n, 2), dtype=self.dtype)
            self.copies.download(rows, self.partials)
        else:
            rows = self.partials[:n]
        d, s = rows.max(axis=0)
        return float(d), float(s)

    def estimate(self, src):
        """The current estimate as a NumPy frame (a view on the CPU path, a
        copy from the device otherwise)."""
        padded = src.to_numpy() if self.device_buffers else src
        return interior(padded, self.reach, self.shape)

"""The engine behind :func:`ipc_taichi.couple` and :func:`ipc_taichi.decouple`.

Per call: validate the input once (:func:`ipc_taichi._inputs.as_stack`: a
NumPy-readable array, a PyTorch tensor, or a CuPy/JAX/DLPack array seen through
PyTorch, see :mod:`ipc_taichi._device`), take the :class:`Workspace` of the frame shape from
a small cache (its padded working arrays are allocated once per shape and reused
by every frame of a stack and by later calls), and run the frames one by one:

1. the frame goes into the unpadded ``io`` buffer: on CUDA one host-to-device
   copy from page-locked memory (NumPy input), or a device copy into the
   output tensor (device input); on the CPU the caller's frame is read in place
   when it can be (runtime dtype, contiguous, no bad pixel);
2. ``load`` (one kernel) pads and initialises on the device: the padded
   estimate ``S_0 = M``, the ``ok`` array, bad pixels zeroed, one flag saying
   whether any pixel is bad (which picks the kernel variant that gates alphas);
   on the CPU NumPy does the same (:func:`_load_host`);
3. one ``step`` kernel per iteration: Jacobi step plus the two stopping-rule
   maxima, reduced in the same launch on the GPU layout, by the host over the
   CPU sweep's few dozen strips (see :mod:`ipc_taichi._kernels`); only those
   numbers come back to the host;
4. ``store`` (one kernel; a NumPy copy on the CPU) copies the estimate into
   ``io``; on CUDA with NumPy output one device-to-host copy into the
   (page-locked) result;
5. bad pixels get their kept values back (masked: input value, non-finite:
   NaN) from the input, on the input's own device.

Kernels are compiled once per configuration (:mod:`ipc_taichi._kernels` caches
them) and never per shape or per call: frame sizes are run-time arguments.
"""

import collections
import threading

import numpy as np

from . import runtime
from ._device import (
    check_torch_device,
    kind_of,
    pinned_for_call,
    register_per_call,
    shares_memory,
    to_torch,
    torch_dtype,
    torch_stream_order,
)
from ._frames import finite_sum
from ._inputs import Frames, as_result, as_stack
from ._kernels import FrameKernels, KernelConfig, get_frame_kernels, kernel_law_kind
from ._launch import fast
from ._layouts import STRIP_ROWS, default_layout, get_step_kernel, kernel_layout
from ._warm import WarmStart
from ._workspace import Workspace, interior
from .errors import IPCInputError

WORKSPACES_KEPT = 2  # frame shapes whose buffers stay allocated
# the engine path with Taichi ndarrays and explicit copies, as on CUDA; tests
# set it to run that path on the CPU
FORCE_DEVICE_BUFFERS = False

__all__ = ["as_stack", "Frames", "Workspace", "run_couple", "run_decouple", "interior",
           "default_layout", "start", "STRIP_ROWS", "workspace_cache_info", "clear_workspaces",
           "cached_workspaces", "as_result", "frame_copies", "ENGINE_LOCK"]


def start(arch, precision):
    return runtime.init(arch, precision)


# Taichi has one runtime per process, with one buffer of kernel temporaries
# and one ``partials``/flag read-back protocol per workspace: calls from two
# threads would corrupt each other's stopping-rule maxima. Every call holds
# this lock (re-entrant: a decouple callback may call couple), so threads are
# served one after the other, safely; parallelism is across processes.
ENGINE_LOCK = threading.RLock()
_workspaces = collections.OrderedDict()


def _cache():
    return _workspaces


def _workspace(info, shape, config, device_buffers):
    key = (info.arch, info.precision, tuple(shape), config.offsets, config.edge, config.layout,
           device_buffers)
    cache = _cache()
    ws = cache.get(key)
    if ws is None:
        while len(cache) >= WORKSPACES_KEPT:
            cache.popitem(last=False)
        ws = cache[key] = Workspace(info, shape, config, device_buffers)
    else:
        cache.move_to_end(key)
    return ws


def cached_workspaces():
    """The cached workspaces, least recently used first."""
    return list(_cache().values())


def clear_workspaces():
    """Free every cached workspace (their memory goes back to Taichi or NumPy),
    and the bond maps' kernel copies."""
    with ENGINE_LOCK:
        _workspaces.clear()
        _bond_cache.clear()


def workspace_cache_info():
    """``{key: bytes}`` of the cached workspaces (tests, benchmark)."""
    return {k: ws.nbytes for k, ws in _cache().items()}


def frame_copies():
    """The benchmark's hook for timing the host<->device copies alone:
    ``(upload(host), download(host))`` between a host frame and the device
    frame of the most recently used workspace, or ``None`` when that
    workspace keeps no device frame (the CPU path)."""
    with ENGINE_LOCK:
        ws = next(reversed(_workspaces.values()), None)
        if ws is None or not ws.device_buffers:
            return None
        return (lambda host: ws.copies.upload(ws.io, host),
                lambda host: ws.copies.download(host, ws.io))


runtime.on_reset(clear_workspaces)


# --------------------------------------------------------------------------- parameters

_params = collections.OrderedDict()


def _model_arrays(model, info, device_buffers):
    """The law's and geometry's kernel arguments (cached: one upload per model)."""
    law, half = model.law, model.geometry.half_stencil()
    dtype = info.dtype
    p = law.kernel_params().astype(dtype)
    w = np.array([wts for _, wts in half], dtype=dtype)
    table = np.ascontiguousarray(law.table if law.kind == "table" else np.zeros((2, 2)),
                                 dtype=dtype)
    key = (info.arch, info.precision, device_buffers, p.tobytes(), w.tobytes(),
           table.shape, table.tobytes())
    hit = _params.get(key)
    if hit is None:
        hit = tuple(_to_taichi(a) if device_buffers else a for a in (p, w, table))
        _params[key] = hit
        while len(_params) > 8:
            _params.popitem(last=False)
    return hit


_bond_cache = collections.OrderedDict()


def _bond_arrays(bonds, info, config, device_buffers):
    """The bond map as the step kernels read it (cached: one copy per map,
    layout and precision): padded by the geometry's reach with the map's edge
    rule (:meth:`~ipc_taichi.bondmap.BondMap.padded`), in the working precision,
    at the same index as the padded frames (``lanes``: rows as wide as its
    frames' padded rows, 64-byte aligned); 3-D ``[k, y, x]`` on the device path,
    on the host as the layout's kernel reads it (:meth:`~ipc_taichi._layouts.Layout.bond_array`)."""
    key = (id(bonds), info.arch, info.precision, config.layout, device_buffers)
    hit = _bond_cache.get(key)
    if hit is not None and hit[0] is bonds:
        _bond_cache.move_to_end(key)
        return hit[1]
    padded = bonds.padded(config.reach, info.dtype)
    array = _to_taichi(padded) if device_buffers \
        else kernel_layout(config.layout).bond_array(padded, config.reach, info.precision)
    while len(_bond_cache) >= WORKSPACES_KEPT:
        _bond_cache.popitem(last=False)
    _bond_cache[key] = (bonds, array)
    return array


def _no_bonds(info, device_buffers):
    """What a step without a map gets for its (unused) ``bonds`` argument."""
    key = ("none", info.arch, info.precision, device_buffers)
    hit = _params.get(key)
    if hit is None:
        empty = np.zeros((1, 1, 1) if device_buffers else (1,), dtype=info.dtype)
        hit = _params[key] = _to_taichi(empty) if device_buffers else empty
    return hit


def _to_taichi(array):
    import taichi as ti

    kind = {np.dtype(np.float64): ti.f64, np.dtype(np.float32): ti.f32}[array.dtype]
    nd = ti.ndarray(dtype=kind, shape=array.shape)
    nd.from_numpy(array)
    return nd


runtime.on_reset(_params.clear)


# --------------------------------------------------------------------------- running

class _Run:
    """One call: the model's kernels and arguments, the workspace, the frames."""

    def __init__(self, frames, model, info, layout, what):
        if model.bonds is not None:
            model.bonds.check(model.geometry, frames.shape[1:])
        self.frames = frames
        self.info = info
        offsets = tuple(u for u, _ in model.geometry.half_stencil())
        if frames.on_device:
            check_torch_device(frames.data, info.arch, what)
        # working arrays live where the kernels run (Taichi ndarrays on CUDA);
        # a tensor's frame is handed to Taichi as it is, a NumPy frame copied
        device_buffers = info.arch == "cuda" or FORCE_DEVICE_BUFFERS
        layout = layout or default_layout(info.arch, device_buffers)
        self.device_buffers = device_buffers
        # host arrays go to the kernels flat (see KernelConfig.flat)
        self.configs = {m: KernelConfig(offsets=offsets, law_kind=kernel_law_kind(model.law),
                                        edge=model.edge, masked=m, precision=info.precision,
                                        layout=layout, flat=not device_buffers,
                                        mapped=model.bonds is not None)
                        for m in (False, True)}
        self.copy_frames = device_buffers and not frames.on_device
        self.ws = _workspace(info, frames.shape[1:], self.configs[False], device_buffers)
        self.p, self.w, self.table = _model_arrays(model, info, device_buffers)
        self.bonds = (_no_bonds(info, device_buffers) if model.bonds is None
                      else _bond_arrays(model.bonds, info, self.configs[False], device_buffers))
        kernels = get_frame_kernels(info.precision)
        # the device path launches its kernels by the short route (see _launch)
        self.kernels = FrameKernels(fast(kernels.load), fast(kernels.store)) \
            if device_buffers else kernels
        # out= is the input (or overlaps it): each frame is kept before it is
        # overwritten, for its bad pixels' values
        self.aliased = False
        self.kept = None
        self.loose = None  # the caller's out when results are copied there at the end

    def output(self, out):
        """The result stack (the caller's ``out`` after checks, or a new one)."""
        shape, frames = self.frames.shape, self.frames
        if frames.on_device:
            import torch

            dt = torch_dtype(self.info.dtype)
            if out is None:
                return torch.empty(shape, dtype=dt, device=frames.data.device)
            out = to_torch(out, kind_of(out))
            out3 = out.unsqueeze(0) if out.dim() == 2 else out
            if tuple(out3.shape) != shape or out3.dtype != dt or not out3.is_contiguous() \
                    or out3.device != frames.data.device:
                raise IPCInputError(f"out: expected a contiguous {dt} array of shape "
                                    f"{shape[1:] if frames.was_2d else shape} on "
                                    f"{frames.data.device}")
            self.aliased = self._check_alias(out3)
            return out3
        if out is None:
            return np.empty(shape, dtype=self.info.dtype)
        out3 = out[np.newaxis] if isinstance(out, np.ndarray) and out.ndim == 2 else out
        if not (isinstance(out3, np.ndarray) and out3.shape == shape
                and out3.dtype.kind == "f" and out3.flags.writeable):
            raise IPCInputError(f"out: expected a writeable {self.info.dtype} NumPy array of "
                                f"shape {shape[1:] if frames.was_2d else shape}")
        self.aliased = self._check_alias(out3)
        if out3.dtype != self.info.dtype or not out3.flags.c_contiguous:
            if self.aliased:
                raise IPCInputError("out: the input itself must be a C-contiguous "
                                    f"{self.info.dtype} array")
            if self.device_buffers:  # a strict frame stack, copied into out at the end
                self.loose = out3
                return np.empty(shape, dtype=self.info.dtype)
        return out3

    def _check_alias(self, out3):
        """Whether ``out`` is the input itself (then each frame is kept before
        it is overwritten); ``out`` overlapping the input otherwise is refused."""
        data = self.frames.data
        if not shares_memory(out3, data):
            return False
        if isinstance(data, np.ndarray):
            same = (out3.__array_interface__["data"][0] == data.__array_interface__["data"][0]
                    and out3.strides == data.strides)
        else:
            same = out3.data_ptr() == data.data_ptr() and out3.stride() == data.stride()
        if not same:
            raise IPCInputError("out: overlaps the input without being it; pass the input "
                                "itself, or memory of its own")
        return True

    def pinned(self, out):
        """Page-lock the NumPy input and output for this call (CUDA, under the
        ``register`` copy policy only: by default large frames are staged,
        see :class:`~ipc_taichi._device.HostCopies`)."""
        host = self.frames.kind == "numpy" and self.info.arch == "cuda" and register_per_call()
        data = self.frames.data if host and _uploadable(self.frames.data, self.ws.dtype) \
            else None
        return pinned_for_call([data, out if host else None], self.info.arch, enabled=host)

    def load(self, k, out, shift=None):
        """Frame ``k`` into the workspace; returns ``(base, io, any_bad)``: the
        unpadded measured frame the steps read (bad pixels zeroed), the result
        frame, and whether any pixel is bad. On the host path, ``shift`` (a
        frame, optional) is added to the start: ``S_0 = M + shift``."""
        frames, ws = self.frames, self.ws
        bad = None if frames.bad is None else frames.bad[k]
        if self.aliased:
            self.kept = frames.data[k].clone() if frames.on_device else frames.data[k].copy()
        if not self.device_buffers:
            io = out[k]
            host = frames.data[k]
            if frames.on_device:  # a CPU tensor: the same memory seen by NumPy
                io, host = io.numpy(), _numpy_view(host, out.dtype)
                bad = None if bad is None else bad.numpy()
            base, any_bad = _load_host(host, bad, io, ws, shift)
            return base, io, any_bad
        src = None  # where load reads the frame; None: from io itself
        if frames.on_device:
            io = out[k]
            data = frames.data[k]
            if self.aliased or data.dtype != io.dtype or not data.is_contiguous():
                io.copy_(data)
            else:  # load copies the input into io itself: one pass over the frame less
                src = data
            mask = ws.no_mask if bad is None else bad.to(dtype=_torch_u8()).contiguous()
        else:
            io = ws.io
            host = frames.data[k]
            if not _uploadable(host, ws.dtype):
                staging = ws.staging(self.info.arch)
                np.copyto(staging, host, casting="unsafe")
                host = staging
            ws.copies.upload(io, host)
            mask = ws.no_mask
            if bad is not None:
                mask = ws.mask_buffer()
                ws.copies.upload(mask, np.ascontiguousarray(bad, dtype=np.uint8))
        ws.clear_flag()
        ws.start = ws.prev
        self.kernels.load(io if src is None else src, io, 0 if src is None else 1, mask,
                          0 if bad is None else 1, ws.prev, ws.ok, ws.reach, ws.flag)
        any_bad = ws.read(ws.flag, 1)[0] != 0
        ws.ok_clean = not any_bad
        return io, io, any_bad

    def step(self, masked, src, base, dst, sign):
        """One step; returns ``(max|dst - src|, max|dst|)`` over good pixels."""
        self._launch(masked, src, base, dst, sign)
        return self.ws.maxima()

    def launch(self, masked, src, base, dst, sign):
        """One step, launched; returns a handle whose maxima
        :meth:`~ipc_taichi._workspace.Workspace.maxima_wait` gives. On CUDA
        nothing waits for the device: the maxima come back by an asynchronous
        copy into page-locked memory, so the host can launch the next step
        while this one runs."""
        self._launch(masked, src, base, dst, sign)
        return self.ws.maxima_start()

    def _launch(self, masked, src, base, dst, sign):
        ws = self.ws
        config = self.configs[masked]
        kernel = get_step_kernel(config)
        if self.device_buffers:
            kernel = fast(kernel)
        src, base, dst, ok, bonds, table, ring = ws.layout.arguments(ws, config, src, base, dst,
                                                                     self.table, self.bonds)
        kernel(src, base, dst, ok, bonds, self.p, self.w, table, float(sign), ws.partials,
               ring, ws.strip, ws.shape[1])

    def finish(self, k, io, src, out, any_bad):
        """The estimate in padded ``src`` into the result frame ``io`` (= frame
        ``k`` of ``out``, or the device frame that is then copied there)."""
        ws = self.ws
        if self.device_buffers:
            self.kernels.store(src, io, ws.reach)
            if self.copy_frames:
                ws.copies.download(out[k], io)
        else:
            # on the CPU a copy by NumPy costs less than a kernel launch
            np.copyto(io, interior(src, ws.reach, ws.shape))
        if any_bad:
            self.restore(k, out)

    def restore(self, k, out):
        """Bad pixels keep their input value (masked) or become NaN (not finite)."""
        frames = self.frames
        src = self.kept if self.aliased else frames.data[k]
        if frames.on_device:
            import torch

            kept = src.to(out.dtype)
            bad = ~torch.isfinite(kept)
            kept = torch.where(bad, torch.full_like(kept, float("nan")), kept)
            if frames.bad is not None:
                bad = bad | frames.bad[k]
            out[k] = torch.where(bad, kept, out[k])
            return
        kept = np.asarray(src).astype(out.dtype, copy=False)
        bad = ~np.isfinite(kept)
        if frames.bad is not None:
            bad |= frames.bad[k]
        values = kept[bad].astype(out.dtype)
        values[~np.isfinite(values)] = np.nan
        out[k][bad] = values


def _load_host(host, bad, io, ws, shift=None):
    """What the ``load`` kernel does (see :func:`ipc_taichi._kernels.get_frame_kernels`),
    in NumPy, on the CPU: Taichi's CPU code for this per-pixel copy is scalar and
    about twice as slow as NumPy's vectorised passes, and a launch costs more
    than the work on small tiles. Returns ``(base, any_bad)``: ``base`` is the
    caller's frame itself when it can be read as it is (runtime dtype,
    C-contiguous, no bad pixel), else ``io`` holding it with bad pixels zeroed."""
    # a finite sum means every pixel is finite (NaN and inf propagate): one read
    # of the frame, no temporary; of a float frame before its conversion (f32 for
    # an f64 run: half the bytes; an overflowing sum takes the per-pixel test)
    all_finite = bad is None and finite_sum(host)
    if not _uploadable(host, ws.dtype):
        np.copyto(io, host, casting="unsafe")
        host = io
    if all_finite:
        good, any_bad = None, False
    else:
        good = np.isfinite(host)
        if bad is not None:
            good &= ~bad
        any_bad = not good.all()
    base = host
    bad_px = ~good if any_bad else None
    if any_bad:
        if host is not io:
            np.copyto(io, host)
        io[bad_px] = 0.0
        base = io
    ws.place_measured(base, warm=shift is not None)
    start = interior(ws.prev, ws.reach, ws.shape)
    if shift is not None:  # a warm start, S_0 = M + shift, in the same pass
        if hasattr(shift, "add_to"):  # lanes: from the padded frame just placed (_warm.LaneShift)
            shift.add_to(ws)
        else:
            np.add(base, shift, out=start)
        if any_bad:
            start[bad_px] = 0.0
    elif ws.start is ws.prev:
        start[...] = base
    if any_bad or not ws.ok_clean:
        interior(ws.ok_array(), ws.reach, ws.shape)[...] = True if good is None else good
        ws.ok_clean = not any_bad
    return base, any_bad


def _uploadable(array, dtype):
    return array.dtype == dtype and array.flags.c_contiguous


def _numpy_view(tensor, dtype):
    """A CPU tensor seen by NumPy; a dtype NumPy lacks (bfloat16) converted
    to ``dtype`` (the output's) first."""
    try:
        return tensor.numpy()
    except TypeError:
        return tensor.to(dtype).numpy()


def _torch_u8():
    import torch

    return torch.uint8


def run_couple(frames, model, info, layout, out=None):
    """The forward model on every frame; returns the result stack."""
    with ENGINE_LOCK, _stream_order(frames) as order:
        run = _Run(frames, model, info, layout, "signal")
        ws = run.ws
        out = run.output(out)
        with run.pinned(out):
            for k in range(frames.shape[0]):
                base, io, any_bad = run.load(k, out)
                run.step(any_bad, ws.start, base, ws.nxt, +1.0)
                run.finish(k, io, ws.nxt, out, any_bad)
        order.adopt(out if frames.on_device else None)
    if run.loose is not None:
        np.copyto(run.loose, out, casting="unsafe")
        return run.loose
    return out


def run_decouple(frames, model, info, layout, iterate, out=None, warm_start=False):
    """Decouple every frame; ``iterate(k, step, ws, warm)`` runs the Jacobi
    iterations of frame ``k`` (the rules live with the caller) from the start
    the engine loaded into ``ws.start`` and returns the padded array holding the
    answer; ``warm`` says whether that start is the warm one (see
    :class:`WarmStart`; only with ``warm_start`` and from the second frame on)."""
    with ENGINE_LOCK, _stream_order(frames) as order:
        run = _Run(frames, model, info, layout, "measured")
        out = run.output(out)
        carried = not isinstance(warm_start, bool)  # a carrier: from the call before, to the next
        warm = _warm_for(run, warm_start, carried)
        with run.pinned(out):
            for k in range(frames.shape[0]):
                shift = warm.host_shift() if warm is not None else None
                base, io, any_bad = run.load(k, out, shift)
                warmed = warm is not None and warm.apply(shift)

                def step(src, dst, masked=any_bad, base=base):
                    return run.step(masked, src, base, dst, -1.0)

                if run.device_buffers:  # steps run ahead of the host (see decoupling)
                    def launch(src, dst, masked=any_bad, base=base):
                        return run.launch(masked, src, base, dst, -1.0)

                    step.launch, step.result = launch, run.ws.maxima_wait

                answer = iterate(k, step, run.ws, warmed)
                if warm is not None and (carried or k + 1 < frames.shape[0]):
                    warm.keep(answer, base)
                run.finish(k, io, answer, out, any_bad)
        order.adopt(out if frames.on_device else None)
    if carried:
        warm_start.state = warm
    if run.loose is not None:
        np.copyto(run.loose, out, casting="unsafe")
        return run.loose
    return out


def _warm_for(run, warm_start, carried):
    """The call's :class:`WarmStart`: none (cold), a new one (a stack with
    ``warm_start=True``), or with a carrier (an object with a ``state``
    attribute, :class:`ipc_taichi.decoupling.WarmCarry`) the one it carries
    from the call before, when that ran in this workspace (else a new one:
    the first frame starts from scratch)."""
    if not carried:
        return WarmStart(run) if warm_start and run.frames.shape[0] > 1 else None
    held = warm_start.state
    if held is not None and held.run.ws is run.ws:
        held.run = run
        return held
    return WarmStart(run)


def _stream_order(frames):
    """Order the call with the caller's PyTorch stream (device input only)."""
    return torch_stream_order(frames.data if frames.on_device else None)

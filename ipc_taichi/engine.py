"""The engine's public face for the benchmark and the tests: workspaces, copies, kernels.

Users call :func:`ipc_taichi.couple` and :func:`ipc_taichi.decouple`. What
``ipc_taichi.bench`` and the test suite need of the machinery behind them is
here, so that nothing outside the core imports a private module. The core is
the private modules (``ipc_taichi/_*.py``: ``_engine``, ``_kernels``,
``_alpha``, ``_device``, ``_inputs``, ``_warm``, ...) and the three modules
that face them: :mod:`ipc_taichi.coupling`, :mod:`ipc_taichi.decoupling` and
this one (``tests/test_repository.py`` checks it).

Workspaces
    :func:`cached_workspaces`, :func:`workspace_cache_info`,
    :func:`clear_workspaces`: the per-shape working arrays the engine keeps
    (:data:`ENGINE_LOCK` serialises the calls that use them).
Copies
    :func:`frame_copies` (the host<->device copies of the last workspace, for
    timing them alone), page-locked host memory (:func:`pinned_empty`,
    :class:`pinned_for_call`, :func:`pageable_copies`, :data:`PIN_MIN_BYTES`),
    the CUDA driver calls (:class:`CudaDriver`, :func:`cuda_driver`),
    :class:`HostCopies`, array kinds (:func:`kind_of`) and stream order
    (:class:`torch_stream_order`).
Kernels
    :class:`KernelConfig`, the layout objects (:data:`LAYOUTS`, :func:`kernel_layout`),
    :class:`StepPlan`, :func:`get_step_kernel`, :func:`get_frame_kernels`,
    :func:`get_reduce_kernel`, :func:`tree_rows`, :data:`FAN_IN`; the device law
    (:func:`make_alpha`, :func:`make_exp`, :func:`kernel_law_kind`);
    :func:`clear_kernels`; the ``lanes`` step's vector unit (:func:`vector_unit`
    of a CPU's flags, :func:`host_vector_unit` of this one or
    ``$IPC_TAICHI_LANES``, :func:`lane_count`, :func:`vector_extensions`).
Settings for a while
    Context managers that change one of the engine's layout constants and put
    it back: :func:`device_buffers` (the CUDA code path, run on the CPU),
    :func:`pixel_runs`, :func:`reduction_fan_in`, :func:`vector_unit_set` (the
    ``lanes`` step built for another vector unit), and :func:`step_kernels_built`
    (which step kernels a call asked for).
"""

import contextlib
import os

from . import _engine, _kernels, _layouts
from ._alpha import kernel_law_kind, make_alpha, make_exp
from ._copies import STAGE_CHUNK, HostCopies
from ._device import (
    CUDA_ERROR_HOST_MEMORY_ALREADY_REGISTERED,
    PIN_MIN_BYTES,
    CudaDriver,
    copy_policy,
    cuda_driver,
    kind_of,
    pageable_copies,
    pinned_empty,
    pinned_for_call,
    torch_stream_order,
)
from ._engine import (
    ENGINE_LOCK,
    cached_workspaces,
    clear_workspaces,
    frame_copies,
    workspace_cache_info,
)
from ._kernels import FAN_IN, KernelConfig, get_frame_kernels, get_reduce_kernel, tree_rows
from ._lanes import (
    LANES_ENV,
    aligned_zeros,
    host_vector_unit,
    lane_count,
    vector_extensions,
    vector_unit,
)
from ._layouts import LAYOUTS, StepPlan, default_layout, get_step_kernel, kernel_layout
from ._warm import LaneShift, lanes_warm_kernels

__all__ = [
    # workspaces
    "ENGINE_LOCK", "cached_workspaces", "workspace_cache_info", "clear_workspaces",
    # copies
    "frame_copies", "pinned_empty", "pinned_for_call", "pageable_copies", "copy_policy",
    "PIN_MIN_BYTES", "STAGE_CHUNK",
    "CudaDriver", "cuda_driver", "CUDA_ERROR_HOST_MEMORY_ALREADY_REGISTERED", "HostCopies",
    "kind_of", "torch_stream_order",
    # kernels
    "KernelConfig", "StepPlan", "get_step_kernel", "get_frame_kernels", "get_reduce_kernel",
    "LAYOUTS", "kernel_layout",
    "tree_rows",
    "FAN_IN", "make_alpha", "make_exp", "kernel_law_kind", "clear_kernels",
    "default_layout", "LANES_ENV", "vector_unit", "host_vector_unit", "lane_count",
    "vector_extensions", "aligned_zeros",
    # warm starts on the lanes layout
    "LaneShift", "lanes_warm_kernels",
    # settings for a while
    "device_buffers", "pixel_runs", "reduction_fan_in", "vector_unit_set", "step_kernels_built",
]


def clear_kernels():
    """Forget every compiled kernel and cached workspace (the next call
    compiles again): after a layout constant changed."""
    _layouts.clear_kernels()
    clear_workspaces()


@contextlib.contextmanager
def _set(module, **values):
    """``module``'s attributes set to ``values`` inside the context, then put back."""
    old = {name: getattr(module, name) for name in values}
    for name, value in values.items():
        setattr(module, name, value)
    try:
        yield
    finally:
        for name, value in old.items():
            setattr(module, name, value)


@contextlib.contextmanager
def device_buffers(forced=True):
    """Inside the context, the engine keeps its working arrays in Taichi
    ndarrays and copies frames in and out explicitly, as on CUDA, whatever the
    arch (``forced=False``: only on CUDA, the default). How the tests run the
    GPU engine's code path on the CPU."""
    with _set(_engine, FORCE_DEVICE_BUFFERS=forced):
        yield


@contextlib.contextmanager
def pixel_runs(threads=None, min_rows=None):
    """Inside the context, the ``pixel`` layout aims for ``threads`` threads
    per step with column runs of at least ``min_rows`` rows (``None``: as it
    is). Cached workspaces are freed on entry and exit, as their run height
    was cut for the old values."""
    values = {"PIXEL_THREADS": threads, "MIN_RUN_ROWS": min_rows}
    with _set(_layouts, **{k: v for k, v in values.items() if v is not None}):
        clear_workspaces()
        try:
            yield
        finally:
            clear_workspaces()


@contextlib.contextmanager
def reduction_fan_in(n):
    """Inside the context, the stopping-rule maxima are reduced by a tree of
    ``n`` entries per thread and level (capacity ``n ** 5`` partials instead of
    ``32 ** 5``), so a small frame is wider than the tree. Kernels and
    workspaces are rebuilt on entry and exit."""
    with _set(_kernels, FAN_IN=n):
        clear_kernels()
        try:
            yield
        finally:
            clear_kernels()


@contextlib.contextmanager
def vector_unit_set(name):
    """Inside the context, ``$IPC_TAICHI_LANES`` is ``name`` (``avx512``,
    ``avx2``, ``sse``, ``neon``, ``none``, or f32 lanes ``4``, ``8``, ``16``;
    ``None``: unset, this CPU's own):
    the ``lanes`` step is built for that vector unit's width. Kernels and
    workspaces are rebuilt on entry and exit; the variable is put back."""
    old = os.environ.get(LANES_ENV)
    try:
        _put_lanes_env(name)
        clear_kernels()
        yield
    finally:
        _put_lanes_env(old)
        clear_kernels()


def _put_lanes_env(value):
    """``$IPC_TAICHI_LANES`` set to ``value`` (``None``: unset)."""
    if value is None:
        os.environ.pop(LANES_ENV, None)
    else:
        os.environ[LANES_ENV] = value


@contextlib.contextmanager
def step_kernels_built():
    """Inside the context, the :class:`KernelConfig` of every step kernel the
    engine asks for is appended to the list the context yields (whether
    compiled then or taken from the cache)."""
    built = []
    build = _engine.get_step_kernel

    def recording(config):
        built.append(config)
        return build(config)

    with _set(_engine, get_step_kernel=recording):
        yield built

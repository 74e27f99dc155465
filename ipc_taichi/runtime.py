"""The one place that initialises Taichi.

Taichi has a single runtime per process. :func:`init` owns it: it is
idempotent, it is called lazily by every public function that runs a
kernel, and it is never called at import time.

The arch is chosen, in order, by the ``arch`` argument, the environment
variable ``IPC_TAICHI_ARCH`` (``auto``, ``cpu`` or ``cuda``) and the default
``auto``. The precision likewise by ``precision``, ``IPC_TAICHI_PRECISION``
(``f64`` or ``f32``) and the default ``f64``.

A precision sticks until changed: once a runtime runs, ``precision=None``
keeps its precision (the environment and the default only choose the first
runtime's). So after ``init(precision="f32")`` every later
``decouple()``/``couple()`` without ``precision=`` runs in f32, without a
recompile; ``precision="f64"`` (or ``init(precision="f64")``) switches back.
The arch is kept as before: ``auto`` (the default) keeps the running one.

``IPC_TAICHI_THREADS`` (a positive integer), when set, caps the threads of
Taichi's CPU thread pool (``ti.init(cpu_max_num_threads=...)``): the Dask
workers of :func:`ipc_taichi.cluster.local_client` get ``cores // workers``
each, so that they add up to the cores instead of each using all of them.

- ``cuda`` requested explicitly and not available raises
  :class:`~ipc_taichi.errors.ArchUnavailableError`.
- ``auto`` tries CUDA and falls back to the CPU with a logged notice.

Asking for a different arch or precision than the running one resets the
runtime (kernels are recompiled on next use).

Taichi's offline cache is on: compiled kernels are kept in the user's cache
directory (Taichi's default, ``$XDG_CACHE_HOME/taichi/ticache``, else
``~/.cache/taichi/ticache``; ``$TI_OFFLINE_CACHE_FILE_PATH`` moves it), never in
the working directory, so a fresh process skips the LLVM compile of every kernel
an earlier one built (Taichi still parses the kernels' Python). ``$TI_OFFLINE_CACHE=0``
turns it off. Taichi guards the cache's index with a lock file (``ticache.lock``, created
exclusively, removed when done); a process killed while it held the lock leaves it
behind, and every later process then neither loads nor saves a kernel (each run
recompiles everything: seconds). :func:`init` removes a lock older than
:data:`STALE_LOCK_S` (held for milliseconds by a live process) before it starts Taichi,
and makes Taichi's parse of this package's kernels skip the error-message art it
formats for every node (:func:`light_source_positions`).

No network at run time: ``ti.init`` would start a thread that posts Taichi's
version to its makers each day until one answers; :func:`init` sets
``$TI_SKIP_VERSION_CHECK=ON`` (a value the user set is kept).
"""

import contextlib
import io
import logging
import os
import time
from dataclasses import dataclass

import numpy as np

from .errors import ArchUnavailableError
from .gpus import cuda_present

__all__ = ["RuntimeInfo", "init", "current", "cpu_threads", "positive_env", "ARCH_ENV",
           "PRECISION_ENV", "THREADS_ENV", "CACHE_ENV", "CACHE_PATH_ENV", "CACHE_LOCK",
           "STALE_LOCK_S", "clear_stale_cache_lock", "light_source_positions", "finish",
           "VERSION_CHECK_ENV"]

ARCH_ENV = "IPC_TAICHI_ARCH"
PRECISION_ENV = "IPC_TAICHI_PRECISION"
THREADS_ENV = "IPC_TAICHI_THREADS"
CACHE_ENV = "TI_OFFLINE_CACHE"  # Taichi's own switch of its offline cache
CACHE_PATH_ENV = "TI_OFFLINE_CACHE_FILE_PATH"  # Taichi's own: where the cache lives
CACHE_LOCK = "ticache.lock"  # Taichi's lock of the cache's index, in that directory
#: Taichi's own switch of the version check that ``ti.init`` starts (a thread that
#: posts to metadata.taichi.graphics each day it has no answer): ``ON`` skips it
VERSION_CHECK_ENV = "TI_SKIP_VERSION_CHECK"
#: seconds after which Taichi's cache lock is taken for one a killed process left
STALE_LOCK_S = 120.0
_ARCHES = ("auto", "cpu", "cuda")
_PRECISIONS = ("f64", "f32")

log = logging.getLogger("ipc_taichi")
_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


@dataclass(frozen=True)
class RuntimeInfo:
    """What the running Taichi runtime actually is.

    Attributes
    ----------
    arch : str
        ``"cpu"`` or ``"cuda"``: the arch kernels run on.
    precision : str
        ``"f64"`` or ``"f32"``: the floating type of every array and kernel.
    requested : str
        The arch that was asked for (``auto``, ``cpu`` or ``cuda``).
    threads : int or None
        The cap on Taichi's CPU threads (``$IPC_TAICHI_THREADS``), ``None``
        for Taichi's default (every core).
    """

    arch: str
    precision: str
    requested: str
    threads: int = None

    @property
    def dtype(self):
        """NumPy dtype matching ``precision``."""
        return np.float64 if self.precision == "f64" else np.float32


_current = None
_reset_hooks = []


def _resolve(value, env, allowed, default, what):
    value = value if value is not None else os.environ.get(env) or default
    value = str(value).strip().lower()
    if value not in allowed:
        raise ValueError(
            f"unknown {what} {value!r} (from {'argument' if value else env}); "
            f"choose one of {', '.join(allowed)}"
        )
    return value


def cpu_threads():
    """The cap on Taichi's CPU threads from ``$IPC_TAICHI_THREADS``, or ``None``
    when it is unset or empty (Taichi then uses every core)."""
    return positive_env(THREADS_ENV)


def positive_env(name):
    """The positive integer in environment variable ``name``, or ``None`` when
    it is unset or empty; anything else is refused in one line (a ValueError)."""
    text = os.environ.get(name, "").strip()
    if not text:
        return None
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"{name}={text!r}: expected a positive integer")
    return value


def clear_stale_cache_lock(cache_dir, now=None):
    """Remove Taichi's offline-cache lock in ``cache_dir`` when it is older than
    :data:`STALE_LOCK_S` seconds (a process killed while holding it left it:
    Taichi would neither load nor save a kernel while it is there). Returns
    whether a lock was removed; a young lock, or none, is left alone."""
    lock = os.path.join(cache_dir, CACHE_LOCK)
    try:
        age = (time.time() if now is None else now) - os.stat(lock).st_mtime
        if age <= STALE_LOCK_S:
            return False
        os.remove(lock)
    except OSError:  # none, or another process removed it first
        return False
    log.info("removed a stale Taichi cache lock (%.0f s old): %s", age, lock)
    return True


def light_source_positions():
    """Make Taichi's parse of this package's kernels skip its error-message art.

    Taichi 1.7 re-parses a kernel's Python in every process (the offline cache
    key is computed from what the parse builds) and, for every node of it,
    formats the message it would print were that node to fail: the source
    lines wrapped to 80 columns under a line of carets. For the step kernel that
    is a third of the parse (0.1-0.2 s of each process's start on a 2-core
    machine). For kernels whose source lies in this package the position is
    ``File, line, function`` and the source line, without the carets; the
    kernel Taichi builds, its offline-cache key and its results are the same.
    Every other kernel (a user's own, in the same process) keeps Taichi's
    message; a Taichi whose parser differs is left alone. Idempotent; called
    by :func:`init`.
    """
    import taichi as ti

    try:
        from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext as context
    except ImportError:
        return
    full = getattr(context, "get_pos_info", None)
    if full is None or hasattr(full, "taichi_get_pos_info") or tuple(ti.__version__[:2]) != (1, 7):
        return

    ours = {}  # source file -> in this package

    def get_pos_info(self, node):
        if self.file not in ours:
            ours[self.file] = os.path.abspath(str(self.file)).startswith(_PACKAGE_DIR)
        if not ours[self.file]:
            return full(self, node)
        return (f'File "{self.file}", line {node.lineno + self.lineno_offset}, in '
                f"{self.func.func.__name__}:\n{self.src[node.lineno - 1]}\n")

    get_pos_info.taichi_get_pos_info = full
    context.get_pos_info = get_pos_info


def on_reset(hook):
    """Register ``hook()`` to run whenever the runtime is (re)initialised.

    Kernel factories use it to drop kernels built for the previous runtime.
    """
    _reset_hooks.append(hook)
    return hook


def current():
    """The :class:`RuntimeInfo` of the running runtime, or ``None``."""
    return _current


def init(arch=None, precision=None):
    """Initialise Taichi once (idempotent) and report what is running.

    Parameters
    ----------
    arch : {"auto", "cpu", "cuda"}, optional
        Default: ``$IPC_TAICHI_ARCH`` or ``"auto"`` (which keeps the running arch).
    precision : {"f64", "f32"}, optional
        Default: the running runtime's, else ``$IPC_TAICHI_PRECISION`` or ``"f64"``.

    Returns
    -------
    RuntimeInfo
    """
    global _current
    if _current is not None and precision is None:  # a precision sticks until changed
        precision = _current.precision
    requested = _resolve(arch, ARCH_ENV, _ARCHES, "auto", "arch")
    precision = _resolve(precision, PRECISION_ENV, _PRECISIONS, "f64", "precision")

    if _current is not None and _current.precision == precision and (
        requested == _current.requested
        or requested == _current.arch
        or requested == "auto"
    ):
        return _current

    # Taichi prints a banner to stdout on import and logs its CUDA probe at
    # warning level; our own notice below says what matters. Hence the import
    # here, after the environment that quiets it is set (and importing
    # ipc_taichi stays free of Taichi's start-up cost).
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")
    os.environ.setdefault("TI_LOG_LEVEL", "error")
    os.environ.setdefault(VERSION_CHECK_ENV, "ON")  # no network at run time
    import taichi as ti

    light_source_positions()
    if _current is not None:
        ti.reset()
    for hook in _reset_hooks:
        hook()

    fp = ti.f64 if precision == "f64" else ti.f32
    # fast_math off: it may reorder the stopping rule's max-reductions and drop
    # IEEE guarantees we rely on for f64 agreement with the NumPy reference.
    common = dict(default_fp=fp, fast_math=False, log_level=ti.ERROR)
    on_cpu = requested == "cpu" or (requested == "auto" and not cuda_present())
    if on_cpu:
        # Taichi vectors as LLVM vectors: the CPU's ``lanes`` step is SIMD
        # code only so (see ipc_taichi._lanes); on CUDA Taichi's default
        common["real_matrix_scalarize"] = False
    threads = cpu_threads()
    if threads is not None:
        common["cpu_max_num_threads"] = threads
    if CACHE_ENV not in os.environ:  # said, not left to Taichi's default; the user may say 0
        common["offline_cache"] = True
    clear_stale_cache_lock(os.environ.get(CACHE_PATH_ENV)
                           or ti.lang.impl.default_cfg().offline_cache_file_path)
    # ti.init prints "Starting on arch=..." unconditionally; keep stdout clean
    # for command-line output (the arch is reported by RuntimeInfo instead)
    with contextlib.redirect_stdout(io.StringIO()):
        # (``auto`` without CUDA asks for the CPU: Taichi would probe CUDA again)
        ti.init(arch=ti.cpu if on_cpu else ti.cuda, **common)
    got = ti.lang.impl.current_cfg().arch
    arch_name = "cuda" if got == ti.cuda else "cpu"
    if arch_name != "cuda" and requested == "cuda":
        _current = None
        ti.reset()
        raise ArchUnavailableError(
            "CUDA was requested (arch='cuda') but no CUDA device is available; "
            "use arch='cpu' or 'auto'"
        )
    if arch_name != "cuda" and requested == "auto":
        log.warning("notice: CUDA not available, ipc_taichi runs on the CPU")
    _current = RuntimeInfo(arch=arch_name, precision=precision, requested=requested,
                           threads=threads)
    return _current


def finish():
    """End the running runtime, if any: its kernels and arrays are dropped
    (the reset hooks run) and Taichi's program is destroyed, which writes the
    offline cache's index with the kernels this process compiled. The next
    :func:`init` (or any call that runs a kernel) starts a new runtime. The
    command line calls it at exit (:mod:`ipc_taichi.cli`)."""
    global _current
    if _current is None:
        return
    import taichi as ti

    _current = None
    for hook in _reset_hooks:
        hook()
    ti.reset()

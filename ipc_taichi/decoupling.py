"""The decoupler: the paper's non-linear iterative (Jacobi) inversion (Eqs. 5-7).

``S_0 = M``;  ``S_q = M - flow(S_{q-1})``, where ``flow`` is the coupling term of
the forward model evaluated with alpha on the current estimate. Every pixel of
``S_q`` depends only on ``S_{q-1}`` (Jacobi, not Gauss-Seidel: no in-place race).

The stopping and divergence rules are those of :mod:`ipc_taichi.iteration`
(the paper's: at most 20 iterations, stop when ``max|S_q - S_{q-1}| <= 1e-5
max|S_q|``). On the paper's worked example this stops after 4 iterations.
Information moves one pixel per iteration and per unit of geometry reach,
which is what makes halo tiling exact.
"""

from dataclasses import dataclass, field

from . import iteration
from ._engine import as_result, as_stack, run_decouple, start
from .model import CouplingModel

__all__ = ["decouple", "DecoupleInfo", "WarmCarry"]


class WarmCarry:
    """The warm start carried from one call of :func:`decouple` to the next,
    for the frames of a ramp decoupled one call each (each group read,
    decoupled and written before the next is read): pass the same carrier as
    ``warm_start=`` to every call, group after group; each call starts from
    the answers of the calls before it as a stack's frame would
    (:class:`ipc_taichi._warm.WarmStart`), and keeps its own for the next.
    :meth:`reset` before a frame that does not follow (a new integration):
    it then starts from scratch. The first call, or one after a change of
    frame shape, model layout or runtime, starts from scratch too."""

    def __init__(self):
        self.state = None  # the engine's WarmStart of the last call

    def reset(self):
        """The next call starts from scratch."""
        self.state = None


@dataclass
class DecoupleInfo:
    """How the iteration went for one frame.

    Attributes
    ----------
    iterations : int
        Number of Jacobi iterations performed.
    converged : bool
        Whether the stopping rule was met (``False`` when ``tol == 0``).
    max_delta : list of float
        ``max|S_q - S_{q-1}|`` for q = 1 .. iterations.
    max_signal : list of float
        ``max|S_q|`` for q = 1 .. iterations.
    arch, precision, law, geometry, edge : str
        What was run.
    warm_start : bool
        Whether the iteration started from the previous frame's answer plus
        the new charge (``warm_start=True``, from the second frame of a stack
        on) rather than from ``S_0 = M``.
    """

    iterations: int = 0
    converged: bool = False
    max_delta: list = field(default_factory=list)
    max_signal: list = field(default_factory=list)
    arch: str = ""
    precision: str = ""
    law: str = ""
    geometry: str = ""
    edge: str = ""
    warm_start: bool = False


def decouple(measured, law=None, geometry=None, edge=None, max_iter=iteration.MAX_ITER,
             tol=iteration.TOL, arch=None, precision=None, callback=None, full_output=False,
             layout=None, *, model=None, mask=None, out=None, warm_start=False):
    """Remove signal-dependent IPC from ``measured`` (2-D frame or 3-D stack).

    Parameters
    ----------
    measured : array_like, shape (ny, nx) or (n, ny, nx)
        The read-out frame(s), ``measured[y, x]``, in electrons. NaN/inf are
        bad pixels: they stay NaN and do not couple. A 3-D stack (e.g. ramp
        groups) is decoupled frame by frame in the same working buffers. A
        PyTorch tensor (CPU or CUDA), or a CuPy/JAX array (through DLPack and
        PyTorch), is decoupled on its device and the result returned as the
        same kind on the same device: see :mod:`ipc_taichi._device`.
    law, geometry, edge : optional
        The coupling model, as for :func:`ipc_taichi.couple` (``None``: the
        paper's law, nearest neighbours, edge ``zero``).
    max_iter : int
        At most this many iterations (default :data:`ipc_taichi.iteration.MAX_ITER`,
        the paper's 20).
    tol : float
        Stopping rule ``max|S_q - S_{q-1}| <= tol * max|S_q|`` (default
        :data:`ipc_taichi.iteration.TOL`, the paper's 1e-5); 0 runs exactly
        ``max_iter`` iterations without a warning.
    callback : callable, optional
        ``callback(q, estimate)`` after each iteration (frame by frame);
        ``estimate`` is a NumPy frame that must not be modified (it is the
        working array on the CPU; on CUDA each call copies it to the host).
    full_output : bool
        Also return a :class:`DecoupleInfo` (a list of them for a 3-D stack).
    layout : {None, "lanes", "sweep", "pixel"}
        Kernel loop layout (see :mod:`ipc_taichi._kernels`); ``None`` picks the
        one that suits the arch (``lanes`` on the CPU, ``pixel`` on CUDA). Results
        agree to rounding (``lanes`` and ``sweep`` bit for bit).
    model : CouplingModel, str or path-like, optional
        The law, geometry and edge as one value, or the path of a model file
        (:meth:`ipc_taichi.model.CouplingModel.load`); then ``law``,
        ``geometry`` and ``edge`` must be left ``None`` (else
        :class:`~ipc_taichi.errors.IPCInputError`).
    mask : array_like of bool, optional
        True where a pixel is not trusted (e.g. DQ DO_NOT_USE), shaped like a
        frame or like the stack: it neither gives nor takes charge and keeps
        its measured value. A NumPy masked array's own mask is used the same way.
        For a device array the mask may be a NumPy array or a boolean array of
        its kind.
    out : array, optional
        Where to write the result: the input's kind, its shape, the runtime
        precision, contiguous (e.g. a page-locked buffer from
        :func:`ipc_taichi._device.pinned_empty` reused frame after frame). A
        NumPy ``out`` may also be any writeable floating-point array of the
        shape (another precision or byte order, strided: a window of a
        memory-mapped file), the result rounded into it as it is stored (on
        the CPU in the same pass; on CUDA by one more copy at the end).
    warm_start : bool or WarmCarry
        For a 3-D stack whose frames follow each other, such as the groups of
        a ramp: start frame ``k`` from the previous frame's answer plus the new
        charge, ``S_0 = M_k + (S_(k-1) - M_(k-1))``, instead of ``S_0 = M_k``
        (see :class:`ipc_taichi._warm.WarmStart`). Same stopping rule, which
        judges only the last update: the answer meets the same tolerance as
        from scratch, in fewer iterations up a ramp (typically 1-2 instead of
        4-5), but is not bit-identical to it, and frame ``k``'s answer then
        depends on frame ``k - 1``. Unrelated frames are still decoupled
        correctly (their start is no better than ``M_k``, and the rule still
        decides when to stop). Default ``False``: each frame from scratch,
        independent of the others. A :class:`WarmCarry`: the same for frames
        given one call each (the carrier holds the state between calls).

    Returns
    -------
    signal : ndarray or the input's array kind
        The decoupled frame(s) in the runtime precision, on the input's device;
        a masked array for a masked input.
    info : DecoupleInfo or list of DecoupleInfo
        Only with ``full_output=True``.

    Raises
    ------
    DivergenceError
        The iteration blows up (non-finite, or the update grows 3 times running).

    Warns
    -----
    ConvergenceWarning
        ``max_iter`` was reached before the stopping rule (``tol > 0``).
    """
    frames = as_stack(measured, "measured", mask)
    max_iter, tol = iteration.check_arguments(max_iter, tol)
    model = CouplingModel.resolve(law, geometry, edge, model=model)
    info = start(arch, precision)
    infos = []

    def iterate(k, step, ws, warm):
        record = DecoupleInfo(arch=info.arch, precision=info.precision,
                              law=model.law.describe(), geometry=model.geometry.describe(),
                              edge=model.edge, warm_start=warm)
        answer = _iterate(step, ws, max_iter, tol, callback, record)
        infos.append(record)
        iteration.warn_unconverged(record, max_iter, tol,
                                   where="" if frames.was_2d else f"frame {k}: ", stacklevel=5)
        return answer

    result = run_decouple(frames, model, info, layout, iterate, out=out,
                          warm_start=warm_start if isinstance(warm_start, WarmCarry)
                          else bool(warm_start))
    signal = as_result(result, frames, out)
    if full_output:
        return signal, (infos[0] if frames.was_2d else infos)
    return signal


def _iterate(step, ws, max_iter, tol, callback, record):
    """Jacobi iterations (see :func:`_iterate_here`; on the device path
    without a callback, :func:`_iterate_ahead`)."""
    if callback is None and hasattr(step, "launch"):
        return _iterate_ahead(step, ws, max_iter, tol, record)
    return _iterate_here(step, ws, max_iter, tol, callback, record)


def _iterate_ahead(step, ws, max_iter, tol, record):
    """The iterations of :func:`_iterate_here`, with the same results, decided
    by the same rules in the same order, but launched one step ahead of the
    host's decision: step ``q + 1`` is launched before the maxima of step
    ``q`` are back (``step.launch``, ``step.result``), so the device never
    waits for the host. Step ``q + 1`` writes the buffer of ``S_(q-1)``, so
    ``S_q`` is intact when the rule stops at ``q``; the step launched ahead is
    then wasted work, which is why no step is launched ahead of an iteration
    whose update, extrapolated geometrically from the last two, is expected
    to meet the rule (:func:`_launch_ahead`): a wrong guess costs one wait,
    never a different answer."""
    buffer = ws.holding  # the array holding S_q
    pending = {1: step.launch(buffer(0), buffer(1))}
    q = 0
    for q in range(1, max_iter + 1):
        if q < max_iter and _launch_ahead(record, tol):
            pending[q + 1] = step.launch(buffer(q), buffer(q + 1))
        dmax, smax = step.result(pending.pop(q))
        record.iterations = q
        record.max_delta.append(dmax)
        record.max_signal.append(smax)
        iteration.check_divergence(record.max_delta, record.max_signal)
        if iteration.met(dmax, smax, tol):
            record.converged = True
            break
        if q < max_iter and q + 1 not in pending:
            pending[q + 1] = step.launch(buffer(q), buffer(q + 1))
    return buffer(q)


def _launch_ahead(record, tol):
    """Whether to launch the next step before the maxima of the one in flight
    are back: unless the update of the step in flight, extrapolated from the
    last two (``d_q ~ d_(q-1)^2 / d_(q-2)``), meets the rule."""
    d, s = record.max_delta, record.max_signal
    if tol <= 0 or len(d) < 2 or not d[-2] > 0:
        return True
    return not iteration.met(d[-1] * d[-1] / d[-2], s[-1], tol)


def _iterate_here(step, ws, max_iter, tol, callback, record):
    """Jacobi iterations from ``S_0``, where the engine loaded it (``M``, or
    the warm start); step ``q`` reads ``ws.holding(q - 1)`` and writes
    ``ws.holding(q)`` (the workspace's swap of its two working arrays);
    returns the padded array holding the answer."""
    q = 0
    for q in range(1, max_iter + 1):
        dmax, smax = step(ws.holding(q - 1), ws.holding(q))
        record.iterations = q
        record.max_delta.append(dmax)
        record.max_signal.append(smax)
        iteration.check_divergence(record.max_delta, record.max_signal)
        if callback is not None:
            callback(q, ws.estimate(ws.holding(q)))
        if iteration.met(dmax, smax, tol):
            record.converged = True
            break
    return ws.holding(q)

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

import numpy as np

from . import iteration
from ._engine import Stepper, as_result, as_stack, interior, prepare_frame, restore_bad, start
from .model import CouplingModel

__all__ = ["decouple", "DecoupleInfo"]


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


def decouple(measured, law="donlon2018", geometry=None, edge="zero", max_iter=iteration.MAX_ITER,
             tol=iteration.TOL, arch=None, precision=None, callback=None, full_output=False,
             layout=None, *, model=None, mask=None):
    """Remove signal-dependent IPC from ``measured`` (2-D frame or 3-D stack).

    Parameters
    ----------
    measured : array_like, shape (ny, nx) or (n, ny, nx)
        The read-out frame(s), ``measured[y, x]``. NaN/inf are bad pixels:
        they stay NaN and do not couple. A 3-D stack (e.g. ramp groups) is
        decoupled frame by frame.
    law, geometry, edge :
        The coupling model, as for :func:`ipc_taichi.couple`.
    max_iter : int
        At most this many iterations (paper: 20).
    tol : float
        Stopping rule ``max|S_q - S_{q-1}| <= tol * max|S_q|``; 0 runs exactly
        ``max_iter`` iterations without a warning.
    callback : callable, optional
        ``callback(q, estimate)`` after each iteration (frame by frame);
        ``estimate`` must not be modified (it is the working array on the CPU).
    full_output : bool
        Also return a :class:`DecoupleInfo` (a list of them for a 3-D stack).
    layout : {None, "sweep", "pixel"}
        Kernel loop layout (see :mod:`ipc_taichi._kernels`); ``None`` picks the
        one that suits the arch. Results agree to rounding.
    model : CouplingModel, optional
        The law, geometry and edge as one resolved value (then leave ``law``,
        ``geometry`` and ``edge`` at their defaults).
    mask : array_like of bool, optional
        True where a pixel is not trusted (e.g. DQ DO_NOT_USE), shaped like a
        frame or like the stack: it neither gives nor takes charge and keeps
        its measured value. A NumPy masked array's own mask is used the same way.

    Returns
    -------
    signal : ndarray
        The decoupled frame(s) in the runtime precision; a masked array for a
        masked input.
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
    stack, bad, was_2d = as_stack(measured, "measured", mask)
    max_iter, tol = iteration.check_arguments(max_iter, tol)
    model = CouplingModel.from_arguments(law, geometry, edge, model)
    info = start(arch, precision)
    out = np.empty(stack.shape, dtype=info.dtype)
    infos = []
    steppers = {}
    for k, frame in enumerate(stack):
        work, valid = prepare_frame(frame, info.dtype, model.reach,
                                    None if bad is None else bad[k])
        masked = valid is not None
        if masked not in steppers:
            steppers[masked] = Stepper(model, masked, info, layout=layout)
        frame_info = DecoupleInfo(arch=info.arch, precision=info.precision,
                                  law=model.law.describe(), geometry=model.geometry.describe(),
                                  edge=model.edge)
        out[k] = _iterate(steppers[masked], work, valid, max_iter, tol, callback, frame_info)
        del work
        restore_bad(out[k], frame, valid)
        infos.append(frame_info)
        iteration.warn_unconverged(frame_info, max_iter, tol,
                                   where="" if was_2d else f"frame {k}: ")
    signal = as_result(out, was_2d, measured)
    if full_output:
        return signal, (infos[0] if was_2d else infos)
    return signal


def _iterate(step, work, valid, max_iter, tol, callback, record):
    """Jacobi iterations on the padded frame ``work``; returns the estimate
    (a view of the frame inside the padded working array)."""
    r = step.reach
    ok = step.ok_array(work.shape, valid)
    base = step.to_runtime(work)
    # S_0 = M; the border of both working arrays stays zero (never written)
    prev = step.to_runtime(work) if step.on_device else work.copy()
    nxt = step.zeros(work.shape)
    for q in range(1, max_iter + 1):
        dmax, smax = step(prev, base, nxt, ok, -1.0)
        record.iterations = q
        record.max_delta.append(dmax)
        record.max_signal.append(smax)
        iteration.check_divergence(record.max_delta, record.max_signal)
        prev, nxt = nxt, prev
        if callback is not None:
            callback(q, interior(step.to_numpy(prev), r))
        if iteration.met(dmax, smax, tol):
            record.converged = True
            break
    return interior(step.to_numpy(prev), r)

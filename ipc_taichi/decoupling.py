"""The decoupler: the paper's non-linear iterative (Jacobi) inversion (Eqs. 5-7).

``S_0 = M``;  ``S_q = M - flow(S_{q-1})``, where ``flow`` is the coupling term of
the forward model evaluated with alpha on the current estimate. Every pixel of
``S_q`` depends only on ``S_{q-1}`` (Jacobi, not Gauss-Seidel: no in-place race).

Stopping rule (paper section 2.4): stop after ``max_iter`` (20) iterations or
as soon as ``max|S_q - S_{q-1}| <= tol * max|S_q|`` (``tol = 1e-5``, i.e.
0.001 %). On the paper's worked example this stops after 4 iterations.
Information moves one pixel per iteration and per unit of geometry reach,
which is what makes halo tiling exact.
"""

import warnings
from dataclasses import dataclass, field

import numpy as np

from ._engine import Stepper, as_stack, interior, prepare_frame, resolve_model, start
from .errors import ConvergenceWarning, DivergenceError, IPCInputError

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


def decouple(measured, law="donlon2018", geometry=None, edge="zero", max_iter=20, tol=1e-5,
             arch=None, precision=None, callback=None, full_output=False, layout=None):
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

    Returns
    -------
    signal : ndarray
        The decoupled frame(s) in the runtime precision.
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
    stack, was_2d = as_stack(measured, "measured")
    max_iter = int(max_iter)
    if max_iter < 1:
        raise IPCInputError(f"max_iter must be >= 1, got {max_iter}")
    if not (np.isfinite(tol) and tol >= 0):
        raise IPCInputError(f"tol must be finite and >= 0, got {tol}")
    law, geometry, edge = resolve_model(law, geometry, edge)
    info = start(arch, precision)
    out = np.empty(stack.shape, dtype=info.dtype)
    infos = []
    steppers = {}
    for k, frame in enumerate(stack):
        work, valid = prepare_frame(frame, info.dtype, geometry.reach)
        masked = valid is not None
        if masked not in steppers:
            steppers[masked] = Stepper(law, geometry, edge, masked, info, layout=layout)
        frame_info = DecoupleInfo(arch=info.arch, precision=info.precision, law=law.describe(),
                                  geometry=geometry.describe(), edge=edge)
        out[k] = _iterate(steppers[masked], work, valid, max_iter, tol, callback, frame_info)
        del work
        if masked:
            out[k][~valid] = np.nan
        infos.append(frame_info)
        if tol > 0 and not frame_info.converged:
            where = f"frame {k}: " if not was_2d else ""
            warnings.warn(
                f"{where}decouple did not meet the stopping rule in {max_iter} iterations "
                f"(last max|dS| = {frame_info.max_delta[-1]:.3g}, "
                f"tol*max|S| = {tol * frame_info.max_signal[-1]:.3g})",
                ConvergenceWarning, stacklevel=2)
    signal = out[0] if was_2d else out
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
    rising = 0
    for q in range(1, max_iter + 1):
        dmax, smax = step(prev, base, nxt, ok, -1.0)
        record.iterations = q
        record.max_delta.append(dmax)
        record.max_signal.append(smax)
        if not (np.isfinite(dmax) and np.isfinite(smax)):
            raise DivergenceError(f"decouple diverged at iteration {q}: non-finite values; "
                                  "the law/geometry is too strong for this data")
        if q > 1 and dmax > record.max_delta[-2]:
            rising += 1
            if rising >= 3:
                raise DivergenceError(
                    f"decouple diverged: max|dS| grew 3 iterations running "
                    f"({', '.join(f'{d:.3g}' for d in record.max_delta[-4:])})")
        else:
            rising = 0
        prev, nxt = nxt, prev
        if callback is not None:
            callback(q, interior(step.to_numpy(prev), r))
        if tol > 0 and dmax <= tol * smax:
            record.converged = True
            break
    return interior(step.to_numpy(prev), r)

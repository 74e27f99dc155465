"""The rules of the Jacobi iteration, written once: when to stop, when it
has diverged, and what to say about it.

Stopping rule (the paper's section 2.4): stop after ``max_iter`` iterations
(20) or at the first ``q`` with ``max|S_q - S_{q-1}| <= tol * max|S_q|``
(``tol = 1e-5``, i.e. 0.001 %), the maxima taken over the good pixels of
the whole frame. ``tol = 0`` runs exactly ``max_iter`` iterations.

Divergence rule: the iteration has diverged when a maximum is not finite,
or when ``max|S_q - S_{q-1}|`` has grown :data:`RISING_LIMIT` iterations
running (a contracting iteration's update shrinks geometrically).

The whole-frame decoupler applies these rules as it goes; tiling applies them
to the per-iteration maxima gathered over all tiles; the NumPy twin in
:mod:`ipc_taichi.reference` writes them out again on purpose, as an
independent check.
"""

import math
import warnings

from .errors import ConvergenceWarning, DivergenceError, IPCInputError

__all__ = ["MAX_ITER", "TOL", "RISING_LIMIT", "check_arguments", "met", "first_met",
           "check_divergence", "warn_unconverged"]

MAX_ITER = 20
"""The paper's cap on iterations."""

TOL = 1e-5
"""The paper's relative stopping tolerance (0.001 %)."""

RISING_LIMIT = 3
"""Iterations running in which a growing update means divergence."""


def check_arguments(max_iter, tol):
    """Validated ``(max_iter, tol)``; :class:`IPCInputError` otherwise."""
    max_iter = int(max_iter)
    if max_iter < 1:
        raise IPCInputError(f"max_iter must be >= 1, got {max_iter}")
    tol = float(tol)
    if not (math.isfinite(tol) and tol >= 0):
        raise IPCInputError(f"tol must be finite and >= 0, got {tol}")
    return max_iter, tol


def met(max_delta, max_signal, tol):
    """Whether one iteration with these maxima meets the stopping rule."""
    return tol > 0 and max_delta <= tol * max_signal


def first_met(max_delta, max_signal, tol):
    """The first iteration ``q`` (1-based) meeting the rule, or ``None``."""
    for q, (d, s) in enumerate(zip(max_delta, max_signal), start=1):
        if met(d, s, tol):
            return q
    return None


def check_divergence(max_delta, max_signal):
    """Raise :class:`DivergenceError` if the history of maxima (iterations
    ``1 .. q``) shows divergence at its last iteration ``q``.

    Called after every iteration, this is the incremental rule; tiling calls
    it on each prefix of the gathered history.
    """
    q = len(max_delta)
    if q == 0:
        return
    if not (math.isfinite(max_delta[-1]) and math.isfinite(max_signal[-1])):
        raise DivergenceError(f"decouple diverged at iteration {q}: non-finite values; "
                              "the law/geometry is too strong for this data")
    last = max_delta[-RISING_LIMIT - 1:]
    if len(last) == RISING_LIMIT + 1 and all(b > a for a, b in zip(last, last[1:])):
        raise DivergenceError(
            f"decouple diverged: max|dS| grew {RISING_LIMIT} iterations running "
            f"({', '.join(f'{d:.3g}' for d in last)})")


def warn_unconverged(info, max_iter, tol, where="", stacklevel=3):
    """Warn (:class:`ConvergenceWarning`) when a run with ``tol > 0`` stopped at
    ``max_iter`` without meeting the rule; ``info`` is a :class:`DecoupleInfo`."""
    if tol > 0 and not info.converged:
        warnings.warn(
            f"{where}decouple did not meet the stopping rule in {max_iter} iterations "
            f"(last max|dS| = {info.max_delta[-1]:.3g}, "
            f"tol*max|S| = {tol * info.max_signal[-1]:.3g})",
            ConvergenceWarning, stacklevel=stacklevel)

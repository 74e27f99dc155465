"""Exceptions and warnings raised by ipc_taichi.

Every error subclasses a builtin so callers can catch what they expect
(``ValueError`` for bad input, ``RuntimeError`` for a failed computation).
"""

__all__ = [
    "IPCInputError",
    "LawError",
    "GeometryError",
    "ArchUnavailableError",
    "DivergenceError",
    "ConvergenceWarning",
]


class IPCInputError(ValueError):
    """The data handed in cannot be processed (shape, dtype, file, HDU)."""


class LawError(ValueError):
    """A coupling law is malformed or too strong for the iteration to converge."""


class GeometryError(ValueError):
    """A coupling geometry (offsets and weights) is malformed."""


class ArchUnavailableError(RuntimeError):
    """An explicitly requested Taichi arch (e.g. CUDA) is not available."""


class DivergenceError(RuntimeError):
    """The Jacobi iteration of the decoupler diverged."""


class ConvergenceWarning(UserWarning):
    """The decoupler stopped at ``max_iter`` before meeting the stopping rule."""

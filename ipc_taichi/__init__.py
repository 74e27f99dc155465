"""ipc_taichi: signal-dependent interpixel capacitance for hybrid IR detectors.

Simulate IPC with a coupling coefficient alpha(S, N) that depends on the
signal of both pixels (:func:`couple`), and remove it with the non-linear
iterative decoupler of Donlon, Ninkov & Baum (JATIS 2018) (:func:`decouple`),
on the CPU or a CUDA GPU through Taichi kernels.

Pixel convention: ``image[y, x]``, 0-based, integer coordinates at pixel
centres. Taichi is initialised lazily on first use (see :mod:`ipc_taichi.runtime`).

The names below are loaded on first use (``ipc_taichi.couple`` imports
:mod:`ipc_taichi.coupling` then), and so is any submodule named as an
attribute (``ipc_taichi.runtime``): ``import ipc_taichi`` costs almost
nothing, so that ``ipc-taichi --help`` answers at once.
"""

import importlib
import importlib.util

from .errors import (
    ArchUnavailableError,
    ConvergenceWarning,
    DivergenceError,
    GeometryError,
    IPCInputError,
    LawError,
)

__version__ = "0.1.0"

# public name -> the submodule that defines it (imported on first use)
_LAZY = {
    "couple": "coupling", "decouple": "decoupling", "DecoupleInfo": "decoupling",
    "Geometry": "geometry", "ParametricLaw": "laws", "TabulatedLaw": "laws",
    "constant": "laws", "donlon2018": "laws", "donlon2018_printed": "laws",
    "get_law": "laws", "init": "runtime",
}

__all__ = [
    "couple", "decouple", "DecoupleInfo", "Geometry", "ParametricLaw", "TabulatedLaw",
    "constant", "donlon2018", "donlon2018_printed", "get_law", "init",
    "IPCInputError", "LawError", "GeometryError", "ArchUnavailableError",
    "DivergenceError", "ConvergenceWarning", "__version__",
]


def __getattr__(name):
    """A public name of :data:`__all__`, or a submodule, imported on first use."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value  # later lookups skip this function
        return value
    if not name.startswith("__") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))

"""ipc_taichi: signal-dependent interpixel capacitance for hybrid IR detectors.

Simulate IPC with a coupling coefficient alpha(S, N) that depends on the
signal of both pixels (:func:`couple`), and remove it with the non-linear
iterative decoupler of Donlon, Ninkov & Baum (JATIS 2018) (:func:`decouple`),
on the CPU or a CUDA GPU through Taichi kernels.

Pixel convention: ``image[y, x]``, 0-based, integer coordinates at pixel
centres. Taichi is initialised lazily on first use (see :mod:`ipc_taichi.runtime`).
"""

from .coupling import couple
from .decoupling import DecoupleInfo, decouple
from .errors import (
    ArchUnavailableError,
    ConvergenceWarning,
    DivergenceError,
    GeometryError,
    IPCInputError,
    LawError,
)
from .geometry import Geometry
from .laws import ParametricLaw, TabulatedLaw, constant, donlon2018, donlon2018_printed, get_law
from .runtime import init

__version__ = "0.1.0"

__all__ = [
    "couple", "decouple", "DecoupleInfo", "Geometry", "ParametricLaw", "TabulatedLaw",
    "constant", "donlon2018", "donlon2018_printed", "get_law", "init",
    "IPCInputError", "LawError", "GeometryError", "ArchUnavailableError",
    "DivergenceError", "ConvergenceWarning", "__version__",
]

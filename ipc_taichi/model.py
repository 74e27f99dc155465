"""The coupling model: one value for the law, the geometry and the edge rule.

A :class:`CouplingModel` is resolved and validated once (law parsed, geometry
built, edge checked, the Jacobi contraction condition tested) and then handed
unchanged to every layer: the forward model, the decoupler, tiling, the Dask
cluster and the product pipeline.
"""

from dataclasses import dataclass

from .errors import IPCInputError
from .geometry import Geometry
from .laws import check_convergence, get_law

__all__ = ["CouplingModel", "EDGES"]

EDGES = ("zero", "isolated")
"""Edge rules: ``zero`` = zero-signal pixels beyond the frame (they take
charge and give none back, the paper's choice); ``isolated`` = no coupling
across the frame edge (total charge conserved)."""


@dataclass(frozen=True)
class CouplingModel:
    """The IPC model: coupling law, neighbour geometry and edge rule.

    Build it with :meth:`resolve`; the constructor expects resolved objects.

    Attributes
    ----------
    law : ParametricLaw or TabulatedLaw
        alpha(S, N), in electrons of collected charge.
    geometry : Geometry
        Neighbour offsets and the weights that multiply alpha.
    edge : {"zero", "isolated"}
        What lies beyond the frame (see :data:`EDGES`).
    """

    law: object
    geometry: Geometry
    edge: str = "zero"

    @classmethod
    def resolve(cls, law="donlon2018", geometry=None, edge="zero"):
        """A validated model from user-facing values.

        Parameters
        ----------
        law : str, float, law object or CouplingModel
            See :func:`ipc_taichi.laws.get_law`. A :class:`CouplingModel` is
            returned as it is (``geometry`` and ``edge`` must then be left at
            their defaults).
        geometry : Geometry, mapping, str or None
            Default: the 4 nearest neighbours with weight 1.
        edge : {"zero", "isolated"}

        Raises
        ------
        LawError, GeometryError, IPCInputError
        """
        if isinstance(law, cls):
            if geometry is not None or edge != "zero":
                raise IPCInputError("give either a CouplingModel or law/geometry/edge, not both")
            return law
        law = get_law(law)
        if geometry is None:
            geometry = Geometry.nearest()
        elif not isinstance(geometry, Geometry):
            geometry = Geometry.parse(geometry) if isinstance(geometry, str) else Geometry(geometry)
        if edge not in EDGES:
            raise IPCInputError(f"edge must be one of {', '.join(EDGES)}, got {edge!r}")
        check_convergence(law, geometry)
        return cls(law, geometry, edge)

    @classmethod
    def from_arguments(cls, law="donlon2018", geometry=None, edge="zero", model=None):
        """The model of a public function's ``law``/``geometry``/``edge`` or
        ``model=`` arguments (not both)."""
        if model is None:
            return cls.resolve(law, geometry, edge)
        if not isinstance(model, cls):
            raise IPCInputError(f"model must be a CouplingModel, got {type(model).__name__}")
        if not (isinstance(law, str) and law == "donlon2018") or geometry is not None \
                or edge != "zero":
            raise IPCInputError("give either model= or law/geometry/edge, not both")
        return model

    @property
    def reach(self):
        """The furthest neighbour offset (pixels): how far one step moves information."""
        return self.geometry.reach

    def describe(self):
        """One line: ``law; geometry; edge``."""
        return f"{self.law.describe()}; {self.geometry.describe()}; edge {self.edge}"

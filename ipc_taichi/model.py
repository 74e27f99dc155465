"""The coupling model: one value for the law, the geometry and the edge rule.

A :class:`CouplingModel` is resolved and validated once (law parsed, geometry
built, edge checked, the Jacobi contraction condition tested) and then handed
unchanged to every layer: the forward model, the decoupler, tiling, the Dask
cluster and the product pipeline.

The model file
--------------
:meth:`CouplingModel.save` and :meth:`CouplingModel.load` keep a model on disk
(what ``ipc-taichi calibrate`` writes and ``--model FILE`` reads): one JSON
document, versioned, readable by eye and by any language::

    {
      "format": "ipc_taichi.coupling_model",
      "version": 1,
      "law": {"kind": "parametric", "name": "...", "amp_diff": ..., "scale_diff": ...,
              "amp_level": ..., "scale_level": ..., "floor": ...}
          or {"kind": "table", "name": "...", "signal_min": ..., "signal_step": ...,
              "table": [[...], ...]},
      "geometry": [[dy, dx, weight], ...],
      "edge": "zero" | "isolated",
      "units": "electron",
      "provenance": {...},        # free-form: inputs, gain, software version, date
      "fit": {...},               # free-form: fit quality, uncertainties, what was assumed
      # version 2: named sections of what calibrate measured beside the law (optional)
      "law_band": {...},          # the law's 1-sigma band along (S, 0) and (S, S)
      "brighter_fatter": {"kernel": [[...] x 5], "kernel_error": ..., "units": "1/electron"},
      "classical_nonlinearity": {"beta": ..., "error": ..., "form": "M = Q - beta Q^2"},
      "gain": {...},              # the gain given and the gain the flat ramps measured
      # version 3: IPC that varies across the detector (optional; see ipc_taichi.bondmap)
      "bond_map": {"offsets": [[dy, dx], ...], "shape": [ny, nx],
                   "superpixel": [sy, sx], "coarse": [[[...]]]}     # super-pixel values, or
               or {"offsets": ..., "shape": ..., "file": "NAME.npz"} # full resolution, beside
    }                                                               # the model file

The law is in electrons of collected charge (``units`` must say so): a model
measured in DN is converted before it is written. ``geometry`` multiplies
alpha exactly as :class:`ipc_taichi.geometry.Geometry` does. ``provenance``
and ``fit`` are carried, never interpreted, by the readers. The sections
(:data:`SECTIONS`) describe the detector beyond IPC for the forward
simulators (``simulate-lab``, ``discover``'s starting model); the model
itself, and so ``decouple``, is IPC only: it never reads them. Version 1
files (no sections) are read unchanged. A ``bond_map`` (version 3) multiplies
the law per neighbour pair (:mod:`ipc_taichi.bondmap`); without one the model is
uniform across the detector, as every version-1 and -2 file is.

:meth:`CouplingModel.save` writes to a temporary file in the target folder
and renames it into place, so a crash never leaves half a model.
"""

import json
import os
from dataclasses import dataclass

import numpy as np

from .bondmap import BondMap
from .errors import IPCInputError, LawError
from .fitsio import atomic_output, write_json
from .geometry import Geometry
from .laws import ParametricLaw, TabulatedLaw, check_convergence, get_law

__all__ = ["CouplingModel", "EDGES", "DEFAULT_LAW", "DEFAULT_EDGE", "MODEL_FORMAT",
           "MODEL_VERSION", "SECTIONS"]

MODEL_FORMAT = "ipc_taichi.coupling_model"
MODEL_VERSION = 3
SECTIONS = ("law_band", "brighter_fatter", "classical_nonlinearity", "gain")
"""Named sections a model file may carry beside the law (version 2)."""
_PARAMETRIC = ("amp_diff", "scale_diff", "amp_level", "scale_level", "floor")

EDGES = ("zero", "isolated")
"""Edge rules: ``zero`` = zero-signal pixels beyond the frame (they take
charge and give none back, the paper's choice); ``isolated`` = no coupling
across the frame edge (total charge conserved)."""

DEFAULT_LAW = "donlon2018"
"""The law when none is given: the paper's (:func:`ipc_taichi.laws.donlon2018`)."""

DEFAULT_EDGE = "zero"
"""The edge rule when none is given: the paper's."""


def _what_is_wrong(exc, kind, doc):
    """One line saying which entry of a model file (``doc``) is missing or
    malformed (never a bare ``KeyError`` or "not enough values to unpack")."""
    if isinstance(exc, KeyError):
        key = exc.args[0] if exc.args else "?"
        if key == "geometry":
            return 'no "geometry" list of [dy, dx, weight] entries'
        needs = _PARAMETRIC if kind == "parametric" else ("signal_min", "signal_step", "table")
        return (f'a {kind} law needs {", ".join(needs)}: "{key}" is missing' if key in needs
                else f'no "{key}" entry')
    if type(exc) not in (ValueError, TypeError):  # a law or geometry that does not validate
        return str(exc)
    entries = doc.get("geometry")
    if not isinstance(entries, list) or not all(
            isinstance(e, list) and len(e) == 3 and all(isinstance(v, (int, float)) for v in e)
            for e in entries):
        return f'"geometry": each entry must be [dy, dx, weight], numbers ({exc})'
    return f'"law" ({kind}): a malformed value ({exc})'


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
    bonds : BondMap or None
        The coupling of each neighbour pair relative to the law
        (:mod:`ipc_taichi.bondmap`); ``None``: uniform across the detector.
    """

    law: object
    geometry: Geometry
    edge: str = DEFAULT_EDGE
    bonds: BondMap = None

    @classmethod
    def resolve(cls, law=None, geometry=None, edge=None, *, model=None, bonds=None):
        """The validated model of user-facing values: the one way to build one.

        Every public function that takes ``law``/``geometry``/``edge`` or
        ``model=`` hands them here unchanged, so the defaults and the refusal
        of both at once are written only here.

        Parameters
        ----------
        law : str, float, law object, CouplingModel or None
            See :func:`ipc_taichi.laws.get_law`; ``None`` is the paper's law
            (:data:`DEFAULT_LAW`). A :class:`CouplingModel` here is taken as
            ``model=``.
        geometry : Geometry, mapping, str or None
            ``None``: the 4 nearest neighbours with weight 1.
        edge : {"zero", "isolated"} or None
            ``None``: :data:`DEFAULT_EDGE`.
        model : CouplingModel, str or path-like, optional
            A resolved model, or the path of a model file (:meth:`load`); then
            ``law``, ``geometry`` and ``edge`` must be ``None``.
        bonds : BondMap, optional
            A map of the coupling across the detector (with law/geometry/edge,
            not with ``model``); a map of all ones is dropped (the uniform model).

        Returns
        -------
        CouplingModel

        Raises
        ------
        IPCInputError
            ``model`` together with any of ``law``, ``geometry``, ``edge``; a
            bad ``edge``; a ``model`` that is neither a model nor a path; an
            unreadable model file.
        LawError, GeometryError
            A bad law or geometry, or a law too strong for the iteration to
            converge (:func:`ipc_taichi.laws.check_convergence`).
        """
        if isinstance(law, cls):
            if model is not None:
                raise IPCInputError("give the coupling model once (law= or model=), not both")
            law, model = None, law
        if model is not None:
            given = [name for name, value in (("law", law), ("geometry", geometry), ("edge", edge),
                                              ("bonds", bonds)) if value is not None]
            if given:
                raise IPCInputError(f"give either model= or law/geometry/edge, not both "
                                    f"(got model= and {', '.join(given)}=)")
            if isinstance(model, (str, os.PathLike)):
                return cls.load(model)
            if not isinstance(model, cls):
                raise IPCInputError(f"model must be a CouplingModel or a model file path, got "
                                    f"{type(model).__name__}")
            return model
        law = get_law(DEFAULT_LAW if law is None else law)
        if geometry is None:
            geometry = Geometry.nearest()
        elif not isinstance(geometry, Geometry):
            geometry = Geometry.parse(geometry) if isinstance(geometry, str) else Geometry(geometry)
        edge = DEFAULT_EDGE if edge is None else edge
        if edge not in EDGES:
            raise IPCInputError(f"edge must be one of {', '.join(EDGES)}, got {edge!r}")
        if bonds is not None:
            if not isinstance(bonds, BondMap):
                raise IPCInputError(f"bonds must be a BondMap, got {type(bonds).__name__}")
            bonds.check(geometry)
            if bonds.is_uniform():
                bonds = None
        check_convergence(law, geometry, 1.0 if bonds is None else bonds.max_factor())
        return cls(law, geometry, edge, bonds)

    @property
    def reach(self):
        """The furthest neighbour offset (pixels): how far one step moves information."""
        return self.geometry.reach

    def describe(self):
        """One line: ``law; geometry; edge`` (and the map's size, if any)."""
        text = f"{self.law.describe()}; {self.geometry.describe()}; edge {self.edge}"
        if self.bonds is not None:
            ny, nx = self.bonds.shape
            lo, hi = float(self.bonds.values.min()), float(self.bonds.values.max())
            text += f"; bond map {ny}x{nx} ({lo:.3g}..{hi:.3g})"
        return text

    def uniform(self):
        """The same model without its map."""
        return CouplingModel(self.law, self.geometry, self.edge)

    # ---- the model file --------------------------------------------------------------

    def to_dict(self, provenance=None, fit=None, sections=None, map_file=None):
        """The model file's content (see the module docstring); ``sections``
        maps names of :data:`SECTIONS` to JSON objects. A full-resolution map
        is named by ``map_file`` (the file :meth:`save` writes beside the model);
        a super-pixel map is written inline."""
        unknown = sorted(set(sections or ()) - set(SECTIONS))
        if unknown:
            raise IPCInputError(f"unknown model-file section(s) {', '.join(unknown)} "
                                f"(known: {', '.join(SECTIONS)})")
        law = self.law
        if isinstance(law, ParametricLaw):
            law_doc = {"kind": "parametric", "name": law.name,
                       **{k: float(getattr(law, k)) for k in _PARAMETRIC}}
        elif isinstance(law, TabulatedLaw):
            law_doc = {"kind": "table", "name": law.name, "signal_min": float(law.signal_min),
                       "signal_step": float(law.signal_step), "table": law.table.tolist()}
        else:
            raise LawError(f"cannot write a law of type {type(law).__name__} to a model file")
        return {
            "format": MODEL_FORMAT,
            "version": MODEL_VERSION,
            "law": law_doc,
            "geometry": [[dy, dx, float(w)] for (dy, dx), w in self.geometry.weights],
            "edge": self.edge,
            "units": "electron",
            "provenance": dict(provenance or {}),
            "fit": dict(fit or {}),
            **{name: value for name, value in (sections or {}).items() if value is not None},
            **({} if self.bonds is None else {"bond_map": _map_doc(self.bonds, map_file)}),
        }

    @classmethod
    def from_dict(cls, doc, source="model file", folder="."):
        """A validated model from a model file's content; ``source`` names the
        file in errors (:class:`IPCInputError`, one line); ``folder`` is where a
        full-resolution map's file is looked for."""
        def bad(why):
            return IPCInputError(f"{source}: {why}")

        if not isinstance(doc, dict) or doc.get("format") != MODEL_FORMAT:
            raise bad(f"not an ipc_taichi coupling-model file (no \"format\": \"{MODEL_FORMAT}\")")
        version = doc.get("version")
        if not isinstance(version, int) or version < 1:
            raise bad(f"bad version {version!r}")
        if version > MODEL_VERSION:
            raise bad(f"version {version} is newer than this ipc_taichi reads "
                      f"({MODEL_VERSION}); upgrade ipc_taichi")
        if doc.get("units", "electron") != "electron":
            raise bad(f"the law must be in electrons, the file says units={doc.get('units')!r}")
        law_doc = doc.get("law")
        if not isinstance(law_doc, dict):
            raise bad('no "law" object')
        kind = law_doc.get("kind")
        if kind not in ("parametric", "table"):
            raise bad(f"unknown law kind {kind!r} (parametric or table)")
        try:
            if kind == "parametric":
                law = ParametricLaw(*(float(law_doc[k]) for k in _PARAMETRIC),
                                    name=str(law_doc.get("name", "parametric")))
            else:
                law = TabulatedLaw(float(law_doc["signal_min"]), float(law_doc["signal_step"]),
                                   np.asarray(law_doc["table"], dtype=np.float64),
                                   name=str(law_doc.get("name", "table")))
            geometry = Geometry({(int(dy), int(dx)): float(w) for dy, dx, w in doc["geometry"]})
            bonds = (None if doc.get("bond_map") is None
                     else _map_of(doc["bond_map"], geometry, folder))
            return cls.resolve(law, geometry, doc.get("edge", DEFAULT_EDGE), bonds=bonds)
        except (KeyError, TypeError, ValueError) as exc:
            raise bad(_what_is_wrong(exc, kind, doc)) from None

    @classmethod
    def load(cls, path, with_document=False):
        """The model in the file at ``path`` (``(model, document)`` with
        ``with_document``, for its ``provenance`` and ``fit``).

        Raises
        ------
        IPCInputError
            One line naming the file: unreadable, not JSON, not a model file,
            a newer version, or a law/geometry that does not validate.
        """
        path = os.fspath(path)
        try:
            with open(path, encoding="utf-8") as f:
                doc = json.load(f)
        except OSError as exc:
            raise IPCInputError(f"{path}: cannot read the model file "
                                f"({exc.strerror or exc})") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise IPCInputError(f"{path}: not a JSON coupling-model file ({exc})") from None
        model = cls.from_dict(doc, source=path, folder=os.path.dirname(path) or ".")
        return (model, doc) if with_document else model

    def save(self, path, provenance=None, fit=None, overwrite=False, sections=None):
        """Write the model (with ``provenance`` and ``fit`` dicts of JSON values;
        NumPy scalars and arrays are converted, use None for "not measured"; and
        the named ``sections`` of :data:`SECTIONS`) to ``path`` atomically
        (temporary file in the same folder, then renamed).

        Raises
        ------
        IPCInputError
            ``path`` exists and ``overwrite`` is false, or cannot be written.
        """
        map_file = None
        if self.bonds is not None and self.bonds.coarse is None:
            map_file = os.path.splitext(os.path.basename(os.fspath(path)))[0] + ".bonds.npz"
            target = os.path.join(os.path.dirname(os.fspath(path)) or ".", map_file)
            with atomic_output(target, overwrite) as tmp:
                with open(tmp, "wb") as f:
                    np.savez(f, offsets=np.array(self.bonds.offsets), values=self.bonds.values)
        return write_json(path, self.to_dict(provenance, fit, sections, map_file), overwrite)


def _map_doc(bonds, map_file):
    """The model file's ``bond_map`` object (module docstring)."""
    doc = {"offsets": [list(u) for u in bonds.offsets], "shape": list(bonds.shape)}
    if bonds.coarse is not None:
        return {**doc, "superpixel": list(bonds.superpixel), "coarse": bonds.coarse.tolist()}
    if map_file is None:
        raise IPCInputError("a full-resolution bond map is written beside its model file: "
                            "use CouplingModel.save")
    return {**doc, "file": map_file}


def _map_of(doc, geometry, folder):
    """The :class:`BondMap` a model file's ``bond_map`` object describes."""
    shape = tuple(int(n) for n in doc["shape"])
    offsets = tuple((int(dy), int(dx)) for dy, dx in doc["offsets"])
    if "coarse" in doc:
        bonds = BondMap.superpixels(geometry, np.asarray(doc["coarse"], dtype=np.float64),
                                    doc["superpixel"], shape)
    else:
        path = os.path.join(folder, os.path.basename(str(doc["file"])))
        try:
            with np.load(path) as z:
                bonds = BondMap(tuple(map(tuple, z["offsets"].tolist())), z["values"])
        except (OSError, KeyError, ValueError) as exc:
            raise IPCInputError(f"cannot read its bond map {path} ({exc})") from None
    if bonds.offsets != offsets or tuple(bonds.shape) != shape:
        raise IPCInputError("its bond map does not match the offsets/shape it states")
    return bonds


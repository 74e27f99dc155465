"""The records of a calibration (:func:`~.workflow.calibrate`): small frozen values.

:class:`Inputs` is what calibrate was given and read (the files as
:class:`~.inputs.ChargeFrames`, the reference file, the read noise);
:class:`Outcome` what it measured and decided (the hot pixels, the flats, the
effects, the law's fit, the transfer check, the map, the assumptions tested).
Each gives its entries of the report; :func:`assemble` puts them together,
as :func:`ipc_taichi.discover.report.assemble` does for a search.
"""

import datetime
from dataclasses import dataclass

from .. import __version__
from . import flats as flatmod

__all__ = ["Inputs", "Outcome", "assemble"]


@dataclass(frozen=True)
class Inputs:
    """What calibrate was given: ``darks`` and ``flats`` (tuples of
    :class:`~.inputs.ChargeFrames`), the ``reference`` file (or None), the
    read noise ``read_noise_given`` [e-] (or None), the one the darks gave
    ``read_noise_darks`` (or None) and the one used ``read_noise`` (or None:
    taken as 0)."""

    darks: tuple
    flats: tuple
    reference: object
    read_noise_given: object
    read_noise_darks: object
    read_noise: object

    @property
    def files(self):
        return self.darks + self.flats

    def read_noise_source(self):
        if self.read_noise_given is not None:
            return "given"
        return "darks" if self.read_noise_darks is not None else "unknown (0)"

    def provenance(self, gain):
        """The report's and the model file's ``provenance``; ``gain`` the
        report's ``gain`` entry (``used``, ``source``)."""
        return {"software": f"ipc_taichi {__version__}", "command": "calibrate",
                "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                "darks": [f.label for f in self.darks], "flats": [f.label for f in self.flats],
                "reference": self.reference,
                "units": sorted({f.units for f in self.files}),
                "gain": gain["used"], "gain_source": gain["source"],
                "read_noise_e": self.read_noise,
                "read_noise_source": self.read_noise_source()}

    def entries(self):
        """The report's ``inputs``: one entry per file, darks first."""
        return [_input_entry(f, role) for role, files in
                (("dark", self.darks), ("flat", self.flats)) for f in files]


def _input_entry(f, role):
    return {"file": f.label, "role": role, "stack": f.meta.get("stack"),
            "stack_reason": f.meta.get("stack_reason"), "units": f.units,
            "units_note": f.meta.get("units_note"), "dq_note": f.meta.get("dq_note"),
            "shape": list(f.data.shape)}


_SUMMARY = ("chosen", "law", "weights", "weight_errors", "assumed", "held_outside", "notes",
            "chi2_per_point", "n_points")


@dataclass(frozen=True)
class Outcome:
    """What calibrate measured and decided.

    ``hot`` the darks' hot pixels (``found``, ``rows``, ``floors``), ``flat``
    the flats (``rows``, ``measured``, ``frame_rows``; None without flats),
    ``effects`` the report's ``gain``, ``classical_nonlinearity`` and
    ``brighter_fatter``, ``nonlinear_ipc`` the verdict on it, ``fit`` the
    law's choice (:func:`~.lawfit.choose_law`, or the reference file's),
    ``transfer`` the held-out check (or None), ``bond_map`` the map (or None),
    ``assumptions`` those tested, ``reference`` the reference file's entry
    (or None), ``not_measured`` and ``notes`` (sentences).
    """

    hot: object
    flat: object
    effects: dict
    nonlinear_ipc: dict
    fit: dict
    transfer: object
    bond_map: object
    assumptions: list
    reference: object
    not_measured: list
    notes: list

    def summary(self):
        """The model file's ``fit``: the law's choice in brief."""
        out = {k: self.fit.get(k) for k in _SUMMARY}
        out["law_choice"] = self.fit.get("law_choice")
        out["not_measured"] = self.not_measured
        return out

    def sections(self):
        """The model file's named sections (never used by ``decouple``)."""
        out = {}
        bf = self.effects["brighter_fatter"]
        if bf.get("measured") and bf.get("kernel") is not None:
            out["brighter_fatter"] = {"kernel": bf["kernel"], "kernel_error": bf["kernel_error"],
                                      "detected": bf.get("detected"), "units": "1/electron",
                                      "convention": "pixel area 1 + sum_d a(d) Q(p+d); "
                                                    "kernel[2+dy][2+dx]"}
        nl = self.effects["classical_nonlinearity"]
        if nl.get("measured"):
            out["classical_nonlinearity"] = {"beta": nl["beta"], "error": nl["error"],
                                             "detected": nl.get("detected"),
                                             "units": "1/electron", "form": "M = Q - beta Q^2"}
        if self.fit.get("band"):
            out["law_band"] = {**self.fit["band"], "method": "delete-a-fold jackknife of the "
                               "chosen form fitted without each fold; 1 sigma",
                               "held_outside": self.fit.get("held_outside")}
        if self.effects["gain"].get("measured") is not None:
            out["gain"] = self.effects["gain"]
        return out

    def hot_pixels(self):
        """The report's ``hot_pixels``."""
        return {"found": self.hot.found, "bins": self.hot.rows, "floors_e": self.hot.floors}

    def flats(self):
        """The report's ``flats``: the per-level points, each ramp set's
        measurement and the frames' growth with signal."""
        flat = self.flat
        if flat is None:
            return {"levels": [], "ramps": [], "growth_with_signal": {}}
        return {"levels": flat.rows,
                "ramps": [{"files": label, **m} for label, m in flat.measured],
                "growth_with_signal": flatmod.growth_with_signal(flat.frame_rows)}

    def map_entry(self):
        """The report's ``bond_map`` (the map itself is the model's)."""
        if not self.bond_map:
            return None
        return {k: v for k, v in self.bond_map.items() if k != "bonds"}


def assemble(inputs, outcome, model, provenance):
    """The report of a calibration (JSON-ready once through
    :func:`~.report.json_ready`): ``inputs`` (:class:`Inputs`), ``outcome``
    (:class:`Outcome`), the ``model`` written and its ``provenance``
    (:meth:`Inputs.provenance`)."""
    return {"provenance": provenance, "model": model.describe(),
            "inputs": inputs.entries(),
            **outcome.effects, "nonlinear_ipc": outcome.nonlinear_ipc,
            "law_choice": outcome.fit.get("law_choice"),
            "transfer": outcome.transfer, "fit": outcome.fit,
            "hot_pixels": outcome.hot_pixels(), "flats": outcome.flats(),
            "bond_map": outcome.map_entry(), "assumptions": outcome.assumptions,
            "reference": outcome.reference, "not_measured": outcome.not_measured,
            "notes": outcome.notes}

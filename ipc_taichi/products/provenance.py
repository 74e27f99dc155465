"""What a product records about its correction: IPC keywords, HISTORY, S_IPC.

One place for the record written into FITS headers and Roman ``meta``:

- the primary header holds the run: ``S_IPC`` (the JWST step-status
  keyword), ``IPCOP``, the model (``IPCLAW``, ``IPCGEOM``, ``IPCEDGE`` and
  ``IPCEDGER``, why that edge rule), ``IPCNHDU`` (science HDUs changed),
  ``IPCHDU`` (the first, by index and name), ``IPCDQBIT``, ``IPCNBAD``
  (unflagged pixels masked as unphysical: infinite, or a charge no detector
  can hold; all HDUs), ``IPCPED`` (the
  pedestal), ``IPCCOADD``, ``IPCARCH``, ``IPCPREC``, and for decouple
  ``IPCITER``, ``IPCCONV``, ``IPCTOL``, ``IPCMAXIT``, ``IPCREMOV`` (what
  was removed: IPC only); HISTORY lines (the model, what was removed, each
  HDU's units, one line per frame);
- each changed science HDU holds its own: ``IPCOP``, ``IPCHDU``,
  ``IPCSCIRG`` (the science region, inside the reference pixels, as a 1-based
  FITS section ``[x1:x2,y1:y2]``; written as ``IPCREFPX`` before 2026-11, a
  name that said reference pixels for what is the science region),
  ``IPCNREF`` (the reference pixels outside it: bottom, top, left, right, as
  the JWST ``ipc`` step counts them), ``IPCTIME`` (seconds; 0 when not a rate), ``IPCNBAD``
  (this HDU's unphysical pixels masked), and for
  decouple ``IPCITER``, ``IPCCONV``.

``S_IPC`` is written last, after the work (a killed run's temporary file
says ``PENDING``): ``COMPLETE`` when every science HDU of the product is
decoupled and met the stopping rule (or ran a fixed count, ``tol = 0``),
``FAILED`` when the stopping rule was not met (JWST's own value; ``IPCCONV``
says so too), ``PARTIAL`` when ``--hdu`` left other science HDUs uncorrected.
"""

import datetime

from .. import __version__
from ..fitsio import history_lines

__all__ = ["Provenance", "status", "section", "card_text"]

PENDING = "PENDING"

REMOVED_SHORT = "IPC only"
REMOVED = "removed: IPC only; brighter-fatter, non-linearity not corrected"
"""What decouple removes, said in every product it writes: a model file's
brighter-fatter and non-linearity sections are never applied."""


def _now():
    return datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def card_text(text, width, separators=" ,;"):
    """``text`` in at most ``width`` characters for a header card: whole, or
    cut at its last separator (of ``separators``) that leaves room for
    ``...``, never inside a number or a word (the HISTORY holds it whole)."""
    text = str(text)
    if len(text) <= width:
        return text
    head = text[:width - 3]
    cut = max(head.rfind(c) for c in separators)
    return (head[:cut].rstrip(" ,;") if cut > 0 else head) + "..."


def section(region):
    """``(slice y, slice x)`` (0-based, stop exclusive) -> ``"[x1:x2,y1:y2]"``
    (FITS: 1-based, inclusive, x first)."""
    ys, xs = region
    return f"[{xs.start + 1}:{xs.stop},{ys.start + 1}:{ys.stop}]"


def status(infos_by_hdu, all_science, tol):
    """The value of ``S_IPC`` for a decouple run (see the module's text)."""
    infos = [i for infos in infos_by_hdu.values() for i in infos]
    if tol != 0 and not all(i.converged for i in infos):
        return "FAILED"
    return "COMPLETE" if all_science else "PARTIAL"


class Provenance:
    """The record of one run on one product (FITS headers or a Roman dict).

    The header cards are the same before and after the work (values change,
    the count does not), so a header written before the data streams into
    the file keeps its size when it is rewritten at the end.
    """

    def __init__(self, plan, settings, ran=None, noise="none"):
        """The record of a run of ``settings`` (its
        :class:`~ipc_taichi.products.correction.RunSettings`) on ``plan`` (its
        :class:`~ipc_taichi.products.plan.ProductPlan`: the model, edge and
        coadds of its first array, one science HDU per array); ``ran``: the
        runtime it ran on (its ``arch`` and ``precision``; None: not known);
        ``noise``: what was done with the noise arrays
        (:func:`ipc_taichi.products.noise_arrays.noise_of`)."""
        first = plan.arrays[0]
        self.operation = settings.operation
        self.model = first.model
        self.edge_reason = first.edge_reason
        self.bits = int(plan.bits)
        self.pedestal_text = plan.pedestal_text
        self.coadds = int(first.coadds)
        self.arch, self.precision = (ran.arch, ran.precision) if ran is not None else ("", "")
        self.tol, self.max_iter, self.tile = settings.tol, settings.max_iter, settings.tile
        self.all_science = plan.complete
        self.noise = noise
        self.hdus = {}  # index -> dict(name, region, units, exptime, frames)
        self.infos = {}  # index -> list of DecoupleInfo (None before the work)
        self.unphysical = {}  # index -> unflagged pixels masked as unphysical
        self.started = _now()
        for array in plan.arrays:
            self._add(array)

    def _add(self, array):
        """A science array of the run (an :class:`~ipc_taichi.products.plan.ArrayPlan`):
        its reference-pixel widths (bottom, top, left, right: ``IPCNREF``), and
        how its frames are read out when not contiguous (said in HISTORY)."""
        arrangement = array.arrangement
        self.hdus[array.index] = dict(
            name=array.name, label=array.label, region=array.region, units=array.units_text,
            exptime=float(array.exptime or 0.0), frames=array.frames,
            nref=" ".join(str(n) for n in array.science_region.widths),
            arrangement="" if arrangement.identity else arrangement.note)
        self.infos[array.index] = [None] * array.frames

    @property
    def done(self):
        return all(all(i is not None for i in v) for v in self.infos.values())

    def status(self):
        if self.operation != "decouple":
            return None
        return status(self.infos, self.all_science, self.tol) if self.done else PENDING

    def _iterations(self, infos):
        return max(i.iterations for i in infos) if infos and all(infos) else 0

    def _converged(self, infos):
        return bool(infos and all(infos) and all(i.converged for i in infos))

    def primary(self, header):
        """Write the run's keywords and HISTORY into ``header`` (returned)."""
        for key in ("CHECKSUM", "DATASUM"):
            header.remove(key, ignore_missing=True, remove_all=True)
        first = min(self.hdus)
        every = [i for v in self.infos.values() for i in v]
        law, geometry = card_text(self.model.law.name, 68), card_text(
            self.model.geometry.describe(), 68, ";")  # a term is "dy,dx=w"
        cards = {}
        if self.operation == "decouple":
            cards["S_IPC"] = (self.status(), "IPC correction (ipc_taichi)")
        cards.update({
            "IPCVER": (__version__, "ipc_taichi version"),
            "IPCOP": (self.operation, "IPC operation applied"),
            "IPCNHDU": (len(self.hdus), "science HDUs changed"),
            "IPCHDU": (f"{first} {self.hdus[first]['name']}"[:60], "first HDU changed: index name"),
            "IPCLAW": (law, "IPC coupling law alpha(S,N), electrons"),
            "IPCGEOM": (geometry, "IPC geometry (dy,dx)=weight"),
            "IPCEDGE": (self.model.edge, "IPC edge rule"),
            "IPCEDGER": (card_text(self.edge_reason, 60), "why this edge rule"),
            "IPCDQBIT": (self.bits, "DQ bits of pixels left out"),
            "IPCNBAD": (sum(self.unphysical.values()), "unflagged unphysical pixels masked"),
            "IPCPED": (card_text(self.pedestal_text, 60),
                       "charge on the node before the first read"),
            "IPCCOADD": (self.coadds, "exposures summed per frame"),
            "IPCNOISE": (card_text(self.noise, 68), "ERR/VAR_* arrays: how carried"),
            "IPCARCH": (self.arch, "Taichi arch used"),
            "IPCPREC": (self.precision, "floating precision"),
        })
        if self.operation == "decouple":
            cards.update({
                "IPCITER": (self._iterations(every), "Jacobi iterations (max over frames)"),
                "IPCCONV": (self._converged(every), "stopping rule met (all frames)"),
                "IPCTOL": (self.tol, "stop: max|dS| <= TOL*max|S|"),
                "IPCMAXIT": (self.max_iter, "iteration limit"),
                "IPCREMOV": (REMOVED_SHORT, "removed only IPC: not BF, not non-linearity"),
            })
        for key, value in cards.items():
            header[key] = value
        for text in self._history():
            for line in history_lines(text):
                header.add_history(line)
        return header

    def science(self, index, header):
        """Write HDU ``index``'s own keywords into ``header`` (returned)."""
        for key in ("CHECKSUM", "DATASUM"):
            header.remove(key, ignore_missing=True, remove_all=True)
        h = self.hdus[index]
        header["IPCOP"] = (self.operation, "IPC operation applied to this HDU")
        header["IPCHDU"] = (f"{index} {h['name']}"[:60], "this HDU: index name")
        header["IPCSCIRG"] = (section(h["region"]), "science region (FITS section, 1-based)")
        header["IPCNREF"] = (h["nref"], "reference pixels: bottom top left right")
        header["IPCTIME"] = (h["exptime"], "integration time used, s (0: not a rate)")
        header["IPCNBAD"] = (self.unphysical.get(index, 0), "unflagged unphysical pixels masked")
        if self.operation == "decouple":
            infos = self.infos[index]
            header["IPCITER"] = (self._iterations(infos), "Jacobi iterations (max, this HDU)")
            header["IPCCONV"] = (self._converged(infos), "stopping rule met (this HDU)")
        return header

    def _history(self):
        how = f" (tiles {self.tile})" if self.tile else ""
        lines = [f"{self.started} ipc_taichi {__version__} {self.operation}{how}",
                 f"model: {self.model.describe()}; edge: {self.edge_reason}",
                 *([REMOVED] if self.operation == "decouple" else []),
                 f"pedestal: {self.pedestal_text}; coadds: {self.coadds}",
                 f"noise arrays: {self.noise}"]
        for index, h in self.hdus.items():
            lines.append(f"HDU {index} {h['name']}: units {h['units']}")
            if h["arrangement"]:
                lines.append(f"HDU {index} {h['name']}: {h['arrangement']}; corrected in the "
                             "contiguous image, every other sample as it came")
            if self.operation == "decouple":
                for k, i in enumerate(self.infos[index]):
                    if getattr(i, "lost", ""):  # products.checks.LostFrame
                        lines.append(f"  frame {k:5d}: left as it was: {i.lost}")
                        continue
                    it, conv = (i.iterations, i.converged) if i else (0, False)
                    last = i.max_delta[-1] if i and i.max_delta else 0.0
                    lines.append(f"  frame {k:5d}: {it:3d} iterations, "
                                 f"{'converged    ' if conv else 'NOT converged'}, "
                                 f"last max|dS| {last:10.3e}")
        return lines

    def summary(self, output):
        """What a product run returns (:func:`~ipc_taichi.products.process_fits`,
        :func:`~ipc_taichi.products.process_asdf`): ``output``, ``label`` (the
        first array's), ``frames``, ``infos``, ``hdus`` (the arrays' labels),
        ``iterations`` (max over frames), ``converged`` (all frames; None for
        couple or ``tol = 0``), ``law``, ``edge`` and ``masked_unphysical``
        (``IPCNBAD``, all arrays)."""
        infos = [i for v in self.infos.values() for i in v]
        decoupled = self.operation == "decouple"
        converged = all(i.converged for i in infos) if decoupled and self.tol != 0 else None
        return {"output": output, "label": next(iter(self.hdus.values()))["label"],
                "frames": len(infos), "infos": infos,
                "hdus": [h["label"] for h in self.hdus.values()],
                "iterations": max(i.iterations for i in infos) if decoupled else 0,
                "converged": converged, "law": self.model.law.name, "edge": self.model.edge,
                "masked_unphysical": sum(self.unphysical.values())}

    def record(self):
        """The same record as a dict (Roman ``meta.ipc_taichi``)."""
        (index, h), = self.hdus.items()
        out = {"version": __version__, "operation": self.operation,
               "law": self.model.law.name, "model": self.model.describe(),
               "edge_reason": self.edge_reason, "units": h["units"], "dq_bits": self.bits,
               "masked_unphysical": int(self.unphysical.get(index, 0)),
               "pedestal": self.pedestal_text, "coadds": self.coadds, "noise": self.noise,
               "science_region": [[h["region"][0].start, h["region"][0].stop],
                                  [h["region"][1].start, h["region"][1].stop]],
               "arch": self.arch or "", "precision": self.precision or ""}
        if self.operation == "decouple":
            infos = self.infos[index]
            out.update(removed=REMOVED, S_IPC=self.status(),
                       iterations=[int(i.iterations) for i in infos],
                       lost_frames=[k for k, i in enumerate(infos) if getattr(i, "lost", "")],
                       converged=self._converged(infos), tol=float(self.tol),
                       max_iter=int(self.max_iter))
        return out

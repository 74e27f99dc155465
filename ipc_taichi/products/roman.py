"""Roman ASDF products in, the same products out (``pip install ipc_taichi[roman]``).

Read and written through ``roman_datamodels``, so the whole tree (metadata,
``err``, variances, border reference pixels, ``amp33``, WCS) is carried
through; only the science array changes, in its own dtype. The rules are
those of :mod:`ipc_taichi.products.conventions`:

- level 2 (``ImageModel``): ``data`` in DN/s (the trimmed 4088x4088 science
  area; the border reference pixels are stored apart and untouched), ``dq``;
  after the flux step (``meta.cal_step.flux == "COMPLETE"``) the data are
  MJy/sr and refused;
  the rate is converted with the gain and the integration time
  (``meta.exposure.effective_exposure_time``, else ``exposure_time``);
- ramps (``RampModel``, resultants in DN after bias and reference-pixel
  correction): resultant by resultant, ``pixeldq`` and ``groupdq`` honoured,
  a 4-pixel reference border in a 4096x4096 frame unless flagged otherwise;
- raw level-1 resultants (``ScienceRawModel``, uint16 with the bias in them)
  are refused: the law needs collected charge, so subtract the bias first.

The output records ``meta.ipc_taichi`` (what was done, ``S_IPC = COMPLETE``)
and, for ramps, ``meta.cal_step.ipc = "COMPLETE"``.
"""

import os
import tempfile
import warnings

import numpy as np

from .. import iteration
from ..errors import IPCInputError
from ..fitsio import cannot_write, check_output_path
from ..interrupts import check_stop
from . import conventions as cv
from . import missions
from .gain import read_gain
from .options import ProductOptions, resolve_model
from .provenance import Provenance

__all__ = ["process_asdf"]

ROMAN_FULL_FRAME = (4096, 4096)


def _exposure_time(meta):
    exposure = meta.get("exposure", {}) if hasattr(meta, "get") else {}
    for key in ("effective_exposure_time", "exposure_time"):
        value = exposure.get(key) if hasattr(exposure, "get") else None
        if value is not None and float(value) > 0:
            return float(value)
    return None


def _units(dm, ramp):
    """DN for ramps; DN/s for level 2 until its flux step has run (then MJy/sr)."""
    if ramp:
        return "DN"
    steps = dm.meta.get("cal_step", {}) if hasattr(dm.meta, "get") else {}
    flux = steps.get("flux") if hasattr(steps, "get") else None
    return "MJy/sr" if flux == "COMPLETE" else "DN/s"


def process_asdf(input_path, output_path, operation="decouple", *, model=None, options=None,
                 **kwargs):
    """Couple or decouple the science array of a Roman ASDF product.

    Parameters are those of :func:`ipc_taichi.products.process_fits`
    (``hdu`` and ``tile`` do not apply and are refused). Returns the same
    summary dict.
    """
    options = ProductOptions.from_kwargs(options, **kwargs)
    try:
        import roman_datamodels.datamodels as rdm
    except ImportError:
        raise IPCInputError(f"{input_path}: Roman ASDF needs roman_datamodels: "
                            "pip install 'ipc_taichi[roman]'") from None
    if options.tile:
        raise IPCInputError(f"{input_path}: --tile is for FITS products")
    if options.hdu is not None:
        raise IPCInputError(f"{input_path}: --hdu is for FITS products")
    model, options = resolve_model(model, options)
    max_iter, tol = iteration.check_arguments(options.max_iter, options.tol)
    check_output_path(output_path, options.overwrite)
    if not os.path.exists(input_path):
        raise IPCInputError(f"{input_path}: no such file")
    if os.path.exists(output_path) and os.path.samefile(input_path, output_path):
        raise IPCInputError(f"{output_path}: is the input; write to another file")
    label = f"{input_path}[data]"
    mission = missions.roman_mission()
    missions.check_model_chosen(mission, options.model_chosen, label)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dm = rdm.open(input_path)
    except Exception as exc:
        raise IPCInputError(f"{input_path}: not a readable Roman datamodel "
                            f"({type(exc).__name__})") from None
    with dm:
        kind = type(dm).__name__
        if kind == "ScienceRawModel":
            raise IPCInputError(f"{label}: raw level-1 resultants (uint16) hold the bias; "
                                "subtract it first (romancal through the refpix step) and "
                                "decouple that RampModel")
        if kind not in ("ImageModel", "RampModel"):
            raise IPCInputError(f"{label}: a {kind}; give a level-2 ImageModel or a RampModel")
        ramp = kind == "RampModel"
        names = ("pixeldq", "groupdq") if ramp else ("dq",)
        try:  # a truncated file fails here, when its blocks are read
            data = np.asarray(dm.data)
            flags = [np.asarray(dm[name]) for name in names if name in dm and dm[name] is not None]
        except Exception as exc:
            raise IPCInputError(f"{input_path}: its arrays cannot be read, the file may be "
                                f"truncated ({type(exc).__name__})") from None
        if data.dtype.kind != "f":
            raise IPCInputError(f"{label}: integer data ({data.dtype}); subtract the bias first")
        units = cv.parse_units(options.bunit if options.bunit is not None
                               else _units(dm, ramp), label,
                               "--bunit" if options.bunit is not None else
                               "units (meta.cal_step.flux)")
        if options.gain is not None and not units.needs_gain:
            raise IPCInputError(f"{label}: a gain was given but the data are in {units.text}; "
                                "give --bunit DN or DN/s if they are not")
        if "ipc_taichi" in dm.meta and dm.meta["ipc_taichi"].get("operation") == "decouple":
            warnings.warn(f"{label}: IPC was already corrected by ipc_taichi; correcting again",
                          cv.ProductWarning, stacklevel=2)
        exptime = options.exptime if options.exptime is not None else _exposure_time(dm.meta)
        scale, units_text = cv.charge_scale(
            units, read_gain(options.gain, data.shape[-2:]), exptime, label,
            time_source="meta.exposure.effective_exposure_time",
            gain_source="a gain reference file (--gain FILE.asdf)",
            coadds=options.coadds or 1)
        bits = cv.parse_dq_bits(options.dq_bits, mission.dq_flags) & ~cv.REFERENCE_PIXEL
        for name, f in zip(names, flags):
            if f.shape != data.shape[data.ndim - f.ndim:]:
                raise IPCInputError(f"{input_path}[{name}]: shape {f.shape} does not match "
                                    f"the data {data.shape}")
        first = flags[0].reshape((-1,) + data.shape[-2:])[0].astype(np.int64) if flags else None
        reference = None if first is None else (first & cv.REFERENCE_PIXEL) != 0
        refpix = options.refpix
        if refpix is None and (reference is None or not reference.any()):
            refpix = 4 if ramp and data.shape[-2:] == ROMAN_FULL_FRAME else None
        try:
            region, inside = cv.science_region(data.shape[-2:], refpix, reference)
        except IPCInputError as exc:
            raise IPCInputError(f"{label}: {exc}") from None
        full_inside = None
        if inside is not None:
            full_inside = np.zeros(data.shape[-2:], dtype=bool)
            full_inside[region] = inside
        mask = cv.untrusted(flags, bits, data.shape, full_inside, values=data,
                            saturation=options.saturation)
        if options.output_dtype not in (None, "same") and \
                np.dtype(options.output_dtype) != data.dtype:
            raise IPCInputError(f"{label}: a Roman product keeps its schema's dtype "
                                f"({data.dtype})")
        inner, edge_reason = cv.choose_edge(model, region, data.shape[-2:], True,
                                            options.edge_chosen)
        if data.shape[-2:] == (4088, 4088) and not options.edge_chosen:
            # a level-2 image is the science area with its 4-pixel reference border
            # stored apart: beyond its edge lie reference pixels, zero-signal neighbours
            inner = type(model)(model.law, model.geometry, "zero")
            edge_reason = "reference border stored apart: zero-signal neighbours"
        out = np.empty(data.shape, dtype=data.dtype)
        record = cv.Unphysical(options.unphysical)
        _, infos = cv.correct_frames(data, operation, inner, mask=mask, region=region,
                                     scale=scale, out=out, max_iter=max_iter, tol=tol,
                                     arch=options.arch, precision=options.precision,
                                     label=label, unphysical=record,
                                     progress=options.progress)
        dm.data = out
        from .. import runtime

        rt = runtime.current()
        prov = Provenance(operation, inner, edge_reason, bits, "none", options.coadds or 1,
                          rt.arch if rt else "", rt.precision if rt else "", tol, max_iter)
        prov.add_hdu(0, "data", label, region, units_text, exptime if units.rate else 0.0,
                     len(infos))
        prov.infos[0] = infos
        prov.unphysical[0] = record.masked
        dm.meta["ipc_taichi"] = prov.record()
        if ramp and operation == "decouple" and "cal_step" in dm.meta:
            dm.meta.cal_step["ipc"] = "COMPLETE" if prov.status() == "COMPLETE" else "FAILED"
        _save(dm, output_path, options.overwrite)
    converged = None if operation == "couple" or tol == 0 else all(i.converged for i in infos)
    return {"output": output_path, "label": label, "frames": len(infos), "infos": infos,
            "hdus": [label],
            "iterations": max(i.iterations for i in infos) if operation == "decouple" else 0,
            "converged": converged, "law": inner.law.name, "edge": inner.edge,
            "masked_unphysical": record.masked}


def _save(dm, output_path, overwrite):
    """Save ``dm`` atomically: into a temporary directory beside the target under
    the target's own name (the datamodel records its file name), then renamed
    into place; the directory is removed on any error, SIGINT or SIGTERM."""
    parent = os.path.dirname(os.path.abspath(output_path))
    try:
        staging = tempfile.TemporaryDirectory(prefix=".tmp-", dir=parent)
    except OSError as exc:  # name the output, not the temporary directory
        raise cannot_write(output_path, exc) from None
    with staging as tmpdir:
        tmp = os.path.join(tmpdir, os.path.basename(output_path))
        try:
            dm.save(tmp)
        except OSError as exc:
            raise IPCInputError(f"{output_path}: cannot be written "
                                f"({exc.strerror or type(exc).__name__})") from None
        check_stop()  # a swallowed SIGINT/SIGTERM: do not commit
        check_output_path(output_path, overwrite)  # it may have appeared meanwhile
        os.replace(tmp, output_path)

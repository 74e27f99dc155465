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

from .. import __version__, iteration
from ..errors import IPCInputError
from ..fitsio import check_output_path
from ..interrupts import check_stop
from ..model import CouplingModel
from . import conventions as cv

__all__ = ["process_asdf", "is_asdf"]

ROMAN_FULL_FRAME = (4096, 4096)


def is_asdf(path):
    """Whether ``path`` names an ASDF file (by its first bytes, else its name)."""
    try:
        with open(path, "rb") as f:
            return f.read(5) == b"#ASDF"
    except OSError:
        return str(path).lower().endswith(".asdf")


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


def process_asdf(input_path, output_path, operation="decouple", *, model=None, overwrite=False,
                 max_iter=iteration.MAX_ITER, tol=iteration.TOL, arch=None, precision=None,
                 dq_bits="DO_NOT_USE", refpix=None, gain=None, exptime=None, bunit=None,
                 output_dtype=None, hdu=None, tile=None, progress=False):
    """Couple or decouple the science array of a Roman ASDF product.

    Parameters are those of :func:`ipc_taichi.products.process_fits`
    (``hdu`` and ``tile`` do not apply and are refused; ``progress`` is
    ignored). Returns the same summary dict.
    """
    try:
        import roman_datamodels.datamodels as rdm
    except ImportError:
        raise IPCInputError(f"{input_path}: Roman ASDF needs roman_datamodels: "
                            "pip install 'ipc_taichi[roman]'") from None
    if tile:
        raise IPCInputError(f"{input_path}: --tile is for FITS products")
    if hdu is not None:
        raise IPCInputError(f"{input_path}: --hdu is for FITS products")
    model = CouplingModel.resolve(model if model is not None else "donlon2018")
    max_iter, tol = iteration.check_arguments(max_iter, tol)
    check_output_path(output_path, overwrite)
    if not os.path.exists(input_path):
        raise IPCInputError(f"{input_path}: no such file")
    if os.path.exists(output_path) and os.path.samefile(input_path, output_path):
        raise IPCInputError(f"{output_path}: is the input; write to another file")
    try:
        dm = rdm.open(input_path)
    except Exception as exc:
        raise IPCInputError(f"{input_path}: not a readable Roman datamodel "
                            f"({type(exc).__name__})") from None
    with dm:
        kind = type(dm).__name__
        label = f"{input_path}[data]"
        if kind == "ScienceRawModel":
            raise IPCInputError(f"{label}: raw level-1 resultants (uint16) hold the bias; "
                                "subtract it first (romancal through the refpix step) and "
                                "decouple that RampModel")
        if kind not in ("ImageModel", "RampModel"):
            raise IPCInputError(f"{label}: a {kind}; give a level-2 ImageModel or a RampModel")
        data = np.asarray(dm.data)
        if data.dtype.kind != "f":
            raise IPCInputError(f"{label}: integer data ({data.dtype}); subtract the bias first")
        ramp = kind == "RampModel"
        units = cv.parse_units(bunit if bunit is not None else _units(dm, ramp), label)
        if gain is not None and not units.needs_gain:
            raise IPCInputError(f"{label}: a gain was given but the data are in {units.text}; "
                                "give --bunit DN or DN/s if they are not")
        if "ipc_taichi" in dm.meta and dm.meta["ipc_taichi"].get("operation") == "decouple":
            warnings.warn(f"{label}: IPC was already corrected by ipc_taichi; correcting again",
                          cv.ProductWarning, stacklevel=2)
        scale, units_text = cv.charge_scale(
            units, _gain(gain, data.shape[-2:]),
            exptime if exptime is not None else _exposure_time(dm.meta), label)
        bits = cv.parse_dq_bits(dq_bits, mission="roman") & ~cv.REFERENCE_PIXEL
        flags = [np.asarray(dm[name]) for name in (("pixeldq", "groupdq") if ramp else ("dq",))
                 if name in dm and dm[name] is not None]
        for name, f in zip(("pixeldq", "groupdq") if ramp else ("dq",), flags):
            if f.shape != data.shape[data.ndim - f.ndim:]:
                raise IPCInputError(f"{input_path}[{name}]: shape {f.shape} does not match "
                                    f"the data {data.shape}")
        first = flags[0].reshape((-1,) + data.shape[-2:])[0].astype(np.int64) if flags else None
        reference = None if first is None else (first & cv.REFERENCE_PIXEL) != 0
        if refpix is None and (reference is None or not reference.any()):
            refpix = 4 if ramp and data.shape[-2:] == ROMAN_FULL_FRAME else None
        try:
            region, inside = cv.science_region(data.shape[-2:], refpix, reference)
        except IPCInputError as exc:
            raise IPCInputError(f"{label}: {exc}") from None
        mask = None
        if bits or inside is not None:
            mask = np.zeros(data.shape, dtype=bool)
            for f in flags if bits else ():
                mask |= (f.astype(np.int64) & bits) != 0
            if inside is not None:
                mask[(Ellipsis,) + region] |= inside
        if output_dtype not in (None, "same") and np.dtype(output_dtype) != data.dtype:
            raise IPCInputError(f"{label}: a Roman product keeps its schema's dtype "
                                f"({data.dtype})")
        out_dtype = data.dtype
        out = np.empty(data.shape, dtype=out_dtype)
        _, infos = cv.correct_frames(data, operation, model, mask=mask, region=region,
                                     scale=scale, out=out, max_iter=max_iter, tol=tol,
                                     arch=arch, precision=precision, label=label)
        dm.data = out
        from .. import runtime

        rt = runtime.current()
        record = {"version": __version__, "operation": operation,
                  "law": model.law.name, "model": model.describe(), "units": units_text,
                  "dq_bits": int(bits),
                  "science_region": [[region[0].start, region[0].stop],
                                     [region[1].start, region[1].stop]],
                  "arch": rt.arch if rt else "", "precision": rt.precision if rt else ""}
        if operation == "decouple":
            record.update(S_IPC="COMPLETE", iterations=[int(i.iterations) for i in infos],
                          converged=bool(all(i.converged for i in infos)), tol=float(tol),
                          max_iter=int(max_iter))
        dm.meta["ipc_taichi"] = record
        if ramp and operation == "decouple" and "cal_step" in dm.meta:
            dm.meta.cal_step["ipc"] = "COMPLETE"
        _save(dm, output_path, overwrite)
    converged = None if operation == "couple" or tol == 0 else all(i.converged for i in infos)
    return {"output": output_path, "label": label, "frames": len(infos), "infos": infos,
            "iterations": max(i.iterations for i in infos) if operation == "decouple" else 0,
            "converged": converged}


def _save(dm, output_path, overwrite):
    """Save ``dm`` atomically: into a temporary directory beside the target under
    the target's own name (the datamodel records its file name), then renamed
    into place; the directory is removed on any error, SIGINT or SIGTERM."""
    parent = os.path.dirname(os.path.abspath(output_path))
    with tempfile.TemporaryDirectory(prefix=".tmp-", dir=parent) as tmpdir:
        tmp = os.path.join(tmpdir, os.path.basename(output_path))
        dm.save(tmp)
        check_stop()  # a swallowed SIGINT/SIGTERM: do not commit
        check_output_path(output_path, overwrite)  # it may have appeared meanwhile
        os.replace(tmp, output_path)


def _gain(gain, shape2d):
    """``--gain`` as a number, or a per-pixel gain image from a FITS or ASDF file."""
    if gain is None or isinstance(gain, (int, float, np.floating, np.integer, np.ndarray)):
        return gain
    try:
        return float(gain)
    except ValueError:
        pass
    if is_asdf(gain):
        import roman_datamodels.datamodels as rdm

        with rdm.open(gain) as ref:
            image = np.asarray(ref.data, dtype=np.float64)
        if image.shape == ROMAN_FULL_FRAME and shape2d == (4088, 4088):
            image = image[4:-4, 4:-4]  # a full-frame gain file for a level-2 image
        if image.shape != shape2d:
            raise IPCInputError(f"{gain}: gain image {image.shape} does not match the data "
                                f"{shape2d}")
        return image
    from .fits import _read_gain

    return _read_gain(gain, shape2d)

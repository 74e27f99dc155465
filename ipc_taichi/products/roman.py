"""Roman ASDF products in, the same products out (``pip install ipc_taichi[roman]``).

Read and written through ``roman_datamodels``, so the whole tree (metadata,
border reference pixels, ``amp33``, WCS) is carried through; only the science
array changes, in its own dtype, and, when decoupling, ``err``,
``var_poisson``, ``var_rnoise`` and ``var_flat`` (propagated through the
linearised decoupler, :func:`ipc_taichi.products.noise_arrays.noise_of`; the record's
``noise`` says how). The rules are
those of :mod:`ipc_taichi.products.conventions`:

- level 2 (``ImageModel``): ``data`` in DN/s (the trimmed 4088x4088 science
  area; the border reference pixels are stored apart and untouched), ``dq``;
  after the flux step (``meta.cal_step.flux == "COMPLETE"``) the data are
  MJy/sr and refused;
  the rate is converted with the gain and the integration time
  (``meta.exposure.effective_exposure_time``, else ``exposure_time``);
- ramps (``RampModel``, resultants in DN after bias and reference-pixel
  correction): resultant by resultant, ``pixeldq`` and ``groupdq`` honoured,
  a 4-pixel reference border in a 4096x4096 frame unless flagged otherwise
  (Roman's conventions: :data:`ipc_taichi.products.missions.ROMAN`);
- raw level-1 resultants (``ScienceRawModel``, uint16 with the bias in them)
  are refused: the law needs collected charge, so subtract the bias first.

The output records ``meta.ipc_taichi`` (what was done, ``S_IPC = COMPLETE``)
and, for ramps, ``meta.cal_step.ipc = "COMPLETE"``.
"""

import os
import tempfile
import warnings

import numpy as np

from .. import runtime
from ..errors import IPCInputError
from ..fitsio import cannot_write, check_output_path, say_stale
from ..interrupts import check_stop
from . import conventions as cv
from . import missions
from .checks import check_input_file
from .correction import RunSettings, correct_frames
from .noise_arrays import held, noise_of
from .options import ProductOptions, resolve_model
from .plan import ArrayFacts, plan_product
from .provenance import Provenance

__all__ = ["process_asdf"]

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
    settings = RunSettings.of(options, operation)
    check_output_path(output_path, options.overwrite)
    check_input_file(input_path)
    if not str(output_path).lower().endswith(".asdf"):  # found before the work, not after
        raise IPCInputError(f"{output_path}: a Roman ASDF product is written as ASDF; name the "
                            "output .asdf")
    if os.path.exists(output_path) and os.path.samefile(input_path, output_path):
        raise IPCInputError(f"{output_path}: is the input; write to another file")
    label = f"{input_path}[data]"
    mission = missions.roman_mission()
    missions.check_model_chosen(mission, options.model_chosen, label)  # before reading
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dm = rdm.open(input_path)
    except Exception as exc:
        raise IPCInputError(f"{input_path}: not a readable Roman datamodel "
                            f"({type(exc).__name__})") from None
    with dm:
        kind, ramp, data, flags = _arrays(dm, input_path, label)
        if "ipc_taichi" in dm.meta and dm.meta["ipc_taichi"].get("operation") == "decouple":
            warnings.warn(f"{label}: IPC was already corrected by ipc_taichi; correcting again",
                          cv.ProductWarning, stacklevel=2)
        if options.output_dtype not in (None, "same") and \
                np.dtype(options.output_dtype) != data.dtype:
            raise IPCInputError(f"{label}: a Roman product keeps its schema's dtype "
                                f"({data.dtype})")
        plan = plan_product([_facts(dm, kind, label, data.shape, flags)], mission, model,
                            options)
        p, = plan.arrays
        mask = cv.untrusted(flags, plan.bits, data.shape, p.science_region.inside_mask(),
                            values=data, saturation=options.saturation)
        came = held(lambda name: dm[name] if name in dm else None, data.shape)
        propagate, noise_text = noise_of(operation, options, list(came),
                                         f"{input_path}[{next(iter(came), '')}]")
        noise = {k: np.array(v, dtype=np.float64) for k, v in came.items()} \
            if propagate else {}
        out = np.empty(data.shape, dtype=data.dtype)
        record = cv.Unphysical(settings.unphysical)
        _, infos = correct_frames(data, p, settings, mask=mask, out=out, noise=noise,
                                  record=record)
        dm.data = out
        for name, value in noise.items():  # propagated, each in its own dtype
            dm[name] = value.astype(came[name].dtype)
        prov = Provenance(plan, settings, runtime.current(), noise_text)
        prov.infos[p.index] = infos
        prov.unphysical[p.index] = record.masked
        dm.meta["ipc_taichi"] = prov.record()
        if ramp and operation == "decouple" and "cal_step" in dm.meta:
            dm.meta.cal_step["ipc"] = "COMPLETE" if prov.status() == "COMPLETE" else "FAILED"
        _save(dm, output_path, options.overwrite)
    return prov.summary(output_path)


def _arrays(dm, input_path, label):
    """The product's kind, whether a ramp, its ``data`` and
    the DQ arrays present; raw, unknown and integer products refused."""
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
    for name, f in zip(names, flags):
        if f.shape != data.shape[data.ndim - f.ndim:]:
            raise IPCInputError(f"{input_path}[{name}]: shape {f.shape} does not match "
                                f"the data {data.shape}")
    return kind, ramp, data, flags


def _facts(dm, kind, label, shape, flags):
    """What a Roman datamodel says about its ``data``
    (:class:`~ipc_taichi.products.plan.ArrayFacts`): units and times by
    :func:`~ipc_taichi.products.missions.roman_keywords`, the
    ``REFERENCE_PIXEL`` flags of its first DQ array's first frame."""
    def reference():
        if not flags:
            return None
        first = flags[0].reshape((-1,) + shape[-2:])[0].astype(np.int64)
        return (first & cv.REFERENCE_PIXEL) != 0

    keys = missions.roman_keywords(kind, dm.meta)
    return ArrayFacts(0, "data", label, shape, keys, keys, reference)


def _save(dm, output_path, overwrite):
    """Save ``dm`` atomically: into a temporary directory beside the target under
    the target's own name (the datamodel records its file name), then renamed
    into place; the directory is removed on any error, SIGINT or SIGTERM."""
    parent = os.path.dirname(os.path.abspath(output_path))
    say_stale(output_path)
    try:
        staging = tempfile.TemporaryDirectory(prefix=".tmp-", dir=parent)
    except OSError as exc:  # name the output, not the temporary directory
        raise cannot_write(output_path, exc) from None
    with staging as tmpdir:
        tmp = os.path.join(tmpdir, os.path.basename(output_path))
        try:
            dm.save(tmp)
        except (OSError, ValueError) as exc:
            why = getattr(exc, "strerror", None) or (str(exc).splitlines() or [""])[0]
            raise IPCInputError(f"{output_path}: cannot be written "
                                f"({why or type(exc).__name__})") from None
        check_stop()  # a swallowed SIGINT/SIGTERM: do not commit
        check_output_path(output_path, overwrite)  # it may have appeared meanwhile
        os.replace(tmp, output_path)

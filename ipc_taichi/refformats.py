"""The IPC reference files pipelines hold: read into a coupling model, written from one.

Formats
-------
``jwst`` -- JWST CRDS ``ipc`` reference (FITS, ``REFTYPE = 'IPC'``)
    ``SCI``: a 2-D kernel, or a 4-D kernel per pixel ``(ky, kx, ny, nx)``, that
    the pipeline's ``ipc`` step *convolves each group with to remove IPC*
    (an inverse kernel, centre above 1). jwst 3.0.0 ``ipc_corr.ipc_convolve``
    was read for the 4-D case: the kernel axes come first, ``y`` before ``x``;
    the kernel is indexed at the **destination** pixel and applied as a
    convolution (``out[q] = sum_d k[c+d, q] in[q - d]``); the array covers
    the whole detector (reference pixels included), a subarray reads its slice
    at ``SUBSTRT``; the frame's reference pixels are neither corrected nor
    used (a zero border). :mod:`ipc_taichi.refkernels` converts the rows to
    forward kernels by its one rule (each pixel's kernel inverted as if it held
    everywhere). Written: 2-D for a uniform model, 4-D for a model with a map,
    ``float32``, with ``TELESCOP``, ``REFTYPE``, ``DATAMODL = 'IPCModel'``,
    ``INSTRUME``, ``DETECTOR``, ``PEDIGREE``, ``USEAFTER``, ``AUTHOR``,
    ``DESCRIP``, so that ``stdatamodels``' ``IPCModel`` opens it and the
    pipeline's ``--override_ipc`` uses it.
``roman`` -- Roman ``IPC`` reference (ASDF, ``roman.meta.reftype == 'IPC'``)
    ``roman.data``: one 3x3 forward kernel (the fraction each neighbour
    receives). A model with a map is written as its typical kernel (the map's
    median is 1); the map itself only in the kept model (below).
``ipc4d`` -- romanimpreprocess IPC4D (ASDF)
    ``roman.data`` of shape ``(3, 3, ny, nx)`` (4088 x 4088: the science
    pixels), forward, indexed at the **source** pixel
    (``utils/ipc_linearity.ipc_fwd``: ``out[y,x] = sum_d in[y-dy,x-dx]
    K[1+dy,1+dx,y-dy,x-dx]``), and ``roman.dq``. Its test fixture writes no
    ``meta``: a 4-D ``(3, 3, ...)`` ``roman.data`` is read as IPC4D; written
    with ``roman.meta.reftype = 'IPC4D'`` (romanimpreprocess reads only
    ``data``).

Reading (:func:`read_model`): 2-D kernels give a constant law with geometry
(no map); 4-D kernels the model of :func:`ipc_taichi.refkernels.model_from_kernels`
(a constant law, the geometry of the mean kernel, the map normalised to median
1; identical kernels everywhere: no map). The map is for the frame the kernels
cover (JWST: the whole detector; IPC4D: its science pixels).

The model kept in the file
--------------------------
The writer keeps the model's file content (:meth:`CouplingModel.to_dict`,
with the signal it was written at) beside the kernels -- FITS: an
``IPCMODEL`` extension (the JSON text as bytes) and, for a full-resolution
map, ``IPCBONDS`` (float64); ASDF: ``ipc_taichi.model`` and
``ipc_taichi.bond_values`` -- and :func:`read_model` returns it unchanged
(the law with its signal dependence, the map bit for bit) unless
``kept=False``. Pipelines ignore both.
"""

import datetime
import json
import os

import numpy as np

from . import __version__
from .bondmap import BondMap
from .errors import IPCInputError
from .fitsio import atomic_output
from .model import CouplingModel
from .products.fitsfile import open_fits
from .products.missions import is_asdf
from .refkernels import (
    DEFAULT_SIGNAL,
    invert_kernels,
    is_uniform,
    law_from_forward_kernel,
    model_from_kernels,
    rows_from_scatter,
    scatter_from_rows,
    scatter_kernels,
)

__all__ = ["FORMATS", "IPC4D_SHAPE", "read_model", "write_reference"]

FORMATS = ("jwst", "roman", "ipc4d")
IPC4D_SHAPE = (4088, 4088)
"""The frame of an IPC4D file written from a uniform model (Roman's science pixels)."""

MODEL_EXT, BONDS_EXT, ASDF_KEY = "IPCMODEL", "IPCBONDS", "ipc_taichi"


def read_model(path, law=None, kept=True):
    """``(model, info)`` of a JWST (FITS) or Roman / IPC4D (ASDF) IPC reference file.

    Parameters
    ----------
    path : str
    law : law, optional
        Replaces the constant read from a 4-D file's kernels (the map is kept).
    kept : bool
        Return the model kept in the file when there is one (default).

    Raises
    ------
    IPCInputError
        One line naming the file: unreadable, or not an IPC reference of a known kind.
    """
    path = os.fspath(path)
    reader = _read_asdf if is_asdf(path) else _read_fits
    return reader(path, law, kept)


def _refused(path, found):
    return IPCInputError(f"{path}: not an IPC reference file of a known kind ({found}); "
                         "expected the JWST 'ipc' reference (FITS), Roman's IPC reference or "
                         "a romanimpreprocess IPC4D file (ASDF)")


def _read_fits(path, law, kept):
    hdul = open_fits(path, memmap=False)
    with hdul:
        primary = hdul[0].header
        reftype = str(primary.get("REFTYPE", "")).strip().upper()
        telescope = str(primary.get("TELESCOP", "")).strip().upper()
        if reftype != "IPC" or telescope not in ("JWST", ""):
            raise _refused(path, f"REFTYPE={primary.get('REFTYPE')!r}, "
                                 f"TELESCOP={primary.get('TELESCOP')!r}")
        hdu = hdul["SCI"] if "SCI" in hdul else hdul[0]
        if hdu.data is None:
            raise IPCInputError(f"{path}[SCI]: no kernel")
        kernel = np.asarray(hdu.data, dtype=np.float64)
        doc = _kept_json(hdul, path) if kept and MODEL_EXT in hdul else None
        values = (np.asarray(hdul[BONDS_EXT].data, dtype=np.float64)
                  if doc is not None and BONDS_EXT in hdul else None)
    if doc is not None:
        return _kept_model(doc, values, f"{path}[{MODEL_EXT}]"), {
            "kind": "jwst_ipc (the model kept in the file)", "signal": doc.get("signal_e")}
    if kernel.ndim == 2:
        forward = invert_kernels(kernel)
        c = kernel.shape[0] // 2
        base, geometry = law_from_forward_kernel(forward, path)
        return CouplingModel.resolve(law or base, geometry, "zero"), {
            "kind": "jwst_ipc (inverse kernel, inverted here)", "file_kernel": kernel.tolist(),
            "forward_kernel": forward.tolist(), "centre": float(kernel[c, c])}
    _check_4d(kernel, f"{path}[SCI]")
    if is_uniform(kernel):
        model, info = _read_uniform(invert_kernels(kernel[:, :, 0, 0]), path, law)
        return model, {"kind": "jwst_ipc 4-D, the same kernel at every pixel (no map)", **info}
    rows = invert_kernels(kernel)  # per pixel, as the pipeline applies them
    model, info = model_from_kernels(scatter_from_rows(rows), path, "zero", law)
    return model, {"kind": "jwst_ipc 4-D (inverse kernels per destination pixel, each "
                           "inverted here)", "shape": list(kernel.shape), **info}


def _kept_json(hdul, path):
    """The kept model's document in a FITS file's ``IPCMODEL`` extension."""
    try:
        return json.loads(bytes(np.asarray(hdul[MODEL_EXT].data, dtype=np.uint8)).decode())
    except (ValueError, TypeError) as exc:
        raise IPCInputError(f"{path}[{MODEL_EXT}]: not the JSON of a coupling model "
                            f"({type(exc).__name__})") from None


def _check_4d(kernel, label):
    ky, kx = kernel.shape[:2]
    if kernel.ndim != 4 or ky != kx or ky not in (3, 5):
        raise IPCInputError(f"{label}: a per-pixel IPC kernel must be (3|5, 3|5, ny, nx), "
                            f"got shape {kernel.shape}")


def _read_uniform(forward, path, law):
    base, geometry = law_from_forward_kernel(forward, path)
    return CouplingModel.resolve(law or base, geometry, "zero"), {
        "forward_kernel": np.asarray(forward).tolist(), "map": None}


def _read_asdf(path, law, kept):
    try:
        import asdf
    except ImportError:
        raise IPCInputError(f"{path}: reading ASDF needs the asdf package") from None
    try:
        af = asdf.open(path, lazy_load=False, memmap=False)
    except Exception as exc:
        raise IPCInputError(f"{path}: cannot read as ASDF ({type(exc).__name__})") from None
    with af:
        roman = af.tree.get("roman", {})
        meta = roman.get("meta", {}) if hasattr(roman, "get") else {}
        reftype = str(meta.get("reftype", "")).strip().upper() if hasattr(meta, "get") else ""
        data = (np.asarray(roman["data"], dtype=np.float64)
                if hasattr(roman, "get") and "data" in roman else None)
        ours = af.tree.get(ASDF_KEY) if kept else None
        doc = dict(ours["model"]) if ours is not None and "model" in ours else None
        values = (np.asarray(ours["bond_values"], dtype=np.float64)
                  if doc is not None and "bond_values" in ours else None)
    four_d = data is not None and data.ndim == 4 and data.shape[:2] == (3, 3)
    if data is None or not (four_d and reftype in ("", "IPC", "IPC4D")
                            or data.ndim == 2 and reftype == "IPC"):
        raise _refused(path, f"reftype={reftype or None!r}, data shape "
                             f"{None if data is None else data.shape}")
    if doc is not None:
        return _kept_model(_plain(doc), values, f"{path}[{ASDF_KEY}]"), {
            "kind": f"{'ipc4d' if four_d else 'roman_ipc'} (the model kept in the file)",
            "signal": doc.get("signal_e")}
    if not four_d:
        c = data.shape[0] // 2
        model, info = _read_uniform(data, path, law)
        return model, {"kind": "roman_ipc (forward kernel)", "centre": float(data[c, c]), **info}
    if is_uniform(data):
        model, info = _read_uniform(data[:, :, 0, 0], path, law)
        return model, {"kind": "ipc4d, the same kernel at every pixel (no map)", **info}
    model, info = model_from_kernels(data, path, "zero", law)
    return model, {"kind": "ipc4d (forward kernels per source pixel)",
                   "shape": list(data.shape), **info}


def _plain(value):
    """An ASDF tree's mappings and lists as plain dicts and lists (for JSON)."""
    if hasattr(value, "items"):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value.item() if isinstance(value, np.generic) else value


def _kept_model(doc, values, label):
    """The model kept in a file: its document and, for a full-resolution map,
    the values stored beside it."""
    doc = dict(doc)
    doc.pop("signal_e", None)
    section = doc.get("bond_map")
    if section is None or "coarse" in section:
        return CouplingModel.from_dict(doc, source=label)
    if values is None:
        raise IPCInputError(f"{label}: the kept model names a bond map the file does not hold")
    doc.pop("bond_map")
    model = CouplingModel.from_dict(doc, source=label)
    offsets = tuple((int(dy), int(dx)) for dy, dx in section["offsets"])
    bonds = BondMap(offsets, values)
    if tuple(bonds.shape) != tuple(int(n) for n in section["shape"]):
        raise IPCInputError(f"{label}: the bond map's shape {bonds.shape} is not the "
                            f"{tuple(section['shape'])} the model states")
    return CouplingModel.resolve(model.law, model.geometry, model.edge, bonds=bonds)


def _kept_document(model, fmt, signal):
    """The model's file content kept in a written reference (module docstring)."""
    full = model.bonds is not None and model.bonds.coarse is None
    doc = model.to_dict(provenance={"software": f"ipc_taichi {__version__}",
                                    "command": "export-reference", "format": fmt},
                        map_file=BONDS_EXT if full else None)
    doc["signal_e"] = float(signal)
    return doc, (model.bonds.values if full else None)


def write_reference(model, path, fmt, signal=DEFAULT_SIGNAL, overwrite=False, shape=None,
                    instrument="NIRISS", detector="NIS", pedigree="GROUND"):
    """Write ``model`` as a reference file of format ``fmt`` (:data:`FORMATS`),
    atomically, with the model kept in it (module docstring).

    Parameters
    ----------
    model : CouplingModel
    signal : float
        Electrons: a signal-dependent law is written as its kernel at this
        level (``alpha(S, S)``, :mod:`ipc_taichi.refkernels`).
    shape : (ny, nx), optional
        An IPC4D file's frame for a uniform model (default :data:`IPC4D_SHAPE`).
    instrument, detector, pedigree : str
        The JWST file's ``INSTRUME``, ``DETECTOR``, ``PEDIGREE``.

    Returns
    -------
    dict
        What was written: ``format``, ``kernel_shape``, ``signal_e``, ``alpha``.
    """
    if fmt not in FORMATS:
        raise IPCInputError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    if not np.isfinite(signal) or signal < 0:
        raise IPCInputError(f"--signal must be a non-negative number of electrons, got {signal}")
    path = os.fspath(path)
    doc, values = _kept_document(model, fmt, signal)
    alpha = float(model.law.alpha(float(signal), float(signal)))
    r = max(model.geometry.reach, 1)
    if fmt == "jwst":
        if model.bonds is None:
            data = invert_kernels(model.geometry.kernel(alpha))
        else:
            data = invert_kernels(rows_from_scatter(scatter_kernels(model, signal, pad=r)))
        _write_fits(path, data.astype(np.float32), doc, values, overwrite,
                    {"INSTRUME": instrument, "DETECTOR": detector, "PEDIGREE": pedigree})
    else:
        if fmt == "roman":
            data = model.geometry.kernel(alpha)
        else:
            if model.geometry.reach > 1:
                raise IPCInputError("an IPC4D file holds 3x3 kernels; this model's geometry "
                                    f"reaches {model.geometry.reach} pixels")
            if model.bonds is not None and shape is not None and \
                    tuple(shape) != tuple(model.bonds.shape):
                raise IPCInputError(f"--shape {shape[0]} {shape[1]}: the model's map is "
                                    f"{model.bonds.shape[0]}x{model.bonds.shape[1]}")
            data = scatter_kernels(model, signal, shape or IPC4D_SHAPE)
        _write_asdf(path, data.astype(np.float32), doc, values, overwrite, fmt)
    return {"format": fmt, "kernel_shape": list(data.shape), "signal_e": float(signal),
            "alpha": alpha}


def _provenance_text(doc):
    return (f"IPC of an ipc_taichi coupling model ({doc['law'].get('name')}) written at "
            f"S = {doc['signal_e']:g} e-")


def _write_fits(path, data, doc, values, overwrite, keys):
    from astropy.io import fits

    primary = fits.PrimaryHDU()
    h = primary.header
    h["TELESCOP"] = "JWST"
    h["REFTYPE"] = ("IPC", "reference file type")
    h["DATAMODL"] = "IPCModel"
    for key, value in keys.items():
        h[key] = value
    h["USEAFTER"] = "2000-01-01T00:00:00"
    h["AUTHOR"] = f"ipc_taichi {__version__}"
    h["DESCRIP"] = _provenance_text(doc)[:68]
    h["DATE"] = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    h["IPCSIGNL"] = (doc["signal_e"], "[electron] signal the kernels are written at")
    h["HISTORY"] = ("SCI: inverse IPC kernels as jwst ipc_corr applies them (per destination "
                    "pixel, convolution); IPCMODEL: the ipc_taichi model (JSON)")
    hdus = [primary, fits.ImageHDU(data, name="SCI"),
            fits.ImageHDU(np.frombuffer(json.dumps(doc).encode(), dtype=np.uint8),
                          name=MODEL_EXT)]
    if values is not None:
        hdus.append(fits.ImageHDU(np.asarray(values, dtype=np.float64), name=BONDS_EXT))
    with atomic_output(path, overwrite) as tmp:
        fits.HDUList(hdus).writeto(tmp)


def _write_asdf(path, data, doc, values, overwrite, fmt):
    try:
        import asdf
    except ImportError:
        raise IPCInputError(f"{path}: writing ASDF needs the asdf package") from None
    meta = {"reftype": "IPC" if fmt == "roman" else "IPC4D", "telescope": "ROMAN",
            "author": f"ipc_taichi {__version__}", "description": _provenance_text(doc),
            "signal_e": doc["signal_e"]}
    roman = {"meta": meta, "data": data}
    if fmt == "ipc4d":
        roman["dq"] = np.zeros(data.shape[2:], dtype=np.uint32)
    ours = {"model": doc, **({} if values is None else {"bond_values": np.asarray(values)})}
    with atomic_output(path, overwrite) as tmp:
        asdf.AsdfFile({"roman": roman, ASDF_KEY: ours}).write_to(tmp)

"""FITS products in, the same products out.

:func:`process_fits` couples or decouples the science array of a FITS
product and changes nothing else:

- every other HDU is copied byte for byte (ERR, DQ, VAR_*, the ASDF
  extension, tables), so nothing is lost and nothing is rescaled;
- every header keyword is kept; the science HDU keeps its dtype (float32
  stays float32; integer data become float64 unless ``output_dtype`` says
  otherwise), its scaling keywords (BZERO/BSCALE/BLANK) are dropped since the
  result is stored unscaled, and CHECKSUM/DATASUM of the changed headers are
  dropped since they no longer hold;
- the primary header records what was done: ``IPC*`` keywords and HISTORY
  lines, and for decouple ``S_IPC = 'COMPLETE'`` (the JWST pipeline's
  step-status keyword);
- the output is written at a temporary path beside the target and renamed
  into place when complete; an error, SIGINT or SIGTERM removes it.

Which pixels take part and in which units follows
:mod:`ipc_taichi.products.conventions`. With ``tile`` the science array is
read and written tile by tile through memory maps (frames larger than memory,
including scaled integer storage such as uint16 with BZERO); the result is the
same as the whole-frame one (see :mod:`ipc_taichi.tiling`).

ERR and VAR_* arrays are passed through unchanged, as the JWST ``ipc`` step
does: the correction moves about alpha (under 1 %) of each pixel's charge
between neighbours, so its effect on the variances is a redistribution of
that size, below the accuracy they are used with; propagating it properly
would need the pixel covariance, which the products do not carry.
"""

import datetime
import gzip
import os
import warnings

import numpy as np

from .. import __version__, iteration
from ..errors import IPCInputError
from ..fitsio import atomic_output, check_output_path, parse_hdu
from ..interrupts import check_stop
from ..model import CouplingModel
from . import conventions as cv

__all__ = ["process_fits", "written_by_ipc_taichi", "BIT_FLAG_HDUS"]

BIT_FLAG_HDUS = ("DQ", "PIXELDQ", "GROUPDQ")
"""HDUs of bit flags: they say which pixels to trust and are never data."""

_DROP_CHANGED = ("BZERO", "BSCALE", "BLANK", "CHECKSUM", "DATASUM")
_BITPIX = {np.dtype(np.float32): -32, np.dtype(np.float64): -64}


def written_by_ipc_taichi(path):
    """Whether ``path`` is a product this tool wrote: a FITS file whose primary
    header has ``IPCOP``, or an ASDF file with ``meta.ipc_taichi``."""
    from astropy.io import fits

    from .roman import is_asdf

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if is_asdf(path):
                import asdf

                with asdf.open(path, lazy_load=True, memmap=False) as af:
                    meta = af.tree.get("roman", {}).get("meta", {})
                    return "ipc_taichi" in meta
            return "IPCOP" in fits.getheader(path, 0)
    except Exception:
        return False


def _now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _open(path, memmap=True):
    from astropy.io import fits

    if not os.path.exists(path):
        raise IPCInputError(f"{path}: no such file")
    try:
        hdul = fits.open(path, memmap=memmap, lazy_load_hdus=False)
    except Exception as exc:
        text = str(exc).splitlines()[0] if str(exc) else ""
        raise IPCInputError(f"{path}: not a readable FITS file ({type(exc).__name__}"
                            f"{': ' + text if text else ''})") from None
    return hdul


def _hdu_label(hdul, index):
    """``SCI`` (the EXTNAME, with its EXTVER when not 1) or the index."""
    h = hdul[index]
    name = h.header.get("EXTNAME") if index else None
    if not name:
        return str(index)
    ver = h.header.get("EXTVER", 1)
    return f"{name},{ver}" if ver != 1 else str(name)


def _find_science(path, hdul, hdu):
    """Index of the science HDU: ``hdu`` if given, else SCI, else the first
    image HDU with data. Refuses tables, empty HDUs and bit-flag HDUs."""
    if hdu is None:
        names = [h.name for h in hdul]
        if "SCI" in names:
            index = names.index("SCI")
        else:
            index = next((k for k, h in enumerate(hdul)
                          if h.is_image and h.header.get("NAXIS", 0) > 0), None)
            if index is None:
                raise IPCInputError(f"{path}: no HDU holds image data")
    else:
        try:
            index = hdul.index_of(hdu)
            if not 0 <= index < len(hdul):
                raise IndexError(index)
        except Exception:
            listing = ", ".join(str(x.name) or "?" for x in hdul)
            where = f"[{hdu[0]},{hdu[1]}]" if isinstance(hdu, tuple) else f"[{hdu}]"
            raise IPCInputError(f"{path}{where}: no such HDU (file has {len(hdul)}: "
                                f"{listing})") from None
    h = hdul[index]
    label = f"{path}[{_hdu_label(hdul, index)}]"
    if not h.is_image:
        raise IPCInputError(f"{label}: is a {type(h).__name__}, not an image")
    naxis = h.header.get("NAXIS", 0)
    if naxis == 0:
        raise IPCInputError(f"{label}: HDU has no data")
    name = (h.name or "").upper()
    if name in BIT_FLAG_HDUS or name.endswith("DQ") or (
            h.header["BITPIX"] > 0 and name in ("MASK", "FLAGS", "BPM", "BADPIX")):
        raise IPCInputError(f"{label}: holds data-quality bit flags, not data; give the "
                            "science HDU (e.g. --hdu SCI)")
    if naxis not in (2, 3, 4):
        raise IPCInputError(f"{label}: expected a 2-D image, a 3-D stack or a 4-D ramp, got "
                            f"{naxis} axes")
    if naxis == 4 and h.header["BITPIX"] > 0:
        raise IPCInputError(f"{label}: an integer 4-D ramp is raw (_uncal) data with the bias "
                            "in it; subtract the bias first (calwebb_detector1 through the "
                            "superbias step) and decouple that ramp")
    return index, label


def _warn_if_corrected(hdul, label):
    """A product whose IPC was already corrected (S_IPC = 'COMPLETE', e.g. by
    the JWST ``ipc`` step or by this tool) would be corrected twice."""
    primary = hdul[0].header
    if str(primary.get("S_IPC", "")).strip().upper() == "COMPLETE":
        by = "by ipc_taichi" if "IPCOP" in primary else \
            "(S_IPC = 'COMPLETE', e.g. by the JWST ipc step)"
        warnings.warn(f"{label}: IPC was already corrected {by}; correcting again",
                      cv.ProductWarning, stacklevel=3)


def _shape(header):
    return tuple(int(header[f"NAXIS{k}"]) for k in range(header["NAXIS"], 0, -1))


def _keyword(hdul, index, key):
    """``key`` from the science header, else the primary header, else None."""
    for h in (hdul[index].header, hdul[0].header):
        if key in h and h[key] not in (None, ""):
            return h[key]
    return None


class _RawImage:
    """Windows of an image HDU read through a memory map of the file, scaled
    by BZERO/BSCALE (astropy refuses memory-mapped sections of scaled data)."""

    def __init__(self, path, hdul, index):
        header = hdul[index].header
        info = hdul.fileinfo(index)
        bitpix = header["BITPIX"]
        dtype = {8: "u1", 16: ">i2", 32: ">i4", 64: ">i8", -32: ">f4", -64: ">f8"}[bitpix]
        self.shape = _shape(header)
        self.integer = bitpix > 0
        self.zero = header.get("BZERO", 0)
        self.scale = header.get("BSCALE", 1)
        self.blank = header.get("BLANK") if self.integer else None
        with open(path, "rb") as f:
            if f.read(2) == b"\x1f\x8b":
                raise IPCInputError(f"{path}: --tile needs an uncompressed file (gunzip it)")
        self.raw = np.memmap(path, dtype=dtype, mode="r", offset=info["datLoc"],
                             shape=self.shape)

    def __getitem__(self, key):
        raw = np.asarray(self.raw[key])
        if self.integer:
            if self.scale == 1 and float(self.zero).is_integer() and self.blank is None:
                return raw.astype(np.int64) + int(self.zero)
            out = self.zero + self.scale * raw.astype(np.float64)
            if self.blank is not None:
                out[raw == self.blank] = np.nan
            return out
        return raw.astype(np.float64)


def _dq_arrays(hdul, index, shape, path):
    """The companion bit-flag HDUs of the science HDU: a list of
    ``(index, leading axes it lacks)`` for DQ, PIXELDQ and GROUPDQ."""
    extver = hdul[index].header.get("EXTVER", 1)
    found = []
    for k, h in enumerate(hdul):
        name = (h.name or "").upper()
        if name not in BIT_FLAG_HDUS or h.header.get("EXTVER", 1) != extver \
                or h.header.get("NAXIS", 0) == 0:
            continue
        dq_shape = _shape(h.header)
        if dq_shape != shape[len(shape) - len(dq_shape):]:
            raise IPCInputError(f"{path}[{name}]: shape {dq_shape} does not match the science "
                                f"array {shape}")
        found.append((k, len(shape) - len(dq_shape)))
    return found


def _read_gain(gain, shape2d):
    """``--gain``: None, a number, or a FITS gain image (first image HDU)."""
    if gain is None or isinstance(gain, (int, float, np.floating, np.integer)):
        return gain
    if isinstance(gain, np.ndarray):
        return gain
    text = str(gain)
    try:
        return float(text)
    except ValueError:
        pass
    hdul = _open(text, memmap=False)
    with hdul:
        data = next((np.array(h.data, dtype=np.float64) for h in hdul
                     if h.is_image and h.data is not None), None)
    if data is None or data.shape != tuple(shape2d):
        raise IPCInputError(f"{text}: a gain image must be a {shape2d[0]}x{shape2d[1]} image, "
                            f"got {None if data is None else data.shape}")
    return data


def _full_frame_border(hdul, shape2d):
    """The default reference border: 4 for JWST near-IR full frames, else 0."""
    primary = hdul[0].header
    if (str(primary.get("TELESCOP", "")).upper() == "JWST"
            and str(primary.get("SUBARRAY", "")).upper() == "FULL" and shape2d == (2048, 2048)):
        return 4
    return 0


def _region_text(region):
    return f"[{region[0].start}:{region[0].stop},{region[1].start}:{region[1].stop}]"


class _Provenance:
    """The keywords and HISTORY lines written into the primary header. The
    header is written before the data (so that tiles can stream into the file)
    and rewritten in place afterwards: every value is formatted to a fixed
    width so that the header keeps its size."""

    def __init__(self, operation, model, label, hdu_name, units_text, dq_bits, region, frames,
                 tol, max_iter, arch, precision, tile):
        self.operation = operation
        self.frames = frames
        # S_IPC is the JWST pipeline's status of the IPC correction: only decouple sets it
        self.keywords = {"S_IPC": ("COMPLETE", "IPC correction (ipc_taichi)")} \
            if operation == "decouple" else {}
        self.keywords.update({
            "IPCVER": (__version__, "ipc_taichi version"),
            "IPCOP": (operation, "IPC operation applied"),
            "IPCHDU": (hdu_name[:60], "HDU changed"),
            "IPCLAW": (model.law.name[:68], "IPC coupling law alpha(S,N), electrons"),
            "IPCGEOM": (model.geometry.describe()[:68], "IPC geometry (dy,dx)=weight"),
            "IPCEDGE": (model.edge, "IPC edge rule"),
            "IPCREFPX": (_region_text(region), "science region inside reference pixels"),
            "IPCDQBIT": (int(dq_bits), "DQ bits of pixels left out"),
            "IPCARCH": (arch, "Taichi arch used"),
            "IPCPREC": (precision, "floating precision"),
        })
        if operation == "decouple":
            self.keywords.update({
                "IPCITER": (0, "Jacobi iterations (max over frames)"),
                "IPCCONV": (False, "stopping rule met (all frames)"),
                "IPCTOL": (tol, "stop: max|dS| <= TOL*max|S|"),
                "IPCMAXIT": (max_iter, "iteration limit"),
            })
        how = f" (tiles {tile})" if tile else ""
        self.history = [f"{_now()} ipc_taichi {__version__} {operation} {label}{how}",
                        f"model: {model.describe()}", f"units: {units_text}"]
        self.infos = [None] * frames

    def lines(self):
        out = list(self.history)
        if self.operation == "decouple":
            for k, i in enumerate(self.infos):
                it, conv = (i.iterations, i.converged) if i else (0, False)
                last = i.max_delta[-1] if i and i.max_delta else 0.0
                out.append(f"frame {k:5d}: {it:3d} iterations, "
                           f"{'converged    ' if conv else 'NOT converged'}, "
                           f"last max|dS| {last:10.3e}")
        return out

    def apply(self, header):
        for key in _DROP_CHANGED[3:]:
            header.remove(key, ignore_missing=True, remove_all=True)
        if self.operation == "decouple" and all(self.infos):
            self.keywords["IPCITER"] = (max(i.iterations for i in self.infos),
                                        self.keywords["IPCITER"][1])
            self.keywords["IPCCONV"] = (all(i.converged for i in self.infos),
                                        self.keywords["IPCCONV"][1])
        for key, value in self.keywords.items():
            header[key] = value
        for line in self.lines():
            header.add_history(line)
        return header


def _science_header(header, out_dtype):
    h = header.copy()
    h["BITPIX"] = _BITPIX[np.dtype(out_dtype)]
    for key in _DROP_CHANGED:
        h.remove(key, ignore_missing=True, remove_all=True)
    return h


def _raw_opener(path):
    with open(path, "rb") as f:
        gz = f.read(2) == b"\x1f\x8b"
    return gzip.open(path, "rb") if gz else open(path, "rb")


def _write_skeleton(tmp, path, hdul, index, science_header, primary_header, out_dtype):
    """Write the output file: every HDU copied byte for byte except the
    primary header (provenance) and the science HDU (new header, data space
    left zero). Returns ``(primary header offset, its length, data offset)``."""
    data_offset = None
    with open(tmp, "wb") as out, _raw_opener(path) as raw:
        for k in range(len(hdul)):
            info = hdul.fileinfo(k)
            start = out.tell()
            if k == index:
                text = science_header.tostring().encode("ascii")
                out.write(text)
                data_offset = out.tell()
                nbytes = int(np.prod(_shape(science_header))) * np.dtype(out_dtype).itemsize
                out.seek(-(-nbytes // 2880) * 2880, os.SEEK_CUR)  # a hole, filled later
                out.truncate(out.tell())
                if k == 0:
                    primary = (start, len(text))
                continue
            if k == 0:
                text = primary_header.tostring().encode("ascii")
                out.write(text)
                primary = (start, len(text))
                raw.seek(info["datLoc"])
                out.write(raw.read(info["datSpan"]))
                continue
            raw.seek(info["hdrLoc"])
            _copy(raw, out, info["datLoc"] + info["datSpan"] - info["hdrLoc"])
    return primary[0], primary[1], data_offset


def _copy(src, dst, n, chunk=1 << 24):
    while n > 0:
        block = src.read(min(chunk, n))
        if not block:
            raise IPCInputError("input file truncated")
        dst.write(block)
        n -= len(block)


def process_fits(input_path, output_path, operation="decouple", *, model=None, hdu=None,
                 overwrite=False, max_iter=iteration.MAX_ITER, tol=iteration.TOL, arch=None,
                 precision=None, tile=None, progress=False, dq_bits="DO_NOT_USE", refpix=None,
                 gain=None, exptime=None, bunit=None, output_dtype=None):
    """Couple or decouple the science array of a FITS product into ``output_path``.

    Parameters
    ----------
    input_path, output_path : str
    operation : {"couple", "decouple"}
    model : CouplingModel or str, optional
        The coupling model (default donlon2018, nearest neighbours, zero edge).
    hdu : int, str or (str, int), optional
        The science HDU (default: SCI, else the first image HDU with data).
        Bit-flag HDUs (DQ, PIXELDQ, GROUPDQ) are refused.
    overwrite : bool
        Replace an existing ``output_path``.
    max_iter, tol, arch, precision :
        As for :func:`ipc_taichi.decouple`.
    tile : int, optional
        Decouple tile by tile through memory maps (decouple only).
    progress : bool
        A progress bar on a terminal (tiled runs).
    dq_bits : str or int
        DQ bits whose pixels are left out (default ``DO_NOT_USE``; 0: none).
    refpix : int or None
        Width of the reference border; ``None``: the REFERENCE_PIXEL flags, else
        4 for a JWST near-IR full frame, else 0.
    gain : float, str (FITS gain image) or ndarray, optional
        e-/DN (default: the GAIN keyword).
    exptime : float, optional
        Integration time of a rate in seconds (default: EFFINTTM).
    bunit : str, optional
        Override the file's BUNIT.
    output_dtype : {None, "float32", "float64"}
        Default: the input's float dtype; float64 for integer input.

    Returns
    -------
    dict
        ``output``, ``frames``, ``iterations`` (max over frames), ``converged``
        (all frames; ``None`` for couple), ``infos``.
    """
    model = CouplingModel.resolve(model if model is not None else "donlon2018")
    if operation not in ("couple", "decouple"):
        raise IPCInputError(f"operation must be couple or decouple, got {operation!r}")
    if tile and operation != "decouple":
        raise IPCInputError("--tile is for decouple")
    max_iter, tol = iteration.check_arguments(max_iter, tol)
    check_output_path(output_path, overwrite)  # fail before computing
    if os.path.exists(output_path) and os.path.samefile(input_path, output_path):
        raise IPCInputError(f"{output_path}: is the input; write to another file")
    if str(output_path).lower().endswith((".gz", ".fz", ".bz2")):
        raise IPCInputError(f"{output_path}: the output is written uncompressed; name it .fits")
    hdul = _open(input_path, memmap=True)
    with hdul:
        index, label = _find_science(input_path, hdul, parse_hdu(hdu))
        sci = hdul[index]
        shape = _shape(sci.header)
        shape2d = shape[-2:]
        units = cv.parse_units(bunit if bunit is not None else _keyword(hdul, index, "BUNIT"),
                               label)
        if gain is not None and not units.needs_gain:
            raise IPCInputError(f"{label}: a gain was given but the data are in "
                                f"{units.text or 'electrons (no BUNIT)'}; give --bunit DN or "
                                "DN/s if they are not")
        _warn_if_corrected(hdul, label)
        gain_value = _read_gain(gain if gain is not None else _keyword(hdul, index, "GAIN"),
                                shape2d)
        scale, units_text = cv.charge_scale(
            units, gain_value, exptime if exptime is not None else
            _keyword(hdul, index, "EFFINTTM"), label)
        bits = cv.parse_dq_bits(dq_bits) & ~cv.REFERENCE_PIXEL
        flag_hdus = _dq_arrays(hdul, index, shape, input_path)
        region, inside = _science_region(input_path, hdul, flag_hdus, shape2d, refpix, label)
        out_dtype = _output_dtype(sci.header["BITPIX"], output_dtype)
        from .. import runtime

        rt = runtime.init(arch, precision)
        frames = int(np.prod(shape[:-2])) if len(shape) > 2 else 1
        prov = _Provenance(operation, cv.region_model(model, region, shape2d), label,
                           _hdu_label(hdul, index), units_text, bits, region, frames, tol,
                           max_iter, rt.arch, rt.precision, tile)
        primary = hdul[0].header.copy() if index != 0 else None
        science_header = _science_header(sci.header, out_dtype)
        head = prov.apply(science_header.copy() if index == 0 else primary)
        with atomic_output(output_path, overwrite) as tmp:
            at, length, data_offset = _write_skeleton(
                tmp, input_path, hdul, index, head if index == 0 else science_header,
                head, out_dtype)
            out = np.memmap(tmp, dtype=out_dtype.newbyteorder(">"), mode="r+",
                            offset=data_offset, shape=shape)
            try:
                source = _RawImage(input_path, hdul, index) if tile else None
                masks = _MaskReader(input_path, hdul, flag_hdus, bits, shape, inside, tile,
                                    label)
                if tile:
                    infos = _tiled(source, out, masks, region, scale, model, max_iter, tol,
                                   arch, precision, tile, progress, label)
                else:
                    data = _array(input_path, hdul, index, label)
                    _, infos = cv.correct_frames(
                        data, operation, model, mask=masks.whole(region), region=region,
                        scale=scale, out=out, max_iter=max_iter, tol=tol, arch=arch,
                        precision=precision, label=label)
                out.flush()
            finally:
                del out
            prov.infos = infos
            final = prov.apply(science_header.copy() if index == 0 else hdul[0].header.copy())
            with warnings.catch_warnings():  # its cards were verified (and reported) above
                warnings.simplefilter("ignore")
                text = final.tostring().encode("ascii")
            if len(text) != length:  # fixed-width provenance: cannot happen
                raise RuntimeError(f"{output_path}: provenance header changed size")
            with open(tmp, "r+b") as f:
                f.seek(at)
                f.write(text)
    # a fixed iteration count (tol 0) is what was asked for, not a failure to converge
    converged = None if operation == "couple" or tol == 0 else all(i.converged for i in infos)
    return {"output": output_path, "label": label, "frames": frames, "infos": infos,
            "iterations": max(i.iterations for i in infos) if operation == "decouple" else 0,
            "converged": converged}


def _science_region(path, hdul, flag_hdus, shape2d, refpix, label):
    """The science region inside the reference pixels (see
    :func:`~ipc_taichi.products.conventions.science_region`): ``refpix`` if
    given, else the REFERENCE_PIXEL flags of the first frame (PIXELDQ, or
    DQ's first plane), else 4 for a JWST near-IR full frame, else none."""
    reference = None
    if refpix is None and flag_hdus:
        source = min(flag_hdus, key=lambda f: hdul[f[0]].header["NAXIS"])[0]
        flags = np.asarray(_array(path, hdul, source, label)).reshape((-1,) + shape2d)[0]
        reference = (flags.astype(np.int64) & cv.REFERENCE_PIXEL) != 0
    if refpix is None and (reference is None or not reference.any()):
        refpix = _full_frame_border(hdul, shape2d) or None
    try:
        return cv.science_region(shape2d, refpix, reference)
    except IPCInputError as exc:
        raise IPCInputError(f"{label}: {exc}") from None


def _output_dtype(bitpix, output_dtype):
    """The input's float dtype, float64 for integer data, or ``output_dtype``."""
    if output_dtype in (None, "same"):
        return {-32: np.dtype(np.float32)}.get(bitpix, np.dtype(np.float64))
    out = np.dtype(output_dtype)
    if out not in _BITPIX:
        raise IPCInputError(f"--output-dtype {output_dtype}: give float32 or float64")
    return out


def _array(path, hdul, index, label):
    """The data of HDU ``index``, scaled (astropy memory-maps unscaled data;
    scaled integer storage, e.g. uint16 as int16 + BZERO, is read into memory)."""
    from astropy.io import fits

    try:
        h = hdul[index]
        if not any(k in h.header for k in ("BZERO", "BSCALE", "BLANK")):
            return h.data
        with fits.open(path, memmap=False) as again:
            return np.array(again[index].data)
    except Exception as exc:
        raise IPCInputError(f"{label}: {hdul[index].name or 'HDU'} data cannot be read "
                            f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
                            ) from None


class _MaskReader:
    """The untrusted pixels: any of ``bits`` in DQ, PIXELDQ or GROUPDQ, and
    reference-flagged pixels inside the science region."""

    def __init__(self, path, hdul, flag_hdus, bits, shape, inside, tile, label):
        self.shape = shape
        self.bits = bits
        self.inside = inside
        flag_hdus = flag_hdus if bits else []
        if tile:  # windows through memory maps
            self.sources = [(_RawImage(path, hdul, k), lead) for k, lead in flag_hdus]
        else:
            self.sources = [(_array(path, hdul, k, label), lead) for k, lead in flag_hdus]

    def whole(self, region):
        """The mask of the whole array (None when nothing is masked)."""
        if not self.sources and self.inside is None:
            return None
        mask = np.zeros(self.shape, dtype=bool)
        for src, lead in self.sources:
            mask |= (np.asarray(src[...], dtype=np.int64) & self.bits) != 0
        if self.inside is not None:
            mask[(Ellipsis,) + region] |= self.inside
        return mask

    def window(self, lead_index, region, window):
        """Mask of frame ``lead_index`` (a tuple of leading indices), window
        ``window`` of the science region; None when nothing is masked."""
        if not self.sources and self.inside is None:
            return None
        full = tuple(slice(r.start + w.start, r.start + w.stop) for r, w in zip(region, window))
        mask = np.zeros(tuple(s.stop - s.start for s in full), dtype=bool)
        for src, lead in self.sources:
            key = tuple(lead_index[lead:]) + full
            mask |= (np.asarray(src[key], dtype=np.int64) & self.bits) != 0
        if self.inside is not None:
            mask |= self.inside[window]
        return mask


def _tiled(source, out, masks, region, scale, model, max_iter, tol, arch, precision, tile,
           progress, label):
    """Decouple every frame tile by tile (read and write through memory maps)."""
    from ..tiling import decouple_blocks

    shape = source.shape
    ny, nx = region[0].stop - region[0].start, region[1].stop - region[1].start
    inner_model = cv.region_model(model, region, shape[-2:])
    s = np.asarray(scale, dtype=np.float64)
    infos = []
    leads = list(np.ndindex(*shape[:-2])) if len(shape) > 2 else [()]
    # pixels outside the region (reference pixels) are copied unchanged
    for lead in leads:
        for ys, xs in _strips(shape[-2:]):
            out[lead + (ys, xs)] = source[lead + (ys, xs)]
    for k, lead in enumerate(leads):
        where = f"{label} frame {k}" if len(leads) > 1 else label

        def full(window):
            return tuple(slice(r.start + w.start, r.start + w.stop)
                         for r, w in zip(region, window))

        def factor(window):
            return s[full(window)] if s.ndim == 2 else s

        # NaN pixels travel as masked pixels holding zero (the same rule: neither
        # gives nor takes charge), so that no tile is ever all NaN
        def read(window, lead=lead):
            values = source[lead + full(window)] * factor(window)
            return np.where(np.isfinite(values), values, 0.0)

        def read_mask(window, lead=lead):
            m = ~np.isfinite(source[lead + full(window)])
            flagged = masks.window(lead, region, window)
            if flagged is not None:
                m |= flagged
            if s.ndim == 2:  # pixels without a usable gain
                f = factor(window)
                m |= ~(np.isfinite(f) & (f > 0))
            return m

        def write(core, values, lead=lead):
            check_stop()  # a SIGINT/SIGTERM swallowed by a library stops the run here
            with np.errstate(divide="ignore", invalid="ignore"):  # no gain: masked below
                result = values / factor(core)
            out[lead + full(core)] = np.where(read_mask(core), source[lead + full(core)],
                                              result)

        _check_not_empty(read, read_mask, (ny, nx), tile, where)  # one read pass
        with cv.named(where):
            info = decouple_blocks(read, write, (ny, nx), tile, inner_model, max_iter=max_iter,
                                   tol=tol, arch=arch, precision=precision, progress=progress,
                                   read_mask=read_mask)
        infos.append(info)
    return infos


def _strips(shape, rows=256):
    for y0 in range(0, shape[0], rows):
        yield slice(y0, min(shape[0], y0 + rows)), slice(0, shape[1])


def _check_not_empty(read, read_mask, shape, tile, where):
    from ..tiling import tiles

    for core in tiles(shape, tile):
        v = read(core)
        m = read_mask(core)
        if (np.isfinite(v) & (True if m is None else ~m)).any():
            return
    raise IPCInputError(f"{where}: no finite, unmasked pixel to decouple (all NaN or flagged)")

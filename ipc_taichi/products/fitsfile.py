"""FITS files at the byte level: opening with checks, finding the science
HDUs, windows through memory maps, and the output skeleton.

What :mod:`ipc_taichi.products.fits` orchestrates. Errors are one line naming
the user's file and HDU (never a temporary path).
"""

import bz2
import gzip
import os
import warnings

import numpy as np

from ..errors import IPCInputError
from .checks import check_input_file

__all__ = ["open_fits", "hdu_label", "shape_of", "keyword", "RawImage", "read_array",
           "science_indices", "flag_hdus", "noise_hdus", "write_skeleton", "science_header",
           "BIT_FLAG_HDUS", "is_compressed"]

BIT_FLAG_HDUS = ("DQ", "PIXELDQ", "GROUPDQ")
"""HDUs of bit flags: they say which pixels to trust and are never data."""

DROP_CHANGED = ("BZERO", "BSCALE", "BLANK", "CHECKSUM", "DATASUM")
_BITPIX = {np.dtype(np.float32): -32, np.dtype(np.float64): -64}


def open_fits(path, memmap=True):
    """Open ``path``; refuse a missing, unreadable or truncated file in one line
    (a file cut inside its last header would otherwise lose that HDU)."""
    from astropy.io import fits

    check_input_file(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a cut file is found below, by its size
            hdul = fits.open(path, memmap=memmap, lazy_load_hdus=False)
    except Exception as exc:
        text = str(exc).splitlines()[0] if str(exc) else ""
        raise IPCInputError(f"{path}: not a readable FITS file ({type(exc).__name__}"
                            f"{': ' + text if text else ''})") from None
    if compression(path) is None:  # astropy reads gzip, bzip2 and zip whole
        info = hdul.fileinfo(len(hdul) - 1)
        end, size = info["datLoc"] + info["datSpan"], os.path.getsize(path)
        if size < end:
            hdul.close()
            raise IPCInputError(f"{path}: truncated ({size} bytes, its HDUs need {end})")
        if size > end:
            with open(path, "rb") as f:
                f.seek(end)
                tail = f.read(size - end)
            if tail.strip(b" \0"):
                hdul.close()
                raise IPCInputError(f"{path}: {size - end} bytes after its last complete HDU "
                                    "(a cut or damaged header): the file is incomplete")
    return hdul


def hdu_label(hdul, index):
    """``SCI`` (the EXTNAME, with its EXTVER when not 1) or the index."""
    h = hdul[index]
    name = h.header.get("EXTNAME") if index else None
    if not name:
        return str(index)
    ver = h.header.get("EXTVER", 1)
    return f"{name},{ver}" if ver != 1 else str(name)


def shape_of(header):
    return tuple(int(header[f"NAXIS{k}"]) for k in range(header["NAXIS"], 0, -1))


def keyword(hdul, index, key):
    """``key`` from the science header, else the primary header, else None."""
    for h in (hdul[index].header, hdul[0].header):
        if key in h and h[key] not in (None, ""):
            return h[key]
    return None


def is_compressed(hdu):
    from astropy.io import fits

    return isinstance(hdu, fits.CompImageHDU)


def _check_science(path, hdul, index, raw_ok=False):
    h = hdul[index]
    label = f"{path}[{hdu_label(hdul, index)}]"
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
    if naxis == 4 and h.header["BITPIX"] > 0 and not raw_ok:
        raise IPCInputError(f"{label}: an integer 4-D ramp is raw (_uncal) data with the bias "
                            "in it; subtract the bias first (calwebb_detector1 through the "
                            "superbias step) and decouple that ramp")
    return label


def science_indices(path, hdul, hdu, raw_ok=False):
    """The science HDUs: ``hdu`` if given, else every ``SCI`` HDU (each read
    of a multi-read product), else the first image HDU with data. Returns
    ``[(index, label)]``; refuses tables, empty HDUs and bit-flag HDUs, and
    raw integer 4-D ramps (their bias) unless ``raw_ok`` (calibrate, which
    subtracts the first read)."""
    if hdu is None:
        indices = [k for k, h in enumerate(hdul) if (h.name or "").upper() == "SCI"]
        if not indices:
            first = next((k for k, h in enumerate(hdul)
                          if h.is_image and h.header.get("NAXIS", 0) > 0), None)
            if first is None:
                raise IPCInputError(f"{path}: no HDU holds image data")
            indices = [first]
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
        indices = [index]
    return [(k, _check_science(path, hdul, k, raw_ok)) for k in indices]


class RawImage:
    """Windows of an image HDU read through a memory map of the file, scaled
    by BZERO/BSCALE, BLANK as NaN, as astropy scales them (astropy refuses
    memory-mapped sections of scaled data). Each window maps the file anew and
    lets the map go with its last view, so that pages read stay out of the
    process's memory once used. Refuses gzip files and tile-compressed HDUs
    (their bytes are not pixels)."""

    def __init__(self, path, hdul, index):
        label = f"{path}[{hdu_label(hdul, index)}]"
        if is_compressed(hdul[index]):
            raise IPCInputError(f"{label}: tile-compressed; --tile reads pixels through memory "
                                "maps: run without --tile, or decompress it first (funpack)")
        header = hdul[index].header
        bitpix = header["BITPIX"]
        self.path = path
        self.dtype = np.dtype({8: "u1", 16: ">i2", 32: ">i4", 64: ">i8", -32: ">f4",
                               -64: ">f8"}[bitpix])
        self.offset = hdul.fileinfo(index)["datLoc"]
        self.shape = shape_of(header)
        self.integer = bitpix > 0
        self.zero = header.get("BZERO", 0)
        self.scale = header.get("BSCALE", 1)
        self.blank = header.get("BLANK") if self.integer else None
        if compression(path) is not None:
            raise IPCInputError(f"{path}: --tile needs an uncompressed file "
                                f"({compression(path)}: decompress it first)")

    def __getitem__(self, key):
        raw = np.memmap(self.path, dtype=self.dtype, mode="r", offset=self.offset,
                        shape=self.shape)[key]
        if self.integer and self.scale == 1 and float(self.zero).is_integer() \
                and self.blank is None:
            return raw.astype(np.int64) + int(self.zero)
        out = raw.astype(np.float64)
        if self.scale != 1 or self.zero != 0:
            out = self.zero + self.scale * out
        if self.blank is not None:
            out[raw == self.blank] = np.nan
        return out


def read_array(path, hdul, index):
    """The data of HDU ``index``, scaled (astropy memory-maps unscaled data;
    scaled integer storage, e.g. uint16 as int16 + BZERO, is read into memory)."""
    from astropy.io import fits

    try:
        h = hdul[index]
        if is_compressed(h) or not any(k in h.header for k in ("BZERO", "BSCALE", "BLANK")):
            return h.data
        with fits.open(path, memmap=False) as again:
            return np.array(again[index].data)
    except Exception as exc:
        raise IPCInputError(f"{path}[{hdu_label(hdul, index)}]: data cannot be read "
                            f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
                            ) from None


def flag_hdus(hdul, index, shape, path):
    """The companion bit-flag HDUs of the science HDU (same EXTVER): a list of
    indices of DQ, PIXELDQ and GROUPDQ."""
    extver = hdul[index].header.get("EXTVER", 1)
    found = []
    for k, h in enumerate(hdul):
        name = (h.name or "").upper()
        if name not in BIT_FLAG_HDUS or h.header.get("EXTVER", 1) != extver \
                or h.header.get("NAXIS", 0) == 0:
            continue
        dq_shape = shape_of(h.header)
        if dq_shape != shape[len(shape) - len(dq_shape):]:
            raise IPCInputError(f"{path}[{name}]: shape {dq_shape} does not match the science "
                                f"array {shape}")
        found.append(k)
    return found


def noise_hdus(hdul, index, shape, names):
    """The noise HDUs of the science HDU (same EXTVER, its shape, floating
    point): ``name -> index`` for the ``names`` (lower case) whose EXTNAME
    (upper case) is found; others (another shape, integers) are not listed."""
    extver = hdul[index].header.get("EXTVER", 1)
    found = {}
    for k, h in enumerate(hdul):
        name = (h.name or "").lower()
        if name in names and name not in found and h.header.get("EXTVER", 1) == extver \
                and h.header.get("NAXIS", 0) and h.header.get("BITPIX") in (-32, -64) \
                and "BZERO" not in h.header and shape_of(h.header) == tuple(shape):
            found[name] = k
    return found


def science_header(header, out_dtype):
    """The science HDU's header for unscaled float data of ``out_dtype``."""
    from astropy.io import fits

    if header.get("XTENSION") == "BINTABLE" or "ZIMAGE" in header:  # cannot happen: safety
        raise IPCInputError("internal: a compressed header reached the writer")
    h = header.copy() if isinstance(header, fits.Header) else fits.Header(header)
    h["BITPIX"] = _BITPIX[np.dtype(out_dtype)]
    for key in DROP_CHANGED:
        h.remove(key, ignore_missing=True, remove_all=True)
    return h


_MAGIC = {b"\x1f\x8b": "gzip", b"BZh": "bzip2", b"PK\x03\x04": "zip"}
"""The first bytes of the compressed files astropy opens as FITS."""


def compression(path):
    """How ``path`` is compressed as a whole (``"gzip"``, ``"bzip2"``, ``"zip"``),
    by its first bytes; None when it is not."""
    with open(path, "rb") as f:
        head = f.read(4)
    return next((kind for magic, kind in _MAGIC.items() if head.startswith(magic)), None)


def _raw_opener(path):
    """The file's bytes as astropy reads them (a zip archive: its first member)."""
    kind = compression(path)
    if kind == "zip":
        import zipfile

        archive = zipfile.ZipFile(path)
        return archive.open(archive.namelist()[0])
    return {"gzip": gzip.open, "bzip2": bz2.open}.get(kind, open)(path, "rb")


def write_skeleton(tmp, path, hdul, headers, science):
    """Write the output file: every HDU copied byte for byte except those in
    ``headers`` (index -> new header): the ``science`` HDUs (index -> output
    dtype) get their data space (filled later), the others (the primary) keep
    their data. The whole file is allocated
    on disk before any pixel is written (a full disk fails here, with
    ``OSError``, not later as a bus error in a memory map).

    Returns index -> ``(header offset, header length, data offset or None)``.
    """
    places = {}
    with open(tmp, "wb") as out, _raw_opener(path) as raw:
        for k in range(len(hdul)):
            info = hdul.fileinfo(k)
            start = out.tell()
            if k not in headers:
                raw.seek(info["hdrLoc"])
                _copy(raw, out, info["datLoc"] + info["datSpan"] - info["hdrLoc"], path)
                continue
            with warnings.catch_warnings():  # its cards were verified (and reported) before
                warnings.simplefilter("ignore")
                text = headers[k].tostring().encode("ascii")
            out.write(text)
            data_offset = out.tell()
            if k in science:
                nbytes = int(np.prod(shape_of(headers[k]))) * np.dtype(science[k]).itemsize
                out.seek(-(-nbytes // 2880) * 2880, os.SEEK_CUR)  # filled later
                out.truncate(out.tell())
            else:  # a primary that is not science: its data as they were
                raw.seek(info["datLoc"])
                _copy(raw, out, info["datSpan"], path)
                data_offset = None
            places[k] = (start, len(text), data_offset)
        size = out.tell()
        out.flush()
        try:
            os.posix_fallocate(out.fileno(), 0, size)
        except OSError as exc:
            if exc.errno not in (95, 22):  # EOPNOTSUPP, EINVAL: the writes will tell
                raise
    return places


def _copy(src, dst, n, path, chunk=1 << 24):
    while n > 0:
        block = src.read(min(chunk, n))
        if not block:
            raise IPCInputError(f"{path}: truncated (an HDU ends before its data)")
        dst.write(block)
        n -= len(block)

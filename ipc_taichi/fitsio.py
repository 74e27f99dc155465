"""Small FITS helpers: one-line errors, atomic writes, HDU names.

Products (JWST/Roman files with their DQ, units and every HDU kept) go
through :mod:`ipc_taichi.products`; this module keeps what it and the
analysis scripts share: :func:`parse_hdu`, :func:`check_output_path`,
:class:`atomic_output`, and :func:`read_image` / :func:`write_image` for
single images (analysis and figure data).

Errors name the file and the HDU. Outputs are written to a temporary file in
the destination directory and renamed into place, so a failure never leaves a
truncated file at the output path, and an existing file is only replaced with
``overwrite=True``.
"""

import glob
import json
import logging
import os
import re
import tempfile

import numpy as np

from .errors import IPCInputError
from .interrupts import stop_requested

__all__ = ["read_image", "write_image", "parse_hdu", "atomic_output", "check_output_path",
           "write_json", "history_lines", "HISTORY_WIDTH", "cannot_write", "stale_temporaries",
           "say_stale"]

HISTORY_WIDTH = 70
"""Characters of text per HISTORY card: under the 72 a card holds, so astropy
never cuts a line (it cuts at a fixed column, inside a word or a number)."""

# structural and scaling keywords that must not be copied onto a new float image
_STRUCTURAL = {"SIMPLE", "XTENSION", "BITPIX", "NAXIS", "EXTEND", "PCOUNT", "GCOUNT",
               "BSCALE", "BZERO", "BLANK", "CHECKSUM", "DATASUM", "GROUPS", "EXTNAME",
               "EXTVER"}


def parse_hdu(text):
    """``"1"`` -> 1, ``"SCI"`` -> "SCI", ``"SCI,2"`` -> ("SCI", 2), None -> None."""
    if text is None:
        return None
    if isinstance(text, (int, tuple)):
        return text
    text = str(text).strip()
    if text.lstrip("-").isdigit():
        return int(text)
    name, comma, ver = text.partition(",")
    if comma:
        try:
            return (name.strip(), int(ver))
        except ValueError:
            raise IPCInputError(f"HDU {text!r}: expected INDEX, NAME or NAME,VER") from None
    return name


def _label(hdu):
    return f"[{hdu[0]},{hdu[1]}]" if isinstance(hdu, tuple) else f"[{hdu}]"


def read_image(path, hdu=None):
    """Read an image HDU; return ``(data, header, hdu_label)``.

    ``hdu=None`` takes the first HDU that holds image data. ``data`` is a
    native-endian float64 array (scaled by BSCALE/BZERO where present).
    """
    from astropy.io import fits

    if not os.path.exists(path):
        raise IPCInputError(f"{path}: no such file")
    try:
        hdul = fits.open(path, memmap=False)
    except Exception as exc:
        raise IPCInputError(f"{path}: not a readable FITS file ({type(exc).__name__}: "
                            f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    with hdul:
        if hdu is None:
            index = next((k for k, h in enumerate(hdul)
                          if h.is_image and h.header.get("NAXIS", 0) > 0), None)
            if index is None:
                raise IPCInputError(f"{path}: no HDU holds image data")
            hdu = index
        try:
            h = hdul[hdu]
        except (KeyError, IndexError):
            raise IPCInputError(f"{path}{_label(hdu)}: no such HDU (file has {len(hdul)}: "
                                f"{', '.join(str(x.name) or '?' for x in hdul)})") from None
        label = f"{path}{_label(hdu)}"
        if not h.is_image:
            raise IPCInputError(f"{label}: is a {type(h).__name__}, not an image")
        try:
            data = h.data
        except Exception as exc:
            raise IPCInputError(f"{label}: data cannot be read ({exc})") from None
        if data is None:
            raise IPCInputError(f"{label}: HDU has no data")
        if data.ndim not in (2, 3) or data.size == 0:
            raise IPCInputError(f"{label}: expected a 2-D image or 3-D cube, "
                                f"got shape {data.shape}")
        data = np.asarray(data, dtype=np.float64)  # native order, scaled
        header = h.header.copy()
    return data, header, label


def history_lines(text, width=HISTORY_WIDTH):
    """``text`` as HISTORY lines of at most ``width`` characters, each cut
    after a space or a ``;`` (never inside a word or a number; a single word
    longer than a line is cut where it must); lines after the first are
    indented by two spaces."""
    pieces = [p for p in re.split(r"(?<=[ ;])", str(text)) if p]
    lines, line = [], ""
    for piece in pieces:
        if line and len(line + piece.rstrip()) > width:
            lines.append(line.rstrip())
            line = "  "
        line += piece
        while len(line.rstrip()) > width:  # one word longer than a line
            lines.append(line[:width])
            line = "  " + line[width:]
    if line.strip() or not lines:
        lines.append(line.rstrip())
    return lines


def check_output_path(path, overwrite):
    """Refuse a directory, and an existing file unless ``overwrite``."""
    if os.path.isdir(path):
        raise IPCInputError(f"{path}: is a directory; name an output file")
    if os.path.exists(path) and not overwrite:
        raise IPCInputError(f"{path}: exists (use --overwrite to replace it)")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise IPCInputError(f"{path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise IPCInputError(f"{path}: cannot be written (directory {parent} is not writable)")


def cannot_write(path, exc):
    """The one-line error for an OS error while writing ``path``: it names the
    user's output, never the temporary file beside it."""
    return IPCInputError(f"{path}: cannot be written ({exc.strerror or type(exc).__name__})")


def stale_temporaries(path):
    """Temporary files an earlier run writing ``path`` left when it was killed
    (SIGKILL, a power cut: nothing could remove them): ``.tmp-XXXXXXXX<name>``
    files (:class:`atomic_output`) and ``.tmp-XXXXXXXX/<name>`` directories
    (Roman ASDF) beside it."""
    parent, name = os.path.split(os.path.abspath(path))
    found = []
    for tmp in sorted(glob.glob(os.path.join(glob.escape(parent), ".tmp-????????*"))):
        base = os.path.basename(tmp)
        if base == f"{base[:13]}{name}" and os.path.isfile(tmp):
            found.append(tmp)
        elif len(base) == 13 and os.path.isfile(os.path.join(tmp, name)):
            found.append(os.path.join(tmp, name))
    return found


def say_stale(path):
    """One warning line (logged) for each temporary file a killed run writing
    ``path`` left beside it: never removed here (another run may be writing
    it), named so that it can be."""
    for tmp in stale_temporaries(path):
        size = os.path.getsize(tmp) / 1e6
        logging.getLogger("ipc_taichi").warning(
            "warning: %s: %s (%.1f MB) was left by an earlier run writing it that was killed; "
            "delete it if no other run is writing this output", path, tmp, size)


class atomic_output:
    """Context manager yielding a temporary path beside ``path``; renamed onto
    ``path`` only if the block succeeds, deleted otherwise."""

    def __init__(self, path, overwrite=False):
        self.path = path
        self.overwrite = overwrite

    def __enter__(self):
        check_output_path(self.path, self.overwrite)
        say_stale(self.path)
        parent = os.path.dirname(os.path.abspath(self.path))
        try:  # a read-only file system or a forbidden directory: name the output
            fd, self.tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.basename(self.path),
                                            dir=parent)
        except OSError as exc:
            raise cannot_write(self.path, exc) from None
        os.close(fd)
        os.unlink(self.tmp)  # writers create it themselves
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        stop = stop_requested()
        if exc_type is None and stop is not None:  # a swallowed SIGINT/SIGTERM: do not commit
            if os.path.exists(self.tmp):
                os.unlink(self.tmp)
            raise stop
        if exc_type is None:
            if os.path.exists(self.path) and not self.overwrite:  # appeared meanwhile
                os.unlink(self.tmp)
                raise IPCInputError(f"{self.path}: exists (use --overwrite to replace it)")
            try:
                os.replace(self.tmp, self.path)
            except OSError as exc:  # name the user's file, not the temporary one
                if os.path.exists(self.tmp):
                    os.unlink(self.tmp)
                raise cannot_write(self.path, exc) from None
        else:
            if os.path.exists(self.tmp):
                os.unlink(self.tmp)
            if isinstance(exc, OSError) and not isinstance(exc, IPCInputError) and \
                    self.tmp in str(exc):  # a writer's error naming the temporary file
                raise cannot_write(self.path, exc) from None
        return False


def output_header(header, keywords=None, history=()):
    """The header of an output image: the cards of ``header`` (e.g. the input
    HDU's) except structural, scaling and extension keywords, plus ``keywords``
    (name -> (value, comment)) and ``history`` lines."""
    from astropy.io import fits

    out = fits.Header()
    if header is not None:
        for card in header.cards:
            if card.keyword in _STRUCTURAL or card.keyword.startswith("NAXIS"):
                continue
            out.append(card, end=True)
    for key, (value, comment) in (keywords or {}).items():
        out[key] = (value, comment)
    for text in history:
        for line in history_lines(text):
            out.add_history(line)
    return out


def write_image(path, data, header=None, overwrite=False, keywords=None, history=()):
    """Write ``data`` as the primary HDU of ``path`` atomically.

    The cards of ``header`` (e.g. the input HDU's) are kept, except structural
    and scaling keywords; ``keywords`` (name -> (value, comment)) and
    ``history`` lines are added.
    """
    from astropy.io import fits

    hdu = fits.PrimaryHDU(data=np.asarray(data),
                          header=output_header(header, keywords, history))
    with atomic_output(path, overwrite) as tmp:
        hdu.writeto(tmp, output_verify="silentfix")


def write_json(path, document, overwrite=False):
    """Write ``document`` as JSON to ``path`` atomically (:class:`atomic_output`):
    NumPy scalars and arrays become numbers and lists, tuples lists; NaN is
    refused (use None for "not measured"). Returns ``path``."""
    text = json.dumps(document, indent=1, allow_nan=False, default=_json_value)
    with atomic_output(os.fspath(path), overwrite) as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text + "\n")
    return path


def _json_value(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f"cannot write {type(value).__name__} to JSON")

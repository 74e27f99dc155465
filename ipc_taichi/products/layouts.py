"""How a product's frame is laid out: which samples are detector pixels,
which are reference pixels, and how to get the contiguous science image.

One question for every product path (FITS, ASDF, the JWST Step):
:func:`layout_of` answers it from the headers and the frame's shape with a
:class:`Layout`, whose :meth:`~Layout.to_science` gives the image on which IPC
acts (neighbouring array elements are neighbouring pixels on the detector)
and whose :meth:`~Layout.from_science` puts a corrected image back into the
product, every sample that is not a science pixel exactly as it came.

- **Contiguous** (every product but the two below): the frame is the image;
  both methods are the identity, and the layout names no reference pixels
  (the observatory's border, :mod:`ipc_taichi.products.missions`, applies).
- **NIRSpec IRS2** (``READPATT`` ``NRSIRS2``/``NRSIRS2RAPID``, frames longer
  than the detector): reference samples interleaved with the rows
  (:mod:`ipc_taichi.products.irs2`). The science image is 2048 x 2048 with
  the near-infrared 4-pixel reference border; layouts that cannot be placed
  are refused in one line.
- **MIRI**: 1032 columns of which the first 4 and the last 4 are reference
  columns, with no reference rows (the JWST pipeline's ``refpix`` and ``ipc``
  steps); a subarray holds those of its columns that fall on them, from
  ``SUBSTRT1``. They are reference pixels whether or not the DQ array flags
  them.

Also :func:`ramp_dq`: the ``pixeldq`` and ``groupdq`` of a JWST
``RampModel``, all good when the model has none (the JWST pipeline's own test
fixtures build such models).

Pure NumPy, no I/O: headers are mappings (``astropy.io.fits.Header`` or a
``dict``; a keyword is looked up in the science header first).
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import IPCInputError
from . import irs2

__all__ = ["Layout", "layout_of", "border_mask", "miri_reference_columns", "ramp_dq",
           "ramp_keywords",
           "MIRI_COLUMNS", "MIRI_REFERENCE_COLUMNS", "NEAR_IR_BORDER"]

MIRI_COLUMNS = 1032
"""Columns of a MIRI detector (1024 rows)."""

MIRI_REFERENCE_COLUMNS = 4
"""Reference columns on each side of a MIRI detector (no reference rows)."""

NEAR_IR_BORDER = 4
"""Reference pixels on each side of a JWST near-infrared (H2RG) full frame."""


@dataclass(frozen=True)
class Layout:
    """The layout of one product frame.

    Attributes
    ----------
    kind : str
        ``"contiguous"``, ``"irs2"`` or ``"miri"``.
    shape : tuple of int
        The frame as stored (rows, columns).
    science_shape : tuple of int
        The contiguous science image (rows, columns).
    reference : ndarray of bool or None
        Reference pixels this layout places in the science image (shape
        ``science_shape``), whatever the DQ array says; ``None`` when it
        places none (then the observatory's conventions apply).
    irs2 : IRS2Geometry or None
    note : str
        Said in logs and HISTORY (empty for a plain contiguous frame).
    """

    kind: str
    shape: tuple
    science_shape: tuple
    reference: object = field(default=None, compare=False, repr=False)
    irs2: object = None
    note: str = ""

    @property
    def identity(self):
        """Whether :meth:`to_science` and :meth:`from_science` leave arrays as they are."""
        return self.irs2 is None

    def to_science(self, array):
        """The contiguous science image(s) of ``array`` (frames, a ramp or
        DQ planes: its last two axes are the frame). The array itself when
        the layout is contiguous; a copy otherwise."""
        if self.identity:
            return array
        return irs2.science_image(array, self.irs2)

    def from_science(self, corrected, original):
        """The product frame(s) from corrected science image(s).

        Parameters
        ----------
        corrected : ndarray
            As :meth:`to_science` shaped it.
        original : ndarray
            The frame(s) as they came (not modified): every sample outside
            the science image is taken from here, bit for bit.

        Returns
        -------
        ndarray
            ``corrected`` itself for a contiguous layout; else a new array of
            ``original``'s shape and dtype.
        """
        if self.identity:
            return corrected
        return irs2.interleave(corrected, original, self.irs2)

    def describe(self):
        return self.note or f"contiguous {self.shape[0]}x{self.shape[1]}"


def border_mask(shape2d, left, right, bottom, top):
    """A bool frame, True in ``left``/``right`` columns and ``bottom``/``top``
    rows (row 0 is the bottom)."""
    ny, nx = shape2d
    mask = np.zeros(shape2d, dtype=bool)
    mask[:min(bottom, ny)] = True
    mask[ny - min(top, ny):] = True
    mask[:, :min(left, nx)] = True
    mask[:, nx - min(right, nx):] = True
    return mask


def miri_reference_columns(primary, science, shape2d, label):
    """The MIRI reference columns in a frame (bool mask), or ``None``.

    Columns 1-4 and 1029-1032 of the detector (1-based) are reference
    columns; a subarray holds those that fall between ``SUBSTRT1`` and
    ``SUBSTRT1`` + its width - 1. A 1024 x 1032 frame without ``SUBSTRT1``
    is the full frame; another shape without it, or a frame narrower or wider
    than its ``SUBSIZE1`` (a cut-out, such as a slit of ``extract_2d``):
    ``None``, where it lies is unknown and its DQ flags are what is left.
    ``None`` too for a frame that holds no reference column, and for a
    product that is not MIRI's.

    Raises
    ------
    IPCInputError
        ``SUBSTRT1`` not a whole number from 1, or a frame that runs past the
        detector's 1032 columns (one line, naming ``label``).
    """
    def get(key):
        return irs2.header_value(primary, science, key)

    if str(get("INSTRUME") or "").strip().upper() != "MIRI":
        return None
    ny, nx = shape2d
    start, size = get("SUBSTRT1"), get("SUBSIZE1")
    if size is not None and irs2.whole_number(size) != nx:
        return None
    if start is None:
        if nx != MIRI_COLUMNS:
            return None
        start = 1
    x0 = irs2.whole_number(start)
    if x0 is None:
        raise IPCInputError(f"{label}: SUBSTRT1 = {start!r} is not a column of the MIRI "
                            "detector (a whole number from 1); its reference columns cannot "
                            "be placed; refused")
    if x0 - 1 + nx > MIRI_COLUMNS:
        raise IPCInputError(f"{label}: a MIRI frame of {nx} columns from SUBSTRT1 = {x0} runs "
                            f"past the detector's {MIRI_COLUMNS} columns; refused")
    left = max(0, MIRI_REFERENCE_COLUMNS - (x0 - 1))
    right = max(0, x0 - 1 + nx - (MIRI_COLUMNS - MIRI_REFERENCE_COLUMNS))
    if not (left or right):
        return None
    return border_mask(shape2d, left, right, 0, 0)


def layout_of(primary, science, shape, label):
    """The :class:`Layout` of a product's frames.

    Parameters
    ----------
    primary, science : mapping
        The primary and science headers (for a ``RampModel``, a mapping of
        the same keywords: ``INSTRUME``, ``DETECTOR``, ``READPATT``,
        ``NRS_NORM``, ``NRS_REF``, ``SUBSTRT1``).
    shape : tuple of int
        The science array's shape (the last two axes are the frame).
    label : str
        The file and HDU, for messages (e.g. ``"jw01_uncal.fits[SCI]"``).

    Raises
    ------
    IPCInputError
        A layout that cannot be placed (see :func:`ipc_taichi.products.irs2.irs2_geometry`
        and :func:`miri_reference_columns`); never corrected as if contiguous.
    """
    frame = tuple(int(n) for n in tuple(shape)[-2:])
    if len(frame) < 2:
        return Layout("contiguous", frame, frame)
    geometry = irs2.irs2_geometry(primary, science, frame, label)
    if geometry is not None:
        science_shape = (irs2.DETECTOR_PIXELS, irs2.DETECTOR_PIXELS)
        border = NEAR_IR_BORDER
        return Layout("irs2", frame, science_shape,
                      border_mask(science_shape, border, border, border, border), geometry,
                      geometry.describe())
    columns = miri_reference_columns(primary, science, frame, label)
    if columns is not None:
        count = int(columns[0].sum())
        return Layout("miri", frame, frame, columns, None,
                      f"MIRI, {count} reference column{'s' * (count != 1)} kept as they are")
    note = ""
    if irs2.is_irs2_pattern(irs2.header_value(primary, science, "READPATT")):
        note = "IRS2 read pattern, its interleaved reference samples already removed"
    return Layout("contiguous", frame, frame, None, None, note)


_RAMP_KEYWORDS = {
    "TELESCOP": ("telescope",), "INSTRUME": ("instrument", "name"),
    "DETECTOR": ("instrument", "detector"), "READPATT": ("exposure", "readpatt"),
    "NRS_NORM": ("exposure", "nrs_normal"), "NRS_REF": ("exposure", "nrs_reference"),
    "SUBARRAY": ("subarray", "name"), "SUBSTRT1": ("subarray", "xstart"),
    "SUBSTRT2": ("subarray", "ystart"), "SUBSIZE1": ("subarray", "xsize"),
    "SUBSIZE2": ("subarray", "ysize"),
}


def ramp_keywords(ramp):
    """The layout keywords of a JWST ``RampModel`` as a header mapping (the
    FITS names :func:`layout_of` reads; those the model lacks are left out)."""
    keywords = {}
    for key, path in _RAMP_KEYWORDS.items():
        node = ramp.meta
        for name in path:
            node = getattr(node, name, None)
        if node is not None:
            keywords[key] = node
    return keywords


def ramp_dq(ramp):
    """``(pixeldq, groupdq)`` of a JWST ``RampModel``, all good where missing.

    Parameters
    ----------
    ramp : RampModel
        Its ``data`` is (nints, ngroups, ny, nx).

    Returns
    -------
    pixeldq : ndarray of uint32, shape (ny, nx)
    groupdq : ndarray of uint8, shape of ``data``
        The model's own arrays (as NumPy arrays) when it has them; zeros
        (every pixel good) when it has none. The model is not modified.

    Raises
    ------
    IPCInputError
        A ``pixeldq`` or ``groupdq`` whose shape does not match ``data``.
    """
    shape = tuple(np.shape(ramp.data))
    label = f"{getattr(ramp.meta, 'filename', None) or 'ramp'}"
    pixeldq = getattr(ramp, "pixeldq", None)
    groupdq = getattr(ramp, "groupdq", None)
    pixeldq = np.zeros(shape[-2:], np.uint32) if pixeldq is None else np.asarray(pixeldq)
    groupdq = np.zeros(shape, np.uint8) if groupdq is None else np.asarray(groupdq)
    for name, array, expected in (("PIXELDQ", pixeldq, shape[-2:]), ("GROUPDQ", groupdq, shape)):
        if array.shape != expected:
            raise IPCInputError(f"{label}[{name}]: shape {array.shape} does not match the "
                                f"science data's {expected}; refused")
    return pixeldq, groupdq

"""How a product's frame is read out: which stored samples are the detector's
pixels, and how to get the contiguous image on which IPC acts.

The readout *arrangement* (:class:`Arrangement`) is the first question the
product plan (:func:`ipc_taichi.products.plan.science_region_of`) asks of every
science array, before it decides where the science region lies inside the
reference pixels (the plan's :class:`~ipc_taichi.products.plan.ScienceRegion`,
which holds the arrangement). :func:`arrangement_of` answers it from the
headers and the frame's shape; :meth:`Arrangement.to_science` gives the
image in which neighbouring array elements are neighbouring pixels on the
detector, and :meth:`Arrangement.from_science` puts a corrected image back
into the product, every stored sample that is not a detector pixel exactly
as it came.

- **Contiguous** (every product but the one below): the frame is the image;
  both methods are the identity.
- **NIRSpec IRS2** (``READPATT`` ``NRSIRS2``/``NRSIRS2RAPID``, frames longer
  than the detector): reference samples interleaved with the rows
  (:mod:`ipc_taichi.products.irs2`). The image is the 2048 x 2048 detector,
  with the near-infrared 4-pixel reference border (:attr:`Arrangement.border`);
  arrangements that cannot be placed are refused in one line, never
  corrected as if contiguous.

Reference pixels *inside* a contiguous frame (the near-infrared border, MIRI's
4 + 4 reference columns, Roman's border) are not an arrangement: the plan
places them by one rule, the observatory's convention
(:func:`ipc_taichi.products.missions.reference_border`) unless flags or
``--refpix`` say otherwise.

Pure NumPy, no I/O: headers are mappings with a ``get`` (an
``astropy.io.fits.Header``, a ``dict``); a keyword is looked up in the
science header first.
"""

from dataclasses import dataclass

from . import irs2

__all__ = ["Arrangement", "arrangement_of", "NEAR_IR_BORDER"]

NEAR_IR_BORDER = 4
"""Reference pixels on each side of a JWST near-infrared (H2RG) detector."""


@dataclass(frozen=True)
class Arrangement:
    """How one product frame is read out.

    Attributes
    ----------
    kind : str
        ``"contiguous"`` or ``"irs2"``.
    shape : tuple of int
        The frame as stored (rows, columns).
    science_shape : tuple of int
        The contiguous image of the detector's pixels (rows, columns).
    irs2 : IRS2Geometry or None
    border : int
        Reference pixels on each side of that image the arrangement itself
        places (the IRS2 detector's 4); 0: the plan's conventions decide.
    note : str
        Said in logs and HISTORY (empty for a plain contiguous frame).
    """

    kind: str
    shape: tuple
    science_shape: tuple
    irs2: object = None
    border: int = 0
    note: str = ""

    @classmethod
    def contiguous(cls, shape2d, note=""):
        """The arrangement of a frame that is its own image."""
        shape2d = tuple(int(n) for n in shape2d)
        return cls("contiguous", shape2d, shape2d, note=note)

    @property
    def identity(self):
        """Whether :meth:`to_science` and :meth:`from_science` leave arrays as they are."""
        return self.irs2 is None

    def to_science(self, array):
        """The contiguous image(s) of ``array`` (frames, a ramp or DQ planes:
        its last two axes are the frame). The array itself when contiguous; a
        copy otherwise."""
        if self.identity or array is None:
            return array
        return irs2.science_image(array, self.irs2)

    def from_science(self, corrected, original):
        """The product frame(s) from corrected image(s).

        Parameters
        ----------
        corrected : ndarray
            As :meth:`to_science` shaped it.
        original : ndarray
            The frame(s) as they came (not modified): every sample outside
            the image is taken from here, bit for bit.

        Returns
        -------
        ndarray
            ``corrected`` itself when contiguous; else a new array of
            ``original``'s shape and dtype.
        """
        if self.identity:
            return corrected
        return irs2.interleave(corrected, original, self.irs2)

    def describe(self):
        return self.note or f"contiguous {self.shape[0]}x{self.shape[1]}"


def arrangement_of(primary, science, shape, label):
    """The :class:`Arrangement` of a product's frames.

    Parameters
    ----------
    primary, science : mapping
        The primary and science headers (``INSTRUME``, ``DETECTOR``,
        ``READPATT``, ``NRS_NORM``, ``NRS_REF``).
    shape : tuple of int
        The science array's shape (the last two axes are the frame).
    label : str
        The file and HDU, for messages (e.g. ``"jw01_uncal.fits[SCI]"``).

    Raises
    ------
    IPCInputError
        An interleaved frame that cannot be placed
        (:func:`ipc_taichi.products.irs2.irs2_geometry`).
    """
    frame = tuple(int(n) for n in tuple(shape)[-2:])
    if len(frame) < 2:
        return Arrangement.contiguous(frame)
    geometry = irs2.irs2_geometry(primary, science, frame, label)
    if geometry is not None:
        return Arrangement("irs2", frame, (irs2.DETECTOR_PIXELS, irs2.DETECTOR_PIXELS),
                           geometry, NEAR_IR_BORDER, geometry.describe())
    note = ""
    if irs2.is_irs2_pattern(irs2.header_value(primary, science, "READPATT")):
        note = "IRS2 read pattern, its interleaved reference samples already removed"
    return Arrangement.contiguous(frame, note)

"""NIRSpec IRS2 frames: interleaved reference pixels, taken out and put back.

In the IRS2 read patterns (``READPATT`` ``NRSIRS2`` and ``NRSIRS2RAPID``,
Rauscher et al. 2017) each of the four amplifier outputs of a NIRSpec
detector reads ``NRS_NORM`` (n) science pixels, then ``NRS_REF`` (r)
reference samples, then n science pixels again, and a fifth output (the
*reference output*) is read beside them. The raw frame, and every ramp until
the pipeline's ``refpix`` step strips them, therefore holds along one axis:

- the reference output: ``512 + (512 / n) * r`` samples;
- four amplifier outputs of ``512 + (512 / n) * r`` samples each, every one
  laid out as ``n/2`` science pixels, then ``(r reference, n science)``
  repeated, the last block holding ``n/2`` science pixels (a palindrome, so
  the positions do not depend on the output's readout direction).

With the flight values n = 16, r = 4 that axis has 5 x 640 = 3200 samples, of
which 2048 are the detector's pixels. JWST products are in the DMS
orientation, where that axis is the rows: a full frame is 3200 rows x 2048
columns; NRS1 has its reference output in rows 0-639, NRS2 (read out
mirrored) in rows 2560-3199. IRS2 is not taken in subarrays.

Neighbouring science rows are neighbouring pixels on the detector, even when
reference samples lie between them in the file: IPC couples them, and it never
couples a science pixel to a reference sample. So the coupling must be
removed from the *contiguous* science image (:func:`science_image`), and the
result put back with every reference sample exactly as it came
(:func:`interleave`). The facts are those of the JWST pipeline
(``jwst.ipc.x_irs2``, ``jwst.refpix.irs2_subtract_reference``,
``jwst.lib.pipe_utils.is_irs2``); arrangements it does not cover (odd n, n that
does not divide 512, other shapes, other detectors) are refused in one line
(:class:`~ipc_taichi.errors.IPCInputError`), never corrected as if contiguous.

Pure NumPy, no I/O: headers are mappings (``astropy.io.fits.Header`` or a
``dict``).
"""

from dataclasses import dataclass

import numpy as np

from ..errors import IPCInputError

__all__ = ["IRS2Geometry", "READ_PATTERNS", "irs2_geometry", "science_rows", "science_image",
           "interleave", "is_irs2_pattern", "header_value", "whole_number"]

READ_PATTERNS = ("NRSIRS2", "NRSIRS2RAPID")
"""The IRS2 read patterns of flight data (``READPATT``)."""

DETECTOR_PIXELS = 2048
"""Pixels of a NIRSpec detector along each axis (the 4-pixel border included)."""

OUTPUTS = 4
"""Amplifier outputs of the science pixels (the reference output is a fifth)."""

OUTPUT_PIXELS = DETECTOR_PIXELS // OUTPUTS  # science pixels per output: 512

FLIGHT_NORMAL, FLIGHT_REFERENCE = 16, 4
"""``NRS_NORM`` and ``NRS_REF`` of flight IRS2 data; the pipeline assumes them
when the keywords are missing, and so does :func:`irs2_geometry`."""

_DETECTORS = ("NRS1", "NRS2")


@dataclass(frozen=True)
class IRS2Geometry:
    """Where the science pixels of an IRS2 frame lie.

    Attributes
    ----------
    normal : int
        ``NRS_NORM``: science pixels read between two visits to the
        reference samples.
    reference : int
        ``NRS_REF``: reference samples read at each visit.
    detector : str
        ``"NRS1"`` (reference output first along the rows) or ``"NRS2"``
        (the order mirrored: reference output last).
    """

    normal: int = FLIGHT_NORMAL
    reference: int = FLIGHT_REFERENCE
    detector: str = "NRS1"

    @property
    def output_length(self):
        """Samples per output (the reference output's length too): 640 for 16/4."""
        return OUTPUT_PIXELS + OUTPUT_PIXELS // self.normal * self.reference

    @property
    def length(self):
        """Samples along the interleaved axis (the rows): 3200 for 16/4."""
        return (OUTPUTS + 1) * self.output_length

    @property
    def shape(self):
        """The frame in the DMS orientation: (rows, columns)."""
        return (self.length, DETECTOR_PIXELS)

    def describe(self):
        return (f"IRS2 {self.detector}, NRS_NORM = {self.normal}, NRS_REF = {self.reference} "
                f"({self.length} rows, {DETECTOR_PIXELS} of them science)")


def science_rows(geometry):
    """Which rows of the frame are detector pixels (True) and which are
    reference samples or the reference output (False): a 1-D bool array of
    ``geometry.length``."""
    n, r = geometry.normal, geometry.reference
    position = np.arange(geometry.output_length)  # within one output
    reference = (position >= n // 2) & ((position - n // 2) % (n + r) < r)
    rows = np.concatenate([np.zeros(geometry.output_length, dtype=bool)]
                          + [~reference] * OUTPUTS)
    return rows[::-1].copy() if geometry.detector == "NRS2" else rows


def science_image(frames, geometry):
    """The contiguous science image(s) of IRS2 frame(s): rows without the
    reference samples, in detector order (a copy).

    Parameters
    ----------
    frames : ndarray, shape (..., geometry.length, 2048)
        A frame, a ramp or its DQ planes, in the DMS orientation.
    geometry : IRS2Geometry

    Returns
    -------
    ndarray, shape (..., 2048, 2048)
    """
    _check_frame_shape(frames, geometry)
    return np.asarray(frames)[..., science_rows(geometry), :]


def interleave(science, original, geometry):
    """The IRS2 frame(s) ``original`` with its science rows replaced by
    ``science``: every reference sample bit for bit as in ``original``.

    Parameters
    ----------
    science : ndarray, shape (..., 2048, 2048)
        Corrected science image(s), as :func:`science_image` gave them.
    original : ndarray, shape (..., geometry.length, 2048)
        The frame(s) they came from; not modified.
    geometry : IRS2Geometry

    Returns
    -------
    ndarray
        A new array of ``original``'s shape and dtype.
    """
    _check_frame_shape(original, geometry)
    original = np.asarray(original)
    expected = original.shape[:-2] + (DETECTOR_PIXELS, DETECTOR_PIXELS)
    if np.shape(science) != expected:
        raise IPCInputError(f"IRS2 science image of shape {np.shape(science)} does not fit "
                            f"frames of shape {original.shape} (expected {expected})")
    out = original.copy()
    out[..., science_rows(geometry), :] = science
    return out


def _check_frame_shape(frames, geometry):
    if np.shape(frames)[-2:] != geometry.shape:
        raise IPCInputError(f"frames of shape {np.shape(frames)} are not an IRS2 frame of "
                            f"{geometry.length}x{DETECTOR_PIXELS} ({geometry.describe()})")


def is_irs2_pattern(readpatt):
    """Whether ``READPATT`` names an IRS2 read pattern of flight data."""
    return str(readpatt or "").strip().upper() in READ_PATTERNS


def irs2_geometry(primary, science, shape, label):
    """The :class:`IRS2Geometry` of a frame, ``None`` when it is not interleaved.

    A frame is interleaved when it is longer than the detector and its
    ``READPATT`` is an IRS2 pattern, or it is a NIRSpec frame without
    ``READPATT`` (the JWST pipeline's own rule, ``pipe_utils.is_irs2``, looks
    at the shape alone). A rate file of an IRS2 exposure, 2048 x 2048, has had
    its reference samples removed by the pipeline: ``None``. A NIRSpec frame
    longer than the detector with another ``READPATT`` is refused.
    ``NRS_NORM`` and ``NRS_REF`` default to the flight values 16 and 4, as in
    the pipeline; the frame's shape must then be the one they give.

    Parameters
    ----------
    primary, science : mapping
        The primary and science headers (a keyword is looked up in the
        science header first).
    shape : tuple of int
        The frame's shape (its last two axes are used).
    label : str
        The file and HDU, for messages.

    Raises
    ------
    IPCInputError
        An interleaved frame whose arrangement is not verified here (one line).
    """
    def get(key):
        return header_value(primary, science, key)

    if len(shape) < 2:
        return None
    ny, nx = tuple(shape)[-2:]
    readpatt = str(get("READPATT") or "").strip().upper()
    instrument = str(get("INSTRUME") or "").strip().upper()
    longer = max(ny, nx) > DETECTOR_PIXELS
    if not longer:
        if is_irs2_pattern(readpatt) and (ny, nx) != (DETECTOR_PIXELS, DETECTOR_PIXELS):
            raise IPCInputError(f"{label}: an IRS2 frame ({readpatt}) of {ny}x{nx} pixels, "
                                f"neither the interleaved full frame nor the {DETECTOR_PIXELS}x"
                                f"{DETECTOR_PIXELS} detector image (a cut-out): whether "
                                "reference samples are interleaved in it is unknown; refused")
        return None
    if not is_irs2_pattern(readpatt):
        if instrument != "NIRSPEC":
            return None
        if readpatt:
            raise IPCInputError(f"{label}: a NIRSpec frame of {ny}x{nx} pixels, longer than "
                                f"the detector's {DETECTOR_PIXELS}, with READPATT = {readpatt}, "
                                "not an IRS2 pattern: where its reference samples lie is "
                                "unknown; refused")
        readpatt = "no READPATT"  # the pipeline's rule: the shape says IRS2
    normal = _count(get("NRS_NORM"), FLIGHT_NORMAL, "NRS_NORM", label)
    reference = _count(get("NRS_REF"), FLIGHT_REFERENCE, "NRS_REF", label)
    if normal % 2 or OUTPUT_PIXELS % normal:
        raise IPCInputError(f"{label}: IRS2 with NRS_NORM = {normal}: only an even NRS_NORM "
                            f"that divides {OUTPUT_PIXELS} gives interleaving that does not "
                            "depend on each output's readout direction; refused")
    detector = str(get("DETECTOR") or "").strip().upper()
    if detector not in _DETECTORS:
        raise IPCInputError(f"{label}: an IRS2 frame with DETECTOR = {detector or '(none)'}: "
                            "the interleaving order is known for NRS1 and NRS2 only; refused")
    geometry = IRS2Geometry(normal, reference, detector)
    if (ny, nx) != geometry.shape:
        raise IPCInputError(f"{label}: an IRS2 frame ({readpatt}) of {ny}x{nx} pixels, not the "
                            f"full frame of {geometry.length}x{DETECTOR_PIXELS} that NRS_NORM = "
                            f"{normal} and NRS_REF = {reference} give (rows x columns, DMS "
                            "orientation): its reference samples cannot be placed; refused")
    return geometry


def _count(value, default, key, label):
    """A positive whole number from a keyword (``default`` when it is absent)."""
    if value is None:
        return default
    number = whole_number(value)
    if number is None:
        raise IPCInputError(f"{label}: {key} = {value!r} is not a positive whole number; "
                            "the IRS2 interleaving cannot be placed; refused")
    return number


def header_value(primary, science, key):
    """A keyword's value, from the science header first, then the primary;
    ``None`` when neither holds it (or holds an empty string)."""
    for header in (science, primary):
        value = header.get(key) if header is not None else None
        if value not in (None, ""):
            return value
    return None


def whole_number(value):
    """``value`` as an int when it is a whole number from 1 (``16``, ``16.0``,
    ``"16"``), else ``None``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    if not np.isfinite(number) or number < 1 or number != int(number):
        return None
    return int(number)

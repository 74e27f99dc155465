"""Option and header values that can mean nothing, refused before any pixel
changes, in one line naming the option or the keyword.

Each check is small and stands alone: :class:`~ipc_taichi.products.options.ProductOptions`
calls :func:`check_numbers` when it is built,
:func:`~ipc_taichi.products.conventions.parse_dq_bits` calls :func:`dq_word`
and the plan (:mod:`ipc_taichi.products.plan`) the others.
"""

import math
import os
import stat
from dataclasses import dataclass

import numpy as np

from ..decoupling import DecoupleInfo
from ..errors import IPCInputError

__all__ = ["check_input_file", "check_numbers", "dq_word", "check_pedestal", "header_gain",
           "check_gain_image", "FrameLost", "LostFrame", "LostFrames"]


def check_input_file(path):
    """An input that is not a regular file refused before it is opened: a
    directory, and a device or FIFO (``/dev/zero`` would be read without end, a
    FIFO such as ``<(zcat f.fits.gz)`` cannot be read twice, and opening one
    waits for a writer)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise IPCInputError(f"{path}: no such file") from None
    except OSError as exc:
        raise IPCInputError(f"{path}: cannot be read ({exc.strerror})") from None
    if stat.S_ISDIR(mode):
        raise IPCInputError(f"{path}: is a directory; give a product file")
    if not stat.S_ISREG(mode):
        kind = "a FIFO or pipe" if stat.S_ISFIFO(mode) else "a device or socket"
        raise IPCInputError(f"{path}: {kind}, not a regular file; give the file itself "
                            "(a .fits.gz is read as it is)")


def check_numbers(options):
    """``--coadds`` and ``--saturation`` (a mapping of option values) that
    can mean nothing: a count of exposures below 1 or not whole, a level not
    above zero or not finite."""
    coadds = options.get("coadds")
    if coadds is not None:
        try:
            whole = int(coadds) == coadds and int(coadds) >= 1
        except (TypeError, ValueError):
            whole = False
        if not whole:
            raise IPCInputError(f"--coadds {coadds}: needs a whole number of exposures >= 1")
    level = options.get("saturation")
    if level is not None:
        try:
            ok = math.isfinite(float(level)) and float(level) > 0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise IPCInputError(f"--saturation {level}: needs a level > 0 in data units (every "
                                "pixel at or above it is left out)")


def dq_word(value, given):
    """``value`` as a mask of a 32-bit DQ word; a bit above 31 (no DQ array
    holds one: it would leave nothing out) or a negative value refused."""
    if not 0 <= value < 2 ** 32:
        raise IPCInputError(f"--dq-bits {given}: DQ words have 32 bits (0..31); give a value "
                            f"from 0 to {2 ** 32 - 1}")
    return value


def check_pedestal(frame, option, physical_range):
    """A pedestal (electrons; a number or an image) no node can hold refused:
    not finite, or outside ``physical_range`` everywhere (it would leave every
    pixel NaN or unphysical)."""
    low, high = physical_range
    with np.errstate(invalid="ignore"):
        held = np.isfinite(frame) & (frame >= low) & (frame <= high)
    if not np.any(held):
        what = "charge" if np.ndim(frame) == 0 else "image with at least one finite pixel"
        raise IPCInputError(f"--pedestal {option}: needs a {what} from {low:g} to {high:g} "
                            "e- (the charge on the node before the first read)")


def header_gain(value, label):
    """A ``GAIN`` keyword's value as a number (None when absent): a header value
    is never read as a file, and a bad one is blamed on the keyword, not on
    ``--gain``."""
    if value is None or isinstance(value, (int, float, np.integer, np.floating)):
        return value
    try:
        return float(str(value))
    except ValueError:
        raise IPCInputError(f"{label}: header GAIN = {value!r} is not a number; give "
                            "--gain E_PER_DN") from None


def check_gain_image(unusable, label):
    """A gain image with no usable pixel (``unusable``: every pixel's verdict,
    :func:`~ipc_taichi.products.conventions.unusable_gain`) refused, naming
    the option: it would leave every pixel out."""
    if np.ndim(unusable) == 2 and np.all(unusable):
        raise IPCInputError(f"{label}: the gain image (--gain) has no usable pixel (every "
                            "value <= 0 or not finite)")


class FrameLost(IPCInputError):
    """A frame with no finite, unmasked pixel to correct (all NaN, flagged or
    unphysical)."""


@dataclass
class LostFrame(DecoupleInfo):
    """The record of a frame of a stack left as it came (:class:`LostFrames`):
    nothing to correct, so nothing to converge; ``lost`` says why."""

    lost: str = ""


class LostFrames:
    """The frames of a stack with nothing to correct (an all-flagged
    integration of a ``_rateints``, an all-NaN frame): each is left as it came,
    the others are corrected, and :meth:`said` is the one warning line; a
    lone frame, or every frame lost: refused as before."""

    def __init__(self, frames):
        self.frames, self.lost = frames, []

    def keep(self, exc, operation):
        """The record of the lost frame of ``exc`` (a :class:`FrameLost`);
        ``exc`` raised again where the frame cannot be left out."""
        self.lost.append(str(exc))
        if self.frames == 1 or len(self.lost) == self.frames:
            raise exc
        self.operation = operation
        return LostFrame(converged=True, lost=str(exc).rsplit(": ", 1)[-1]) \
            if operation == "decouple" else None

    def said(self):
        """The one warning line for the frames left as they came (None: none)."""
        if not self.lost:
            return None
        more = f" (and {len(self.lost) - 1} more frame(s) like it)" if len(self.lost) > 1 else ""
        return (f"{self.lost[0]}{more}: left as it was; the other "
                f"{self.frames - len(self.lost)} frame(s) are {self.operation}d")

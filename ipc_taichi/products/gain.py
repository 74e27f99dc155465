"""The gain (e-/DN) of a product, from a number, a keyword or a gain image.

One reader for FITS, Roman and the ``stpipe`` step; which pixels a per-pixel
gain cannot convert is :func:`ipc_taichi.products.conventions.unusable_gain`.
"""

import os

import numpy as np

from ..errors import IPCInputError
from .fitsfile import open_fits
from .missions import ROMAN, is_asdf

__all__ = ["read_gain", "read_frame"]


def read_gain(gain, shape2d):
    """``--gain``: None, a number, an array, or a gain image file (FITS: the
    first image HDU with data; Roman ASDF: its ``data``, trimmed to a level-2
    image's 4088x4088 when it is a 4096x4096 full frame)."""
    return read_frame(gain, shape2d, "gain")


def read_frame(gain, shape2d, what):
    """A per-frame quantity given as None, a number, an array or an image file
    (see :func:`read_gain`); ``what`` names it in errors."""
    if gain is None or isinstance(gain, (int, float, np.floating, np.integer, np.ndarray)):
        return gain
    text = str(gain)
    try:
        return float(text)
    except ValueError:
        pass
    if not os.path.isfile(text):
        why = "a directory" if os.path.isdir(text) else "no such file"
        raise IPCInputError(f"--{what} {text}: neither a number nor a readable {what} file "
                            f"({why})")
    if is_asdf(text):
        try:
            import roman_datamodels.datamodels as rdm

            with rdm.open(text) as ref:
                image = np.asarray(ref.data, dtype=np.float64)
        except ImportError:
            raise IPCInputError(f"{text}: a Roman {what} file needs roman_datamodels") from None
        except Exception as exc:
            raise IPCInputError(f"{text}: not a readable {what} file ({type(exc).__name__})"
                                ) from None
        if image.shape == ROMAN["full_frame"] and tuple(shape2d) == ROMAN["science_area"]:
            b = ROMAN["border"]
            image = image[b:-b, b:-b]
    else:
        try:
            hdul = open_fits(text, memmap=False)
        except IPCInputError as exc:
            reason = str(exc).removeprefix(f"{text}: ")
            raise IPCInputError(f"--{what} {text}: neither a number nor a readable {what} file "
                                f"({reason})") from None
        with hdul:
            image = next((np.array(h.data, dtype=np.float64) for h in hdul
                          if h.is_image and h.data is not None), None)
    if image is None or image.shape != tuple(shape2d):
        raise IPCInputError(f"{text}: a {what} image must be a {shape2d[0]}x{shape2d[1]} image, "
                            f"got {None if image is None else image.shape}")
    return image

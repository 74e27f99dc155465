"""Calibration inputs: darks, ramps and flats read as charge [e-] with their masks.

The product conventions are those of :mod:`ipc_taichi.products` (the same
science-HDU choice, BUNIT and gain rules, DQ bits, reference border as
``decouple``); this module only arranges the result for measuring:
every input becomes ``(nints, nframes, ny, nx)`` float64 electrons and a
boolean mask of the same shape (DQ bits, NaN, the reference border).
A 2-D frame is one integration of one frame; a 3-D stack is one integration
(a ramp's groups, or frames at one level); a 4-D ramp is as written.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import IPCInputError
from ..fitsio import parse_hdu
from ..products import conventions as cv
from ..products import missions
from ..products.fits import science_region_of
from ..products.fitsfile import flag_hdus, keyword, open_fits, read_array, science_indices, shape_of
from ..products.gain import read_gain

__all__ = ["ChargeFrames", "read_frames", "DEFAULT_DQ_BITS"]

DEFAULT_DQ_BITS = "DO_NOT_USE,SATURATED,JUMP_DET,DEAD"
"""DQ bits whose pixels are left out of every measurement (HOT and WARM are
not among them: hot pixels are what the darks are measured with)."""


@dataclass
class ChargeFrames:
    """Charge and mask of one input file."""

    path: str
    label: str
    data: np.ndarray  # (nints, nframes, ny, nx) electrons
    mask: np.ndarray  # same shape, True = not trusted
    units: str
    meta: dict = field(default_factory=dict)

    @property
    def shape2d(self):
        return self.data.shape[-2:]


def _as4d(array):
    a = np.asarray(array)
    return a.reshape((1,) * (4 - a.ndim) + a.shape)


def read_frames(path, hdu=None, gain=None, dq_bits=DEFAULT_DQ_BITS, refpix=None, bunit=None):
    """Read a dark, ramp or flat product into :class:`ChargeFrames`.

    Parameters
    ----------
    path : str
        FITS (JWST layout or plain) or Roman ASDF.
    hdu : int, str or None
        Science HDU (FITS; default SCI, else the first image HDU).
    gain : float, str or None
        e-/DN for data in DN (default: the file's GAIN keyword).
    dq_bits : str or int
        See :data:`DEFAULT_DQ_BITS`.
    refpix : int or None
        Reference border (default: the product's, as for ``decouple``).
    bunit : str or None
        Override the file's units.
    """
    if missions.is_asdf(path):
        return _read_asdf(path, gain, dq_bits, refpix, bunit)
    return _read_fits(path, hdu, gain, dq_bits, refpix, bunit)


def _read_fits(path, hdu, gain, dq_bits, refpix, bunit):
    hdul = open_fits(path, memmap=False)
    with hdul:
        index, label = science_indices(path, hdul, parse_hdu(hdu))[0]
        shape = shape_of(hdul[index].header)
        shape2d = shape[-2:]
        units = cv.parse_units(bunit if bunit is not None else keyword(hdul, index, "BUNIT"),
                               label)
        if units.rate:
            raise IPCInputError(f"{label}: a rate ({units.text}); calibrate needs darks, ramps "
                                "or flats of accumulated charge (DN or electrons)")
        gain_value = read_gain(gain if gain is not None else keyword(hdul, index, "GAIN"),
                               shape2d)
        scale, units_text = cv.charge_scale(units, gain_value, None, label)
        data = np.asarray(read_array(path, hdul, index), dtype=np.float64) * scale
        mission = missions.recognise(hdul[0].header, hdul[index].header)
        bits = _file_dq_bits(hdul, dq_bits, label)
        if bits is None:
            bits = cv.parse_dq_bits(dq_bits, mission.dq_flags) & ~cv.REFERENCE_PIXEL
        flags = flag_hdus(hdul, index, shape, path)
        region, inside = science_region_of(path, hdul, index, flags, shape2d, refpix, mission,
                                           label)
        mask = np.zeros(shape, dtype=bool)
        for k in flags:
            mask |= (np.asarray(read_array(path, hdul, k)).astype(np.int64) & bits) != 0
        saturate = keyword(hdul, index, "SATURATE")
    return _finish(path, label, data, mask, region, inside, units_text,
                   {"saturation": None if saturate is None else float(saturate) * np.max(scale)})


def _file_dq_bits(hdul, dq_bits, label):
    """The bits of ``dq_bits`` by the file's own ``DQ_DEF`` table alone
    (reference files define their own: a NIRSpec dark has HOT = 4, which is
    JUMP_DET in science products, so the mission's names must not fill in);
    None when the file has no such table. Names the table does not define
    are left out."""
    names = missions.dq_def(hdul)
    if not names:
        return None
    bits = 0
    for item in str(dq_bits).replace("+", ",").split(","):
        item = item.strip()
        if item.isdigit():
            bits |= int(item)
        elif item.upper() in names:
            bits |= names[item.upper()]
    return bits & ~(2 ** 31)


def _read_asdf(path, gain, dq_bits, refpix, bunit):
    try:
        import roman_datamodels.datamodels as rdm
    except ImportError:
        raise IPCInputError(f"{path}: Roman ASDF needs roman_datamodels") from None
    label = f"{path}[data]"
    try:
        dm = rdm.open(path)
    except Exception as exc:
        raise IPCInputError(f"{path}: not a readable Roman datamodel ({type(exc).__name__})") \
            from None
    with dm:
        data = np.asarray(dm.data, dtype=np.float64)
        units = cv.parse_units(bunit if bunit is not None else "DN", label)
        scale, units_text = cv.charge_scale(units, gain, None, label)
        data = data * scale
        bits = cv.parse_dq_bits(dq_bits, missions.roman_mission().dq_flags) & ~cv.REFERENCE_PIXEL
        mask = np.zeros(data.shape, dtype=bool)
        for name in ("pixeldq", "groupdq", "dq"):
            if name in dm and dm[name] is not None:
                f = np.asarray(dm[name]).astype(np.int64)
                if f.shape != data.shape[data.ndim - f.ndim:]:
                    raise IPCInputError(f"{path}[{name}]: shape {f.shape} does not match the "
                                        f"data {data.shape}")
                mask |= (f & bits) != 0
    region, inside = cv.science_region(data.shape[-2:], refpix, None)
    return _finish(path, label, data, mask, region, inside, units_text, {})


def _finish(path, label, data, mask, region, inside, units_text, meta):
    mask = mask | ~np.isfinite(data)
    outside = np.ones(data.shape[-2:], dtype=bool)
    outside[region] = False
    if inside is not None:
        outside[region] |= inside
    mask |= outside
    data = np.where(mask, np.nan, data)
    return ChargeFrames(path, label, _as4d(data), _as4d(mask), units_text, meta)

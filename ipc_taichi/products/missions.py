"""Where a product comes from, and the conventions of its observatory.

One place decides what kind of file a product is and reads its observatory's
conventions from it (``docs/products.md`` says the same in words):

- **Instrument products.** A FITS file with a ``TELESCOP`` or an
  ``INSTRUME`` of any observatory (JWST, HST, a ground H2RG such as LBT
  LUCI2, ...), and every Roman ASDF product. The paper's law was measured on
  one test detector: it is never applied to an instrument's data silently;
  without ``--law`` or ``--model`` it is refused (:func:`check_model_chosen`).
  Such a file is also a *detector product*: the edge rule is chosen from it.
  JWST, HST and Roman products get their observatory's conventions below.
- **Reference borders** of full frames: JWST 4 pixels (2048x2048; a subarray
  by its ``SUBSTRT``/``SUBSIZE`` keywords), HST WFC3/IR 5 pixels (the
  ``_ima`` frames of 1024, 522, 266, 138 and 74 pixels; ``_flt`` frames are
  already trimmed), Roman 4 pixels (4096x4096 ramps).
- **DQ bit names**: JWST's (``stdatamodels`` when installed), HST's
  (:data:`HST_DQ_FLAGS`), Roman's (``roman_datamodels``); a file's own
  ``DQ_DEF`` table comes first.
- **Integration time** (rates), in this order: ``--exptime``; ``SAMPTIME`` of
  the science HDU (HST MULTIACCUM reads); ``EFFINTTM`` (JWST); ``EXPTIME``
  (HST, cut-outs); each looked up in the science header, then the primary.
- **Coadds**: a frame that sums ``NCOADDS`` or ``NDIT`` exposures holds that
  many times the charge that was on the node; the law sees the charge of one.
- **Bias products** (``REFTYPE`` or ``FILETYPE`` naming a bias or superbias)
  hold no collected charge and are refused, like raw ``_uncal`` ramps.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import IPCInputError

__all__ = ["Mission", "recognise", "roman_mission", "reference_mask", "HST_DQ_FLAGS",
           "JWST_DQ_FLAGS", "REFERENCE_PIXEL", "check_model_chosen", "check_not_bias",
           "is_asdf", "TIME_KEYWORDS", "COADD_KEYWORDS", "DEFAULT_DQ"]

JWST_DQ_FLAGS = {
    "GOOD": 0, "DO_NOT_USE": 1, "SATURATED": 2, "JUMP_DET": 4, "DROPOUT": 8,
    "NON_SCIENCE": 2 ** 9, "DEAD": 2 ** 10, "HOT": 2 ** 11, "WARM": 2 ** 12,
    "REFERENCE_PIXEL": 2 ** 31,
}
"""The JWST data-quality bits this package relies on, used when ``stdatamodels``
(which has the full table) is not installed."""

REFERENCE_PIXEL = JWST_DQ_FLAGS["REFERENCE_PIXEL"]

HST_DQ_FLAGS = {
    "GOOD": 0, "REED_SOLOMON": 1, "DATA_FILL": 2, "BAD_DETECTOR": 4, "ZERO_READ_DEVIANT": 8,
    "HOT": 16, "UNSTABLE": 32, "WARM": 64, "BAD_REFERENCE": 128, "SATURATED": 256,
    "BAD_FLAT": 512, "ZERO_READ_SIGNAL": 1024, "CR_RAMP": 4096, "CR": 8192,
    "DO_NOT_USE": 1 | 2 | 4,
}
"""HST WFC3/IR data-quality bits. ``DO_NOT_USE`` is this package's name for
the bits that say the value is lost or the pixel is bad (Reed-Solomon error,
fill, bad detector pixel); HST itself has no such bit."""

DEFAULT_DQ = "DO_NOT_USE,SATURATED"
"""Pixels left out unless ``--dq-bits`` says otherwise: the unusable and the
saturated (the charge on a saturated node is unknown, so it can neither give
nor take its share)."""

TIME_KEYWORDS = ("SAMPTIME", "EFFINTTM", "EXPTIME")
COADD_KEYWORDS = ("NCOADDS", "NDIT")
BIAS_TYPES = ("SUPERBIAS", "BIAS")
_JWST_NEAR_IR = ("NIRCAM", "NIRSPEC", "NIRISS", "FGS")
_WFC3_IR_FRAMES = (1024, 522, 266, 138, 74)  # _ima: the science area plus 5-pixel borders


@dataclass(frozen=True)
class Mission:
    """The observatory conventions of one product.

    Attributes
    ----------
    name : str
        ``"JWST"``, ``"HST"``, ``"Roman"``, another ``TELESCOP``, or ``""``
        (a plain image that says nothing about where it comes from).
    instrument : str
    instrument_product : bool
        A product of an instrument (any ``TELESCOP`` or ``INSTRUME``, or
        Roman): the law must be chosen (see :func:`check_model_chosen`).
    dq_flags : dict
        Flag name -> bit value (the file's ``DQ_DEF`` first).
    """

    name: str = ""
    instrument: str = ""
    instrument_product: bool = False
    dq_flags: dict = field(default_factory=lambda: dict(JWST_DQ_FLAGS), compare=False)

    @property
    def detector_product(self):
        """Whether the file says where it comes from (then the edge rule is
        chosen from it: see :func:`ipc_taichi.products.conventions.choose_edge`)."""
        return bool(self.name or self.instrument)

    def describe(self):
        return " ".join(x for x in (self.name, self.instrument) if x) or "a plain image"


def _flag_table(mission):
    try:
        if mission == "Roman":
            from roman_datamodels.dqflags import pixel
        else:
            from stdatamodels.jwst.datamodels.dqflags import pixel
    except ImportError:
        return dict(JWST_DQ_FLAGS)
    return {str(k): int(v) for k, v in dict(
        pixel.__members__ if hasattr(pixel, "__members__") else pixel).items()}


def dq_def(hdul):
    """Name -> bit from a ``DQ_DEF`` table (columns NAME and VALUE), or {}."""
    for h in hdul:
        if (h.name or "").upper() != "DQ_DEF" or h.data is None:
            continue
        names = [c.upper() for c in h.columns.names]
        if "NAME" not in names or "VALUE" not in names:
            return {}
        return {str(n).strip().upper(): int(v)
                for n, v in zip(h.data.field("NAME"), h.data.field("VALUE"))}
    return {}


def recognise(primary, science=None, hdul=None):
    """The :class:`Mission` of a FITS product from its headers (and its
    ``DQ_DEF`` table when ``hdul`` is given)."""
    science = science if science is not None else primary

    def get(key):
        for h in (primary, science):
            value = h.get(key)
            if value not in (None, ""):
                return str(value).strip().upper()
        return ""

    telescope, instrument = get("TELESCOP"), get("INSTRUME")
    if telescope.startswith("HST") or (not telescope and instrument in ("WFC3", "NICMOS")):
        name, flags = "HST", dict(HST_DQ_FLAGS)
    elif telescope == "JWST" or (not telescope and instrument in _JWST_NEAR_IR + ("MIRI",)):
        name, flags = "JWST", _flag_table("JWST")
    elif telescope.startswith("ROMAN"):
        name, flags = "Roman", _flag_table("Roman")
    else:
        name, flags = telescope, dict(JWST_DQ_FLAGS)
    flags.update(dq_def(hdul) if hdul is not None else {})
    return Mission(name, instrument, bool(name or instrument), flags)


def roman_mission():
    """The Roman conventions, with ``roman_datamodels``' DQ names."""
    return Mission("Roman", "WFI", True, _flag_table("Roman"))


def check_model_chosen(mission, explicit, label):
    """Refuse the paper's default law on an instrument product (one line)."""
    if mission.instrument_product and not explicit:
        raise IPCInputError(
            f"{label}: a {mission.describe()} product: the paper's law (donlon2018) is not "
            "this detector's coupling; measure it with 'ipc-taichi calibrate' and give "
            "--model FILE, or choose --law explicitly")


def check_not_bias(primary, label):
    """Refuse a bias or superbias product: bias is not collected charge."""
    for key in ("REFTYPE", "FILETYPE"):
        value = str(primary.get(key, "")).strip().upper()
        if value in BIAS_TYPES:
            raise IPCInputError(f"{label}: a {value.lower()} ({key} = {value}) holds bias, not "
                                "collected charge; IPC acts on charge: decouple the products "
                                "it calibrates")


def reference_mask(mission, primary, science, shape2d):
    """The reference pixels the observatory's conventions place in this frame
    (bool array), or None."""
    ny, nx = shape2d
    get = (lambda k: science.get(k, primary.get(k)))
    if mission.name == "HST" and mission.instrument == "WFC3" and \
            str(get("DETECTOR") or "").upper() == "IR" and ny == nx and ny in _WFC3_IR_FRAMES:
        return _border(shape2d, 5, 5, 5, 5)
    if mission.name == "JWST" and mission.instrument in _JWST_NEAR_IR:
        full = 2048
        if str(get("SUBARRAY") or "").upper() == "FULL" and shape2d == (full, full):
            return _border(shape2d, 4, 4, 4, 4)
        try:
            x0, y0 = int(get("SUBSTRT1")), int(get("SUBSTRT2"))  # 1-based detector pixels
        except (TypeError, ValueError):
            return None
        left, bottom = max(0, 5 - x0), max(0, 5 - y0)
        right, top = max(0, x0 - 1 + nx - (full - 4)), max(0, y0 - 1 + ny - (full - 4))
        if left or bottom or right or top:
            return _border(shape2d, min(left, nx), min(right, nx), min(bottom, ny),
                           min(top, ny))
    return None


def _border(shape2d, left, right, bottom, top):
    mask = np.zeros(shape2d, dtype=bool)
    mask[:bottom] = True
    mask[shape2d[0] - top:] = True
    mask[:, :left] = True
    mask[:, shape2d[1] - right:] = True
    return mask


def is_asdf(path):
    """Whether ``path`` names an ASDF file (by its first bytes, else its name)."""
    try:
        with open(path, "rb") as f:
            return f.read(5) == b"#ASDF"
    except OSError:
        return str(path).lower().endswith(".asdf")

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
- **Reference borders** (:func:`reference_border`, what
  :func:`ipc_taichi.products.plan.science_region_of` falls back on without
  ``REFERENCE_PIXEL`` flags): JWST near-IR 4 pixels on each side of the
  2048x2048 detector, MIRI 4 columns on each side of its 1032-column
  detector (no rows), as the JWST ``ipc`` step's ``get_num_ref_pixels``
  counts them; a subarray gets the sides that reach the detector's border,
  from the geometry keywords of the science array's own header
  (``SUBSTRT1/2``, or a NIRSpec slit cut-out's ``SLTSTRT1/2``), or of the
  primary header only when its ``SUBSIZE1/2`` say it describes this array
  (an MSA slit cut-out is not the whole exposure); HST WFC3/IR 5 pixels
  (the ``_ima`` frames of 1024, 522, 266, 138 and 74 pixels; ``_flt``
  frames are already trimmed); Roman 4 pixels (4096x4096 ramps), and a
  level-2 4088x4088 image is the science area with its border stored apart.
- **DQ bit names**: JWST's (``stdatamodels`` when installed), HST's
  (:data:`HST_DQ_FLAGS`), Roman's (``roman_datamodels``); a file with its
  own ``DQ_DEF`` table is read by that table alone (``Mission.dq_def``; see
  :func:`ipc_taichi.products.plan.dq_bits_of`).
- **Roman** (:data:`ROMAN`): units from the product's kind (ramps DN, level-2
  DN/s until its flux step, then MJy/sr: :func:`roman_units`), the time from
  ``meta.exposure`` (:func:`roman_keywords`; -999999 and other values <= 0
  mean unset), the gain from a reference file.
- **Integration time** (rates), in this order: ``--exptime``; ``SAMPTIME`` of
  the science HDU (HST MULTIACCUM reads); ``EFFINTTM`` (JWST); ``EXPTIME``
  (HST, cut-outs); each looked up in the science header, then the primary.
- **Coadds**: a frame that sums ``NCOADDS`` or ``NDIT`` exposures holds that
  many times the charge that was on the node; the law sees the charge of one.
- **Bias products** (``REFTYPE`` or ``FILETYPE`` naming a bias or superbias)
  hold no collected charge and are refused, like raw ``_uncal`` ramps.
"""

import importlib.util
import os
import sys
from dataclasses import dataclass, field

import numpy as np

from ..errors import IPCInputError
from .irs2 import whole_number

__all__ = ["Mission", "Border", "recognise", "roman_mission", "reference_border", "HST_DQ_FLAGS",
           "JWST_DQ_FLAGS", "REFERENCE_PIXEL", "check_model_chosen", "check_not_bias",
           "is_asdf", "TIME_KEYWORDS", "COADD_KEYWORDS", "DEFAULT_DQ", "ROMAN", "roman_units",
           "roman_keywords", "jwst_units"]

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
_JWST_FULL = {"near-IR": (2048, 2048), "MIRI": (1024, 1032)}  # (rows, columns)
_JWST_BORDER = 4
_WFC3_IR_FRAMES = (1024, 522, 266, 138, 74)  # _ima: the science area plus 5-pixel borders
_WFC3_IR_BORDER = 5

ROMAN = {
    "full_frame": (4096, 4096),
    "border": 4,
    "science_area": (4088, 4088),
    "time_fields": ("effective_exposure_time", "exposure_time"),
    "time_source": "meta.exposure.effective_exposure_time",
    "gain_source": "a gain reference file (--gain FILE.asdf)",
    "units_source": "units (meta.cal_step.flux)",
}
"""Roman WFI conventions: a 4096x4096 detector with a 4-pixel reference border;
a level-2 image is its 4088x4088 science area, the border stored apart (so its
edge has zero-signal neighbours); where the time and the gain are found."""


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
        Flag name -> bit value: the mission's names.
    dq_def : dict
        Flag name -> bit value of the file's own ``DQ_DEF`` table ({} when it
        has none); when given, the only names the file's flags are read by.
    time_keywords : tuple
        Where the integration time of a rate is looked for, in order.
    time_source, gain_source, units_source : str
        Where the time, the gain and the units come from, for messages.
    """

    name: str = ""
    instrument: str = ""
    instrument_product: bool = False
    dq_flags: dict = field(default_factory=lambda: dict(JWST_DQ_FLAGS), compare=False)
    dq_def: dict = field(default_factory=dict, compare=False)
    time_keywords: tuple = TIME_KEYWORDS
    time_source: str = "a SAMPTIME, EFFINTTM or EXPTIME keyword"
    gain_source: str = "a GAIN keyword"
    units_source: str = "BUNIT"

    def flag(self, name):
        """The bit of flag ``name`` by the file's ``DQ_DEF`` when it has one,
        else by the mission's names (0 when undefined)."""
        return int((self.dq_def or self.dq_flags).get(name, 0))

    @property
    def detector_product(self):
        """Whether the file says where it comes from (then the edge rule is
        chosen from it: see :func:`ipc_taichi.products.plan.edge_of`)."""
        return bool(self.name or self.instrument)

    def describe(self):
        return " ".join(x for x in (self.name, self.instrument) if x) or "a plain image"


def _roman_pixel_flags():
    """roman_datamodels' pixel DQ flags, from its ``dqflags.py`` run on its own
    (it imports only ``enum`` and NumPy): importing the package builds its
    whole schema tree first, 2 s of a command line's start."""
    if "roman_datamodels.dqflags" in sys.modules:
        return sys.modules["roman_datamodels.dqflags"].pixel
    spec = importlib.util.find_spec("roman_datamodels")
    if spec is None or spec.origin is None:
        raise ImportError("roman_datamodels is not installed")
    single = importlib.util.spec_from_file_location(
        "ipc_taichi.products._roman_dqflags", os.path.join(os.path.dirname(spec.origin),
                                                           "dqflags.py"))
    module = importlib.util.module_from_spec(single)
    try:
        single.loader.exec_module(module)
    except (OSError, ImportError):  # laid out otherwise: the package's own import
        from roman_datamodels.dqflags import pixel
        return pixel
    return module.pixel


def _flag_table(mission):
    try:
        if mission == "Roman":
            pixel = _roman_pixel_flags()
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
    own = dq_def(hdul) if hdul is not None else {}
    return Mission(name, instrument, bool(name or instrument), flags, own)


def roman_mission():
    """The Roman conventions, with ``roman_datamodels``' DQ names."""
    return Mission("Roman", "WFI", True, _flag_table("Roman"),
                   time_keywords=ROMAN["time_fields"], time_source=ROMAN["time_source"],
                   gain_source=ROMAN["gain_source"], units_source=ROMAN["units_source"])


def roman_units(kind, meta):
    """The units of a Roman product's ``data``: DN for ramps; DN/s for a
    level-2 image until its flux step has run (then MJy/sr, refused)."""
    if kind == "RampModel":
        return "DN"
    steps = meta.get("cal_step", {}) if hasattr(meta, "get") else {}
    flux = steps.get("flux") if hasattr(steps, "get") else None
    return "MJy/sr" if flux == "COMPLETE" else "DN/s"


def roman_keywords(kind, meta):
    """A keyword look-up for a Roman product: ``BUNIT`` (:func:`roman_units`)
    and the ``meta.exposure`` times of :data:`ROMAN` (unset, None, when not
    positive: -999999 is Roman's fill value); anything else None."""
    exposure = meta.get("exposure", {}) if hasattr(meta, "get") else {}

    def get(key):
        if key == "BUNIT":
            return roman_units(kind, meta)
        if key in ROMAN["time_fields"]:
            value = exposure.get(key) if hasattr(exposure, "get") else None
            return float(value) if value is not None and float(value) > 0 else None
        return None
    return get


def jwst_units(ndim):
    """The units of a JWST datamodel's ``data`` that carries no ``bunit_data``:
    a 4-D ramp holds DN, a rate image or cube DN/s."""
    return "DN" if ndim == 4 else "DN/s"


def check_model_chosen(mission, explicit, label):
    """Refuse the paper's default law on an instrument product (one line)."""
    if mission.instrument_product and not explicit:
        raise IPCInputError(
            f"{label}: a {mission.describe()} product: the paper's law (donlon2018) is not "
            "this detector's coupling; measure it with 'ipc-taichi calibrate' and give "
            "--model FILE, or choose --law explicitly")


def check_not_bias(primary, label):
    """Refuse a bias or superbias product: bias is not collected charge.
    ``primary``: its header (or a keyword look-up, ``key -> value``)."""
    get = primary if callable(primary) else primary.get
    for key in ("REFTYPE", "FILETYPE"):
        value = str(get(key) or "").strip().upper()
        if value in BIAS_TYPES:
            raise IPCInputError(f"{label}: a {value.lower()} ({key} = {value}) holds bias, not "
                                "collected charge; IPC acts on charge: decouple the products "
                                "it calibrates")


@dataclass(frozen=True)
class Border:
    """Reference pixels on each side of a frame, by an observatory's convention
    (the JWST ``ipc`` step's ``NumRefPixels``); ``stored_apart``: the frame is
    a science area whose reference border is kept elsewhere (Roman level 2)."""

    bottom: int
    top: int
    left: int
    right: int
    source: str
    stored_apart: bool = False

    def mask(self, shape2d):
        """The reference pixels of a frame of ``shape2d`` (bool array)."""
        ny, nx = shape2d
        mask = np.zeros(shape2d, dtype=bool)
        mask[:min(self.bottom, ny)] = True
        mask[ny - min(self.top, ny):] = True
        mask[:, :min(self.left, nx)] = True
        mask[:, nx - min(self.right, nx):] = True
        return mask


def _origin(own, product, shape2d):
    """The frame's first pixel on the detector (1-based x, y) and where it
    was read: the science header's own ``SUBSTRT1/2`` (or a slit cut-out's
    ``SLTSTRT1/2``), else the primary's when its ``SUBSIZE1/2`` (if any) are
    this frame's size; None when nothing describes this frame."""
    ny, nx = shape2d
    for keys in (("SUBSTRT1", "SUBSTRT2"), ("SLTSTRT1", "SLTSTRT2")):
        x0, y0 = own(keys[0]), own(keys[1])
        if x0 is not None and y0 is not None:
            return _pixel(keys[0], x0), _pixel(keys[1], y0), f"{keys[0][:-1]}1/2"
    x0, y0 = product("SUBSTRT1"), product("SUBSTRT2")
    size = (product("SUBSIZE1"), product("SUBSIZE2"))
    if x0 is None or y0 is None:
        return None
    if None not in size and (whole_number(size[0]), whole_number(size[1])) != (nx, ny):
        return None  # the whole exposure's, not this cut-out's
    return _pixel("SUBSTRT1", x0), _pixel("SUBSTRT2", y0), "SUBSTRT1/2"


def _pixel(key, value):
    """A 1-based detector position from a geometry keyword (refused when not
    a whole number from 1)."""
    number = whole_number(value)
    if number is None:
        raise IPCInputError(f"{key} = {value!r} is not a pixel of the detector (a whole "
                            "number from 1); its reference pixels cannot be placed; refused")
    return number


def reference_border(mission, own, product, shape2d):
    """The reference pixels the observatory's conventions place in a frame.

    Parameters
    ----------
    mission : Mission
    own, product : callable
        ``key -> value or None``: the science array's own header, and its
        product's (primary) header.
    shape2d : (int, int)

    Returns
    -------
    Border or None
    """
    ny, nx = shape2d
    get = (lambda k: own(k) if own(k) is not None else product(k))
    if mission.name == "HST" and mission.instrument == "WFC3" and \
            str(get("DETECTOR") or "").upper() == "IR" and ny == nx and ny in _WFC3_IR_FRAMES:
        n = _WFC3_IR_BORDER
        return Border(n, n, n, n, "WFC3/IR _ima frame")
    if mission.name == "Roman":
        n = ROMAN["border"]
        if tuple(shape2d) == ROMAN["full_frame"]:
            return Border(n, n, n, n, "Roman full frame")
        if tuple(shape2d) == ROMAN["science_area"]:
            return Border(0, 0, 0, 0, "Roman level-2 science area: border stored apart", True)
        return None
    if mission.name != "JWST" or mission.instrument not in _JWST_NEAR_IR + ("MIRI",):
        return None
    miri = mission.instrument == "MIRI"
    full_y, full_x = _JWST_FULL["MIRI" if miri else "near-IR"]
    n = _JWST_BORDER
    origin = _origin(own, product, shape2d)
    if origin is None:
        if tuple(shape2d) != (full_y, full_x):
            return None
        x0, y0, source = 1, 1, "full frame"
    else:
        x0, y0, source = origin
    if x0 - 1 + nx > full_x or y0 - 1 + ny > full_y:
        raise IPCInputError(f"a {mission.instrument} frame of {ny}x{nx} pixels from SUBSTRT1/2 "
                            f"= {x0}, {y0} runs past the detector's {full_y}x{full_x}; refused")
    x0, y0 = x0 - 1, y0 - 1  # 0-based
    bottom, top = (0, 0) if miri else (max(0, n - y0), max(0, y0 + ny - (full_y - n)))
    left, right = max(0, n - x0), max(0, x0 + nx - (full_x - n))
    if not (bottom or top or left or right):
        return None
    return Border(bottom, top, left, right, f"{mission.instrument} {source}")


def is_asdf(path):
    """Whether ``path`` names an ASDF file (by its first bytes, else its name)."""
    try:
        with open(path, "rb") as f:
            return f.read(5) == b"#ASDF"
    except OSError:
        return str(path).lower().endswith(".asdf")

"""The plan of a product: everything decided about it before any pixel changes.

Every path that corrects a product asks this module, in one sequence
(:func:`plan_product`): FITS (:func:`ipc_taichi.products.fits.process_fits`),
Roman ASDF (:func:`ipc_taichi.products.roman.process_asdf`), the JWST Step
(:func:`ipc_taichi.products.jwst_step.correct_model`) and calibrate's reader
(:mod:`ipc_taichi.calibrate.inputs`, which asks :func:`dq_bits_of` and
:func:`science_region_of`). A reader only says what its file holds, as one
:class:`ArrayFacts` per science array (its shape, a keyword look-up of its
own header and of its product's, its ``REFERENCE_PIXEL`` flags); the
decisions, in this order, are made here:

1. **DQ bits** (:func:`dq_bits_of`): the names of the file's own ``DQ_DEF``
   when it has one, else its mission's
   (:mod:`~ipc_taichi.products.missions`); a name the ``DQ_DEF`` lacks is
   said in one line and never taken from another table.
2. **Units and gain** (:func:`units_of`): ``--bunit`` or ``BUNIT`` (a Roman
   product's kind); with neither, DN when a gain is known (``--gain`` or a
   ``GAIN`` keyword), else electrons: one rule for decouple and calibrate;
   ``--gain`` or ``GAIN``; for a rate, the integration time (``--exptime``,
   else the mission's time keywords); ``--coadds`` or ``NCOADDS``/``NDIT``;
   hence electrons per data unit
   (:func:`~ipc_taichi.products.conventions.charge_scale`).
3. **Science region** (:func:`science_region_of`): how the frame is read out (its
   :class:`~ipc_taichi.products.arrangement.Arrangement`: contiguous, or NIRSpec
   IRS2 with reference samples interleaved), then the science region inside
   the reference pixels of the contiguous image (``--refpix``, else the
   ``REFERENCE_PIXEL`` flags, else the observatory's convention,
   :func:`~ipc_taichi.products.missions.reference_border`) and what lies beyond its edge.
4. **Edge** (:func:`edge_of`): the model says which edge rule it asks for;
   the product's frame decides what it gets.
5. **Pedestal**: the charge on the node before the first read.

Whether the noise arrays beside the science one (``ERR``, ``VAR_*``) are
propagated is asked of :func:`ipc_taichi.products.noise_arrays.noise_of`.
The per-array work happens after, in the readers, one :class:`ArrayPlan` at a
time: :func:`~ipc_taichi.products.correction.correct_frames` takes the array's
plan as it is, with the run's
:class:`~ipc_taichi.products.correction.RunSettings`; the record of the run
is built from the same two
(:class:`~ipc_taichi.products.provenance.Provenance`).
"""

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import IPCInputError
from ..model import CouplingModel
from . import arrangement as arrangements
from . import conventions as cv
from . import missions
from .checks import check_gain_image, check_pedestal, header_gain
from .gain import read_frame, read_gain

__all__ = ["ArrayFacts", "ArrayPlan", "ScienceRegion", "ProductPlan", "Zeroth", "plan_product",
           "plan_array", "units_of", "units_in", "dq_bits_of", "say_lacking",
           "arrangement_of", "science_region_of", "edge_of", "BEYOND"]

BEYOND = ("reference", "pixels", "unknown")
"""What lies beyond a science region's edge: reference pixels (zero-signal
neighbours), pixels holding charge like its own (a subarray or cut-out of a
detector product), or unknown (a plain image)."""


def _none(key):
    return None


@dataclass(frozen=True)
class ArrayFacts:
    """What a product says about one science array, however it is stored.

    Attributes
    ----------
    index : int
        Where the array is (the FITS HDU index; 0 for an ASDF ``data``).
    name : str
        Its name in the records (``SCI``, ``SCI,2``, ``data``).
    label : str
        The file and array, for messages (``file.fits[SCI]``).
    shape : tuple
    own, product : callable
        ``key -> value or None``: the array's own header and its product's
        (primary) header; FITS keyword names.
    reference : callable, optional
        ``() -> ndarray of bool or None``: the ``REFERENCE_PIXEL`` flags of
        the first frame.
    zeroth : bool
        The zeroth read of a multi-read product (charge since reset, not a rate).
    """

    index: int
    name: str
    label: str
    shape: tuple
    own: Callable = _none
    product: Callable = _none
    reference: Callable = None
    zeroth: bool = False

    def keyword(self, key):
        """``key`` from the array's own header, else the product's."""
        value = self.own(key)
        return value if value not in (None, "") else self.product(key)


@dataclass(frozen=True)
class Zeroth:
    """A multi-read product's zeroth read: its label, frame shape and its
    charge (``gain -> ndarray``, electrons)."""

    text: str
    shape2d: tuple
    charge: Callable


class _Header:
    """A keyword look-up (``key -> value or None``) as the mapping
    :mod:`~ipc_taichi.products.arrangement` reads."""

    def __init__(self, lookup):
        self.lookup = lookup

    def get(self, key, default=None):
        value = self.lookup(key)
        return default if value is None else value


@dataclass(frozen=True)
class ScienceRegion:
    """Where the science is in a frame.

    Attributes
    ----------
    shape : (int, int)
        The contiguous image of the frame (:attr:`arrangement`'s
        ``science_shape``; the stored frame itself unless interleaved).
    slices : (slice, slice)
        The science region inside the reference pixels, as the frame's slices.
    inside : ndarray of bool or None
        Reference-flagged pixels inside ``slices`` (treated as masked).
    beyond : str
        What lies beyond the region's edge (:data:`BEYOND`).
    source : str
        Where the region came from (one phrase).
    arrangement : Arrangement
        How the stored frame holds that image
        (:func:`~ipc_taichi.products.arrangement.arrangement_of`).
    """

    shape: tuple
    slices: tuple
    inside: object
    beyond: str
    source: str
    arrangement: object = None

    @property
    def widths(self):
        """Reference pixels outside the region: (bottom, top, left, right)."""
        (ys, xs), (ny, nx) = self.slices, self.shape
        return ys.start, ny - ys.stop, xs.start, nx - xs.stop

    def inside_mask(self):
        """:attr:`inside` as a frame-sized array (None when there are none)."""
        if self.inside is None:
            return None
        full = np.zeros(self.shape, dtype=bool)
        full[self.slices] = self.inside
        return full


@dataclass(frozen=True)
class ArrayPlan:
    """Everything decided for one science array; what
    :func:`~ipc_taichi.products.correction.correct_frames` takes as it is (it
    reads the fields a :class:`~ipc_taichi.products.correction.FramePlan` has).

    Attributes
    ----------
    index, name, label, shape :
        As in :class:`ArrayFacts` (``shape``: as stored).
    units_text : str
        How its numbers become electrons (the HISTORY's phrase).
    exptime : float or None
        Integration time used, s (rates only).
    scale : float or ndarray
        Electrons per data unit, per exposure.
    coadds : int
    science_region : ScienceRegion
        Its science region and readout arrangement.
    model : CouplingModel
        The model with the edge rule the frame gets.
    edge_reason : str
    pedestal : ndarray or None
        Charge on the node before the first read, electrons.
    ramp : bool
        Its frames along axis -3 are the groups of a ramp (charge, not a
        rate, in a stack of frames) to be decoupled with warm starts
        (``options.warm_start``; off by default).
    """

    index: int
    name: str
    label: str
    shape: tuple
    units_text: str
    exptime: object
    scale: object
    coadds: int
    science_region: ScienceRegion
    model: object
    edge_reason: str
    pedestal: object = None
    ramp: bool = False

    @property
    def region(self):
        return self.science_region.slices

    @property
    def inside(self):
        return self.science_region.inside

    @property
    def arrangement(self):
        return self.science_region.arrangement

    @property
    def science_shape(self):
        """The shape of the contiguous image(s) corrected (:attr:`shape` unless
        the frames are interleaved)."""
        return tuple(self.shape[:-2]) + tuple(self.science_region.shape)

    @property
    def frames(self):
        return int(np.prod(self.shape[:-2])) if len(self.shape) > 2 else 1


@dataclass(frozen=True)
class ProductPlan:
    """The plan of a product: its mission, the DQ bits left out, one
    :class:`ArrayPlan` per science array, the pedestal's description and
    whether every science array of the product is in it."""

    mission: missions.Mission
    bits: int
    arrays: tuple
    pedestal_text: str = "none"
    complete: bool = True


def _items(text):
    return [item.strip() for item in str(text).replace("+", ",").split(",") if item.strip()]


def dq_bits_of(text, mission):
    """The DQ bits of ``text`` (``"DO_NOT_USE,SATURATED"``, ``"1,2048"``, an int).

    A file with its own ``DQ_DEF`` (``mission.dq_def``) is read by that table
    alone: a name it lacks is not taken from the mission's (a NIRSpec dark's
    bit 2 is WARM, JWST's science bit 2 SATURATED) but returned in
    ``lacking`` for the caller to say. ``REFERENCE_PIXEL`` is never a bit
    left out (reference pixels are the science region's).

    Returns
    -------
    bits : int
    lacking : list of str
        Names the file's ``DQ_DEF`` does not define.

    Raises
    ------
    IPCInputError
        A name neither table knows.
    """
    if text is None:
        text = missions.DEFAULT_DQ
    own = mission.dq_def
    if not own or isinstance(text, (int, np.integer)):
        return cv.parse_dq_bits(text, mission.dq_flags) & ~cv.REFERENCE_PIXEL, []
    bits, lacking = 0, []
    for item in _items(text):
        if item.upper() in own or item.isdigit() or item.upper() not in mission.dq_flags:
            bits |= cv.parse_dq_bits(item, own)  # an unknown name is refused here
        else:
            lacking.append(item.upper())
    return bits & ~cv.REFERENCE_PIXEL, lacking


def say_lacking(lacking, mission, where):
    """One warning line for the DQ names a file's ``DQ_DEF`` lacks (``where``:
    the file and its DQ_DEF HDU); nothing when none."""
    if not lacking:
        return
    names = ", ".join(f"{k} = {v}" for k, v in sorted(mission.dq_def.items(), key=lambda i: i[1]))
    warnings.warn(f"{where}: defines no {', '.join(lacking)}: not left out (this file's flags: "
                  f"{names}); give --dq-bits with its names or bit values",
                  cv.ProductWarning, stacklevel=3)


def _open_edge(mission):
    return "pixels" if mission.detector_product else "unknown"


def arrangement_of(facts, shape2d):
    """How the stored frame of ``facts`` is read out
    (:func:`~ipc_taichi.products.arrangement.arrangement_of`; contiguous when
    nothing is known of it)."""
    if facts is None:
        return arrangements.Arrangement.contiguous(shape2d)
    return arrangements.arrangement_of(_Header(facts.product), _Header(facts.own),
                                  tuple(facts.shape[:-2]) + tuple(shape2d), facts.label)


def science_region_of(shape2d, mission, facts=None, refpix=None):
    """How a frame is read out, its science region and what lies beyond its edge.

    First the frame's readout arrangement (:func:`arrangement_of`: an IRS2
    frame's contiguous image is the 2048 x 2048 detector). Then, in that
    image: ``refpix`` (a border of N pixels) if given; else the
    ``REFERENCE_PIXEL`` flags of the first frame (``facts.reference``); else
    the border the arrangement places (IRS2); else the observatory's
    convention (:func:`~ipc_taichi.products.missions.reference_border`, from
    the array's own geometry keywords: the near-infrared border, MIRI's
    4 + 4 reference columns, Roman's border); else none.

    Parameters
    ----------
    shape2d : (int, int)
        The stored frame.

    Returns
    -------
    ScienceRegion

    Raises
    ------
    IPCInputError
        A frame whose arrangement cannot be placed, a border that leaves no
        science, geometry keywords that place no pixel (one line, naming the
        array).
    """
    arrangement = arrangement_of(facts, shape2d)
    shape2d = arrangement.science_shape
    label = facts.label if facts is not None else "data"
    whole = (slice(0, shape2d[0]), slice(0, shape2d[1]))

    def slices_of(n=None, reference=None):
        try:
            return cv.science_region(shape2d, n, reference)
        except IPCInputError as exc:
            raise IPCInputError(f"{label}: {exc}") from None

    def made(region, inside, beyond, source):
        return ScienceRegion(shape2d, region, inside, beyond, source, arrangement)

    if refpix is not None:
        region, _ = slices_of(refpix)
        beyond = "reference" if int(refpix) else _open_edge(mission)
        return made(region, None, beyond, f"--refpix {int(refpix)}")
    flagged = facts.reference() if facts is not None and facts.reference else None
    flagged = arrangement.to_science(flagged)
    if flagged is not None and flagged.any():
        region, inside = slices_of(None, flagged)
        beyond = "reference" if region != whole else _open_edge(mission)
        return made(region, inside, beyond, "REFERENCE_PIXEL flags")
    border = None
    if arrangement.border:
        n = arrangement.border
        border = missions.Border(n, n, n, n, arrangement.note)
    elif facts is not None:
        try:
            border = missions.reference_border(mission, facts.own, facts.product, shape2d)
        except IPCInputError as exc:
            raise IPCInputError(f"{label}: {exc}") from None
    if border is None:
        return made(whole, None, _open_edge(mission), "no reference pixels")
    if border.stored_apart:
        return made(whole, None, "reference", border.source)
    region, _ = slices_of(None, border.mask(shape2d))
    return made(region, None, "reference", border.source)


def edge_of(model, asked, science_region):
    """The model for a frame's science region, and why its edge rule.

    The model says which edge it asks for (``asked``: the rule the caller
    chose, ``--edge`` or the Step's ``edge=``; None: none chosen); the frame
    decides what it gets:

    - reference pixels beyond the edge: ``zero`` whatever was asked
      (reference pixels collect no photo-charge: zero-signal neighbours, as
      the JWST ``ipc`` step treats them);
    - else the rule asked for, if one was;
    - else, beyond lie pixels holding charge like its own (a subarray or
      cut-out of a detector product): ``isolated`` (``zero`` would invent a
      step at the edge);
    - else (a plain image) the model's own rule (the paper's ``zero`` by
      default).

    Returns
    -------
    model : CouplingModel
    reason : str
    """
    if science_region.beyond == "reference":
        edge, reason = "zero", f"reference pixels ({science_region.source}): zero-signal neighbours"
    elif asked is not None:
        edge, reason = asked, "asked for (--edge)"
    elif science_region.beyond == "pixels":
        edge, reason = "isolated", "no reference border (cut-out or subarray)"
    else:
        edge, reason = model.edge, "default (plain image)"
    if edge == model.edge:
        return model, reason
    return CouplingModel(model.law, model.geometry, edge, model.bonds), reason


def units_in(text, gain_known, label, source="BUNIT"):
    """:class:`~ipc_taichi.products.conventions.Units` of a ``BUNIT`` value
    ``text`` by the rule of :func:`units_of`: none given, DN when
    ``gain_known``, else electrons (``source`` names the keyword)."""
    if (text is None or not str(text).strip()) and gain_known:
        return cv.Units("dn", f"DN (no {source}, a gain known)")
    return cv.parse_units(text, label, source)


def units_of(facts, mission, options, source=None):
    """What the numbers of a science array are, by the one rule of every path
    (decouple, the Step, calibrate).

    ``options.bunit``, else the array's ``BUNIT`` (a Roman product's kind).
    With neither, **DN when a gain is known** (``options.gain``, or a
    ``GAIN`` keyword: a gain is written beside numbers in DN; a lab file's
    habit, the solid-waffle simulator's), **else electrons**, the law's unit.
    The DN so taken say so in their text (the HISTORY's, calibrate's note).
    ``source`` names where the units come from in errors (default: the
    mission's, ``--bunit`` for a Roman override).

    Raises
    ------
    IPCInputError
        Flux or unknown units; a gain given for data in electrons (one line
        naming the array).
    """
    if source is None:
        source = "--bunit" if options.bunit is not None and mission.name == "Roman" else \
            mission.units_source
    text = options.bunit if options.bunit is not None else facts.keyword("BUNIT")
    known = options.gain is not None or facts.keyword("GAIN") is not None
    units = units_in(text, known, facts.label, source)
    if options.gain is not None and not units.needs_gain:
        raise IPCInputError(f"{facts.label}: a gain was given but the data are in "
                            f"{units.text}; give --bunit DN or DN/s if they are not")
    if facts.zeroth:  # a zeroth read holds the charge since reset, not a rate
        units = cv.Units(units.kind.replace("_rate", ""), units.text)
    return units


def _first(facts, options_value, keys, kind=None):
    if options_value is not None:
        return options_value
    for key in keys:
        value = facts.keyword(key)
        if value is not None:
            return value if kind is None else kind(value)
    return None


def _pedestal_option(options):
    """``options.pedestal`` with None read as ``"auto"``, and whether it names
    a pedestal itself (a number or an image file, not none/auto)."""
    option = "auto" if options.pedestal is None else options.pedestal
    return option, option not in ("none", "auto", False, 0, "0")


def _pedestal(facts, options, gain, zeroth, science_region):
    """The pedestal of one array, electrons (None when none), in the science
    image's shape (a pedestal image is given in the product's frame shape)."""
    option, given = _pedestal_option(options)
    shape2d = tuple(facts.shape[-2:])
    if facts.zeroth:
        return None
    if given:
        frame = np.asarray(read_frame(option, shape2d, "pedestal"), dtype=np.float64)
        check_pedestal(frame, option, cv.PHYSICAL_RANGE)
        if frame.ndim == 2:
            frame = science_region.arrangement.to_science(frame)
        return np.broadcast_to(frame, tuple(science_region.shape))
    if option == "auto" and zeroth is not None:
        if tuple(zeroth.shape2d) != shape2d:
            raise IPCInputError(f"{facts.label}: the zeroth read has another shape")
        return zeroth.charge(gain)
    return None


def plan_array(facts, mission, model, options, zeroth=None):
    """The :class:`ArrayPlan` of one science array (steps 2-5 of the module's
    sequence). ``zeroth``: the product's zeroth read (:class:`Zeroth`) or None."""
    where = science_region_of(facts.shape[-2:], mission, facts, options.refpix)
    if options.tile and not where.arrangement.identity:
        raise IPCInputError(f"{facts.label}: an IRS2 frame (reference samples interleaved) is "
                            "corrected whole: run without --tile")
    shape2d = where.shape
    units = units_of(facts, mission, options)
    gain = read_gain(options.gain if options.gain is not None else
                     header_gain(facts.keyword("GAIN"), facts.label), shape2d)
    check_gain_image(cv.unusable_gain(gain) if np.ndim(gain) == 2 else None, facts.label)
    exptime = _first(facts, options.exptime, mission.time_keywords) if units.rate else None
    coadds = int(_first(facts, options.coadds, missions.COADD_KEYWORDS, int) or 1)
    scale, units_text = cv.charge_scale(units, gain, exptime, facts.label,
                                        time_source=mission.time_source, coadds=coadds,
                                        gain_source=mission.gain_source)
    inner, reason = edge_of(model, options.edge, where)
    if model.bonds is not None:  # the science region's map (one of the whole frame is cut)
        inner = CouplingModel(inner.law, inner.geometry, inner.edge,
                              inner.bonds.for_region(where.slices, shape2d, facts.label))
    pedestal = _pedestal(facts, options, gain, zeroth, where)
    if pedestal is not None and options.tile:
        raise IPCInputError(f"{facts.label}: --tile cannot add the pedestal (zeroth read); run "
                            "without --tile, or give --pedestal none")
    return ArrayPlan(facts.index, facts.name, facts.label, tuple(facts.shape), units_text,
                     exptime, scale, coadds, where, inner, reason, pedestal,
                     len(facts.shape) > 2 and not units.rate and options.warm_start)


def plan_product(arrays, mission, model, options, *, dq_where=None, zeroth=None,
                 complete=True):
    """The :class:`ProductPlan` of a product: the whole sequence, once.

    Parameters
    ----------
    arrays : list of ArrayFacts
        Its science arrays.
    mission : Mission
        Its observatory's conventions
        (:func:`~ipc_taichi.products.missions.recognise`).
    model : CouplingModel
        The model asked for (its edge: see :func:`edge_of`).
    options : ProductOptions
    dq_where : str, optional
        The file and its ``DQ_DEF`` HDU, naming the table in the one line
        that says which names it lacks.
    zeroth : Zeroth, optional
        A multi-read product's zeroth read (the ``auto`` pedestal).
    complete : bool
        Whether ``arrays`` are all the product's science arrays.

    Raises
    ------
    IPCInputError
        The paper's law on an instrument product, a bias product, and every
        refusal of the steps (one line naming the file and array).
    """
    first = arrays[0]
    missions.check_not_bias(first.product, first.label)
    missions.check_model_chosen(mission, options.model_chosen, first.label)
    bits, lacking = dq_bits_of(options.dq_bits, mission)
    say_lacking(lacking, mission, dq_where or f"{first.label.rsplit('[', 1)[0]}[DQ_DEF]")
    plans = tuple(plan_array(a, mission, model, options, zeroth) for a in arrays)
    option, given = _pedestal_option(options)
    if given and any(not a.zeroth for a in arrays):
        pedestal_text = f"given: {option} e-"  # the card cuts it whole
    elif zeroth is not None and any(p.pedestal is not None for p in plans):
        pedestal_text = zeroth.text
    else:
        pedestal_text = "none"
    return ProductPlan(mission, bits, plans, pedestal_text, complete)

"""The correction of a science array, frame by frame, by the product rules.

:func:`correct_frames` is the one correction every reader calls (FITS whole,
:func:`ipc_taichi.products.streams.whole`; Roman,
:func:`ipc_taichi.products.roman.process_asdf`; the JWST Step,
:func:`ipc_taichi.products.jwst_step.correct_model`), with two records:

- the array's plan (:class:`~ipc_taichi.products.plan.ArrayPlan`, or a
  :class:`FramePlan` for bare arrays): its model, science region, electrons
  per data unit, pedestal, whether its frames are a ramp's groups, its label;
- the run's settings (:class:`RunSettings`, built once from the
  :class:`~ipc_taichi.products.options.ProductOptions`): the operation, the
  stopping rule, the runtime asked for, what is done with unphysical pixels,
  the progress reporter, the tile size of a tiled run.

The rules it applies (units, masked pixels, unphysical values, the pedestal)
are those of :mod:`ipc_taichi.products.conventions`.
"""

import warnings
from dataclasses import dataclass, replace

import numpy as np

from .. import iteration, noise, runtime
from ..coupling import couple
from ..decoupling import WarmCarry, decouple
from ..errors import ConvergenceWarning, DivergenceError, IPCInputError
from ..interrupts import check_stop
from ..progress import reporters
from .checks import FrameLost, LostFrames
from .conventions import PHYSICAL_RANGE, ProductWarning, Unphysical, untrusted
from .options import precision_for

__all__ = ["RunSettings", "FramePlan", "FrameBuffers", "correct_frames", "named", "OPERATIONS"]

OPERATIONS = ("couple", "decouple")


@dataclass(frozen=True)
class RunSettings:
    """How a run corrects every array of a product: one record, built once
    (:meth:`of`) from the run's options.

    Attributes
    ----------
    operation : {"couple", "decouple"}
    max_iter, tol, arch, precision :
        As for :func:`ipc_taichi.decouple` (``arch``, ``precision``: as asked;
        None: the runtime's).
    unphysical : {"mask", "keep"}
        What is done with unflagged pixels no detector can hold
        (:class:`~ipc_taichi.products.conventions.Unphysical`).
    progress : bool or callable
        Told of each frame done, or of each iteration of a lone frame
        (:func:`ipc_taichi.progress.reporters`); True: only the bar of tiles.
    tile : int, optional
        The tile size of a tiled run (FITS, decouple only).
    """

    operation: str = "decouple"
    max_iter: int = iteration.MAX_ITER
    tol: float = iteration.TOL
    arch: str = None
    precision: str = None
    unphysical: str = "mask"
    progress: object = None
    tile: int = None

    def __post_init__(self):
        if self.operation not in OPERATIONS:
            raise IPCInputError(f"operation must be couple or decouple, got {self.operation!r}")
        max_iter, tol = iteration.check_arguments(self.max_iter, self.tol)
        object.__setattr__(self, "max_iter", max_iter)
        object.__setattr__(self, "tol", tol)

    @classmethod
    def of(cls, options, operation="decouple"):
        """The settings of a run of ``operation`` with ``options`` (a
        :class:`~ipc_taichi.products.options.ProductOptions`)."""
        return cls(operation, options.max_iter, options.tol, options.arch, options.precision,
                   options.unphysical, options.progress, options.tile)


@dataclass(frozen=True)
class FramePlan:
    """What :func:`correct_frames` reads of an array's plan, for bare arrays
    (an :class:`~ipc_taichi.products.plan.ArrayPlan` is one already).

    Attributes
    ----------
    model : CouplingModel
        The model of the science region (its edge rule decided by
        :func:`ipc_taichi.products.plan.edge_of`).
    region : (slice, slice), optional
        The science region inside the reference pixels (default: the frame).
    scale : float or ndarray (ny, nx)
        Electrons per data unit
        (:func:`~ipc_taichi.products.conventions.charge_scale`); pixels
        without a usable per-pixel gain are left out.
    pedestal : ndarray (ny, nx), optional
        Charge on the node before the first read, in electrons, as measured
        (e.g. a zeroth read). The law sees ``data + pedestal``: decouple gives
        ``D(M + P) - D(P)``, couple ``C(S + P) - C(P)``, so the frame keeps its
        meaning (charge since the pedestal) while alpha is evaluated at the
        charge really on the node.
    ramp : bool
        The frames along axis -3 are the groups of a ramp (the charge grows
        from one to the next): decouple each integration's groups with warm
        starts (each group starts from the previous groups' answers plus the
        new charge; the same stopping rule, so the same tolerance as from
        scratch), one group at a time, the start carried from one to the
        next by a :class:`~ipc_taichi.decoupling.WarmCarry`. A group with
        nothing to decouple is left as it came, as a lost frame of a stack.
    label : str
        The file and array, for messages.
    """

    model: object
    region: tuple = None
    scale: object = 1.0
    pedestal: object = None
    ramp: bool = False
    label: str = "data"


class FrameBuffers:
    """The float64 arrays of the frame before, done with, written again for
    the next frame (a new array pays a page fault per page): its charge in
    electrons and its decoupled answer. Each is taken once, and only when it
    has the shape asked for."""

    def __init__(self):
        self.charge = None
        self.answer = None

    def take_charge(self, shape):
        """The previous frame's charge array if it has ``shape`` (no longer held), else None."""
        held, self.charge = self.charge, None
        return held if held is not None and held.shape == tuple(shape) else None

    def take_answer(self, shape):
        """The previous frame's answer if it has ``shape`` (no longer held), else None."""
        held, self.answer = self.answer, None
        return held if held is not None and held.shape == tuple(shape) else None


class named:
    """Context manager: a :class:`DivergenceError` raised inside is raised
    again with ``where`` (the file, HDU and frame) in front of its message."""

    def __init__(self, where):
        self.where = where

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None and issubclass(exc_type, DivergenceError):
            raise DivergenceError(f"{self.where}: {exc}") from None
        return False


def correct_frames(data, plan, settings=RunSettings(), *, mask=None, out=None, noise=None,
                   record=None, written=None):
    """Couple or decouple every 2-D frame of ``data`` by the product rules.

    The pure correction function under every product reader/writer.

    Parameters
    ----------
    data : ndarray, shape (..., ny, nx)
        The science array in its own units (any real dtype).
    plan : ArrayPlan or FramePlan
        The array's plan: its ``model``, ``region``, ``scale``, ``pedestal``,
        ``ramp`` and ``label`` (see :class:`FramePlan`).
    settings : RunSettings
        The run's operation, stopping rule, runtime, unphysical rule and
        progress reporter.
    mask : ndarray of bool, optional
        Untrusted pixels (True), broadcastable to ``data``: they keep their
        values and do not couple
        (:func:`~ipc_taichi.products.conventions.untrusted`).
    out : ndarray, optional
        Where to write (same shape as ``data``; default: a float64 copy).
        Pixels outside the region and masked pixels are copied from ``data``.
    noise : dict, optional
        The product's noise arrays beside ``data`` (``err``, ``var_poisson``, ``var_rnoise``,
        ``var_flat``; each of ``data``'s shape, float64, C-contiguous, data units), replaced in
        place, frame by frame, by their values after the decoupler with this frame's region,
        model, mask, scale and pedestal (:func:`ipc_taichi.noise.propagate_noise`). Decouple only.
    record : Unphysical, optional
        Where the unflagged unphysical pixels are counted (default: a new
        one with ``settings.unphysical``); said in one warning line for the
        whole array.
    written : callable, optional
        Called with each frame of ``out`` (a view, every pixel of it final)
        as soon as it is written, e.g. to start its writeback
        (:meth:`~ipc_taichi.products.pages.OutputPages.written`).

    Returns
    -------
    out : ndarray
    infos : list of DecoupleInfo (decouple) or of None (couple), one per frame.
    """
    data = np.asarray(data)
    if settings.precision == "auto":
        settings = replace(settings, precision=precision_for("auto", [data.dtype]))
    shape = data.shape
    ny, nx = shape[-2:]
    region = plan.region or (slice(0, ny), slice(0, nx))
    operation = settings.operation
    frames = data.reshape((-1, ny, nx))
    masks = None if mask is None else np.broadcast_to(mask, shape).reshape((-1, ny, nx))
    if out is None:
        out = np.array(data, dtype=np.float64)
    else:  # the region is written frame by frame below; the rest kept from data
        _copy_outside(out, data, region)
    flat_out = out.reshape((-1, ny, nx))
    science = frames[:1, region[0], region[1]].shape[1:]
    base = None if plan.pedestal is None else np.asarray(plan.pedestal, np.float64)[region]
    units = _Units(plan.scale, region, data.dtype,
                   runtime.init(settings.arch, settings.precision).dtype, base)
    after_frame, after_iteration = reporters(settings.progress, frames.shape[0],
                                             settings.max_iter)
    solver = _Solver(plan.model, settings, after_iteration, base)
    record = record if record is not None else Unphysical(settings.unphysical)
    offset = (region[0].start or 0, region[1].start or 0)
    if any(not v.flags.c_contiguous for v in (noise or {}).values()):
        raise ValueError("correct_frames: noise arrays must be C-contiguous (updated in place)")
    noisy = {k: v.reshape((-1, ny, nx)) for k, v in (noise or {}).items()
             if operation == "decouple"}
    infos, lost = [], LostFrames(frames.shape[0])
    groups = shape[-3] if plan.ramp and operation == "decouple" and len(shape) > 2 else 0
    # the result stored by the decoupler straight into out (one pass, no f64 copy) when
    # it is the answer as it is: no units, no pedestal, no mask to keep values under
    direct = operation == "decouple" and units.unit and base is None and not noisy
    for k in range(frames.shape[0]):
        check_stop()  # a SIGINT/SIGTERM swallowed by a library stops the run here
        where = f"{plan.label} frame {k}" if frames.shape[0] > 1 else plan.label
        if groups and k % groups == 0:
            solver.carry.reset()  # an integration's first group: from scratch
        try:
            y, m = _frame_in(frames[k][region], units, base, record, where, offset, operation,
                             None if masks is None else masks[k][region],
                             solver.buffers.take_charge(science))
        except FrameLost as exc:  # one frame of a stack or read of a ramp: left as it came
            infos.append(lost.keep(exc, operation))
            flat_out[k][region] = frames[k][region]
            if written is not None:
                written(flat_out[k])
            continue
        target = flat_out[k][region]
        into = target if direct and m is None else None
        result, info = solver.solve(y, m, where, into, warm=bool(groups))
        if into is None:
            result = units.back(result)
            target[...] = result if m is None else np.where(m, frames[k][region], result)
        if written is not None:
            written(flat_out[k])
        if noisy:
            _propagate(noisy, k, region, target, y, m, plan.model, units.inside, base)
        infos.append(info)
        if after_frame is not None:
            after_frame(k + 1)
        solver.buffers.charge = y
    record.warn(plan.label)
    if lost.said():
        warnings.warn(lost.said(), ProductWarning, stacklevel=2)
    return out, infos


class _Units:
    """Electrons per data unit of an array (``scale``) and of its science
    region (``inside``), and the dtype its charge is held in (``dtype``):
    float64, or the runtime's ``precision`` (f32) when the data convert to
    it exactly and the charge is the data (no scale, no pedestal): the
    same bits as through float64, one conversion less."""

    def __init__(self, scale, region, data_dtype=np.float64, precision=np.float64,
                 pedestal=None):
        self.scale = np.asarray(scale, dtype=np.float64)
        self.per_pixel = self.scale.ndim == 2
        self.inside = self.scale[region] if self.per_pixel else self.scale
        # the number 1: a pass saved, no bit changed
        self.unit = self.inside.ndim == 0 and float(self.inside) == 1.0
        exact = self.unit and pedestal is None and np.can_cast(data_dtype, precision, "safe")
        self.dtype = np.dtype(precision if exact else np.float64)

    def back(self, result):
        """A result in electrons back in data units (no gain: masked by the caller)."""
        if self.unit:
            return result
        with np.errstate(divide="ignore", invalid="ignore"):
            return result / self.inside


def _frame_in(frame, units, base, record, where, offset, operation, flagged, into=None):
    """One frame's measured charge (electrons) and its mask (None when none);
    written into ``into`` (an array of its shape, of :attr:`_Units.dtype`, the
    caller has done with) when given.

    The frame's least and largest charge are found first (two reads, no
    temporary): when both lie in :data:`PHYSICAL_RANGE` every pixel is
    finite and physical, and the per-pixel passes of the unphysical and
    finiteness rules are skipped (they would find nothing)."""
    measured = frame.astype(units.dtype) if into is None else into
    if into is not None:
        np.copyto(measured, frame, casting="unsafe")
    if not units.unit:
        measured *= units.inside
    m = untrusted([], 0, measured.shape, flagged,
                  gain=units.inside if units.per_pixel else None)
    if base is None and measured.size and \
            PHYSICAL_RANGE[0] <= measured.min() and measured.max() <= PHYSICAL_RANGE[1]:
        good = True if m is None else ~m  # every pixel finite and physical
    else:
        bad = record.add(measured if base is None else measured + base, m, where, offset)
        if bad is not None:
            m = bad if m is None else (m | bad)
        good = np.isfinite(measured) if m is None else (np.isfinite(measured) & ~m)
    if not np.any(good):
        raise FrameLost(f"{where}: no finite, unmasked pixel to {operation} "
                        "(all NaN, flagged or unphysical)")
    return measured, m


def _copy_outside(out, data, region):
    """``out = data`` outside ``region``, in four slabs (the frame loop writes
    every pixel inside it: its result, or the input for a masked pixel)."""
    (y0, y1, _), (x0, x1, _) = (r.indices(n) for r, n in zip(region, data.shape[-2:]))
    for part in ((slice(0, y0), slice(None)), (slice(y1, None), slice(None)),
                 (slice(y0, y1), slice(0, x0)), (slice(y0, y1), slice(x1, None))):
        out[(Ellipsis,) + part] = data[(Ellipsis,) + part]


class _Solver:
    """The frames of one array through the decoupler or the forward model:
    ``D(M + P) - D(P)`` with a pedestal ``P`` (its own answer computed once
    per mask), the previous frame's buffers written again."""

    def __init__(self, model, settings, callback, base):
        self.model, self.settings, self.callback, self.base = model, settings, callback, base
        self.buffers = FrameBuffers()
        self.cached = {}  # the pedestal's answer, per mask
        self.carry = WarmCarry()  # a ramp's warm start, from one group to the next

    def solve(self, measured, mask, where, into=None, warm=False):
        """One frame (``warm``: a ramp's group, started from the groups before
        it); ``into``: where its answer is stored (any float array of its
        shape; no pedestal), or None."""
        charge = measured if self.base is None else measured + self.base
        result, info = self.run(charge, mask, where, self.buffers, into, warm)
        if self.base is not None:
            key = None if mask is None else mask.tobytes()
            if key not in self.cached:  # the pedestal through the same law, once per mask
                self.cached[key] = self.run(self.base, mask, where)[0]
            result = result - self.cached[key]
        return result, info

    def run(self, charge, mask, where, buffers=None, into=None, warm=False):
        """One frame in electrons; ``buffers`` (a :class:`FrameBuffers` or
        None): the previous frame's answer, done with, is written again, this
        one kept; ``into``: where the answer is stored instead (returned as it
        is); ``warm``: started from the frames before (:attr:`carry`)."""
        s = self.settings
        out = into if into is not None or buffers is None \
            else buffers.take_answer(np.shape(charge))
        with warnings.catch_warnings(), named(where):
            warnings.simplefilter("ignore", ConvergenceWarning)  # reported per frame by callers
            if s.operation == "decouple":
                result, info = decouple(charge, model=self.model, mask=mask,
                                        max_iter=s.max_iter, tol=s.tol, arch=s.arch,
                                        precision=s.precision, full_output=True,
                                        callback=self.callback,
                                        warm_start=self.carry if warm else False, out=out)
                if into is not None:
                    return result, info
                if buffers is not None and type(result) is np.ndarray and result.ndim == 2:
                    buffers.answer = result
            else:
                result, info = couple(charge, model=self.model, mask=mask, arch=s.arch,
                                      precision=s.precision), None
        return np.asarray(np.ma.getdata(result), dtype=np.float64), info


def _propagate(noisy, k, region, solution, measured, mask, model, s_in, base):
    """Frame ``k`` of the noise arrays through the linearised decoupler, in place."""
    given = {name: array[k][region] for name, array in noisy.items()}
    with np.errstate(divide="ignore", invalid="ignore"):
        y = measured / s_in
    new = noise.propagate_noise(np.asarray(solution, dtype=np.float64), model, measured=y,
                                mask=mask, scale=s_in, pedestal=base, **given)
    for name, value in new.items():
        given[name][...] = value

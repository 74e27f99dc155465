"""A JWST pipeline step: signal-dependent IPC on the ramp (``pip install ipc_taichi[jwst]``).

:class:`IPCTaichiStep` is an ``stpipe`` Step that works on a
``RampModel`` group by group, with the law, geometry, edge rule and gain as
step parameters (no reference file is fetched at run time):

.. code-block:: console

    strun ipc_taichi jw_ramp.fits --gain=2.0 --model=nrca1_ipc.json

It asks CRDS for no parameter file (it has none), so it runs offline; the
law is never the paper's by default: give ``model=`` (a coupling-model
file) or ``law=``.

:class:`Detector1TaichiPipeline` is ``calwebb_detector1`` with the built-in
``ipc`` step replaced by it (same place, same name, so ``--steps.ipc.*``
parameters reach it):

.. code-block:: console

    strun ipc_taichi.products.jwst_step.Detector1TaichiPipeline jw_uncal.fits \\
        --steps.ipc.gain=2.0 --steps.ipc.law=constant:0.006 \\
        --steps.ipc.superbias=jwst_nircam_superbias.fits

In ``calwebb_detector1`` the ``ipc`` slot comes before ``superbias``: the
groups still hold the bias, which is not collected charge. The step then
needs the superbias (a local file, ``superbias=``): it subtracts it, corrects,
and adds it back, so the following steps see what they expect. A ramp whose
``superbias`` step is already complete (``meta.cal_step.superbias``) is
taken as bias-free.

The Step asks the same plan as ``ipc-taichi decouple``
(:mod:`ipc_taichi.products.plan`: units, gain, DQ bits, reference pixels,
edge), reading the datamodel's values by their FITS keyword names, and runs
the same correction: on the same file and model the two give bit-identical
science and record the same IPC keywords (``extra_fits``) and HISTORY
(``meta.cal_step.ipc`` is ``S_IPC``). ``edge=`` is the rule asked for; the
frame decides what it gets (``zero`` beside reference pixels, else what was
asked, else ``isolated`` for a subarray inside the detector). A rate or
rateints model is corrected too (DN/s and its integration time). A model
without ``pixeldq``/``groupdq`` is all good. An IRS2 ramp is corrected in
its contiguous image (:mod:`~ipc_taichi.products.arrangement`), its reference
samples as they came; ``err`` and ``var_*`` are propagated as the command
line propagates ``ERR`` and ``VAR_*`` (``noise="keep"`` leaves them).
"""

import logging

import numpy as np

try:
    from jwst.pipeline import Detector1Pipeline
    from jwst.stpipe import Step
except ImportError as exc:  # the optional extra is not installed
    raise ImportError("the JWST step needs jwst: pip install 'ipc_taichi[jwst]'") from exc

from .. import __version__, iteration, runtime
from ..errors import IPCInputError
from . import conventions as cv
from . import missions
from .correction import RunSettings, correct_frames
from .noise_arrays import held, noise_of
from .options import ProductOptions
from .plan import ArrayFacts, plan_product
from .provenance import Provenance
from .stepspec import SPEC, coupling_of

__all__ = ["IPCTaichiStep", "Detector1TaichiPipeline", "correct_ramp", "correct_model",
           "plan_model"]

log = logging.getLogger(__name__)


def _keywords(datamodel):
    """``key -> value`` of a JWST datamodel by its schema's FITS keyword names
    (``SUBSTRT1`` is ``meta.subarray.xstart``), as the command line reads the
    same file: ``TELESCOP`` is JWST, and a ``BUNIT`` the model lacks is its
    kind's (:func:`~ipc_taichi.products.missions.jwst_units`)."""
    cache = {}

    def get(key):
        if key not in cache:
            paths = datamodel.find_fits_keyword(key)
            value = datamodel[paths[0]] if paths else None
            if value in (None, "") and key == "TELESCOP":
                value = "JWST"
            if value in (None, "") and key == "BUNIT":
                value = missions.jwst_units(np.ndim(datamodel.data))
            cache[key] = None if value == "" else value
        return cache[key]
    return get


def _flags(datamodel, shape, label):
    """The model's bit-flag arrays present (``pixeldq``, ``groupdq``, ``dq``):
    a model without them (the pipeline's own test fixtures) is all good, the
    one rule for a missing array."""
    found = []
    for name in ("pixeldq", "groupdq", "dq"):
        value = datamodel.instance.get(name)
        if value is None:
            continue
        f = np.asarray(value)
        if f.shape != shape[len(shape) - f.ndim:]:
            raise IPCInputError(f"{label}[{name.upper()}]: shape {f.shape} does not match the "
                                f"science data's {shape}; refused")
        found.append(f)
    return found


def plan_model(datamodel, coupling, options):
    """The :class:`~ipc_taichi.products.plan.ProductPlan` of a JWST datamodel
    (a ramp, a rate or a rateints), the one the command line makes of the same
    file; and its flag arrays."""
    data = np.asarray(datamodel.data)
    get = _keywords(datamodel)
    label = f"{datamodel.meta.filename or 'model'}[SCI]"
    flags = _flags(datamodel, data.shape, label.rsplit("[", 1)[0])

    def reference():
        if not flags:
            return None
        first = min(flags, key=np.ndim).reshape((-1,) + data.shape[-2:])[0]
        return (first.astype(np.int64) & cv.REFERENCE_PIXEL) != 0

    mission = missions.recognise({"TELESCOP": get("TELESCOP"), "INSTRUME": get("INSTRUME")})
    facts = ArrayFacts(1, "SCI", label, data.shape, get, get, reference)
    return plan_product([facts], mission, coupling, options), flags


def correct_model(datamodel, coupling, options, superbias=None):
    """Decouple a JWST datamodel's science array in place, as
    :func:`ipc_taichi.products.process_fits` decouples the same file (the same
    plan, the same correction, bit for bit), and record it: the IPC keywords
    (``extra_fits``), HISTORY and ``meta.cal_step.ipc``.

    Parameters
    ----------
    datamodel : RampModel, ImageModel or CubeModel
        Groups in DN (ramps) or rates in DN/s.
    coupling : CouplingModel
        The model asked for (its edge: :func:`ipc_taichi.products.plan.edge_of`).
    options : ProductOptions
    superbias : ndarray, optional
        Subtracted before and added back after (a ramp that holds the bias).

    Returns
    -------
    infos : list of DecoupleInfo
    provenance : Provenance
    """
    plan, flags = plan_model(datamodel, coupling, options)
    p, = plan.arrays
    _refuse_file_options(options, np.asarray(datamodel.data).dtype, p.label)
    science = p.arrangement.to_science  # an IRS2 frame: its contiguous image
    stored = np.asarray(datamodel.data)
    data, flags = science(stored), [science(f) for f in flags]
    superbias = None if superbias is None else science(superbias)
    work = data if superbias is None else data - superbias
    mask = cv.untrusted(flags, plan.bits, data.shape, p.science_region.inside_mask(), values=work,
                        saturation=options.saturation)
    came = held(datamodel.instance.get, stored.shape)
    propagate, noise_text = noise_of("decouple", options, list(came),
                                     f"{p.label.rsplit('[', 1)[0]}[{next(iter(came), '')}]")
    noise = {k: np.array(science(v), dtype=np.float64) for k, v in came.items()} \
        if propagate else {}
    out = np.empty(data.shape, dtype=data.dtype)
    settings = RunSettings.of(options, "decouple")
    record = cv.Unphysical(settings.unphysical)
    _, infos = correct_frames(work, p, settings, mask=mask, out=out, noise=noise,
                              record=record)
    if superbias is not None:
        out += superbias.astype(out.dtype)
        # pixels left alone (reference border, masked): exactly as they came
        untouched = np.ones(data.shape, dtype=bool)
        untouched[(Ellipsis,) + p.region] = False
        if mask is not None:
            untouched |= mask
        out[untouched] = data[untouched]
    datamodel.data = p.arrangement.from_science(out, stored)
    for name, value in noise.items():  # in their own dtype, every other sample as it came
        datamodel[name] = p.arrangement.from_science(value.astype(came[name].dtype),
                                                     came[name])
    prov = Provenance(plan, settings, runtime.current(), noise_text)
    prov.infos[p.index] = infos
    prov.unphysical[p.index] = record.masked
    _record(datamodel, prov, p.index)
    return infos, prov


def _refuse_file_options(options, dtype, label):
    """The options of a file run that a datamodel corrected in place cannot
    honour, refused in one line (never dropped silently)."""
    for name, value in (("hdu", options.hdu), ("tile", options.tile),
                        ("overwrite", options.overwrite or None)):
        if value is not None:
            raise IPCInputError(f"{label}: {name}={value!r} is for files (ipc-taichi "
                                "decouple); the Step corrects the datamodel in place")
    if options.output_dtype not in (None, "same") and np.dtype(options.output_dtype) != dtype:
        raise IPCInputError(f"{label}: output_dtype={options.output_dtype!r}: a datamodel keeps "
                            f"its schema's dtype ({dtype})")


def _record(datamodel, prov, index):
    """The run's record in the datamodel, as a FITS product gets it: the
    primary's and the science HDU's IPC keywords (``extra_fits``), the HISTORY
    lines, ``S_IPC`` as ``meta.cal_step.ipc``."""
    from astropy.io import fits

    primary, science = prov.primary(fits.Header()), prov.science(index, fits.Header())
    extra = dict(datamodel.instance.get("extra_fits") or {})
    for hdu, header in (("PRIMARY", primary), ("SCI", science)):
        cards = [[c.keyword, c.value, c.comment] for c in header.cards
                 if c.keyword not in ("HISTORY", "S_IPC")]
        keys = {c[0] for c in cards}
        section = dict(extra.get(hdu) or {})
        kept = [list(c) for c in section.get("header", []) if c[0] not in keys]
        section["header"] = kept + cards
        extra[hdu] = section
    datamodel.extra_fits = extra
    for line in primary.get("HISTORY", []):
        datamodel.add_history_entry(str(line))
    datamodel.meta.cal_step.ipc = primary["S_IPC"]


def correct_ramp(ramp, coupling, gain, superbias=None, dq_bits=None, refpix=None,
                 max_iter=iteration.MAX_ITER, tol=iteration.TOL, arch=None, precision=None,
                 saturation=None, edge=None):
    """Decouple a ``RampModel`` in place, group by group; returns the infos
    (:func:`correct_model` with these options).

    Parameters
    ----------
    ramp : stdatamodels.jwst.datamodels.RampModel
        Groups in DN, shape (nints, ngroups, ny, nx).
    coupling : CouplingModel
    gain : float or ndarray
        e-/DN.
    superbias : ndarray, optional
        Subtracted before and added back after (for a ramp that holds the bias).
    dq_bits, refpix, max_iter, tol, arch, precision, saturation, edge :
        As for :func:`ipc_taichi.products.process_fits`.
    """
    options = ProductOptions.from_kwargs(gain=gain, dq_bits=dq_bits, refpix=refpix,
                                         max_iter=max_iter, tol=tol, arch=arch,
                                         precision=precision, saturation=saturation, edge=edge)
    return correct_model(ramp, coupling, options, superbias)[0]


class IPCTaichiStep(Step):
    """Remove signal-dependent IPC (Donlon, Ninkov & Baum 2018) from a ramp (or a rate)."""

    class_alias = "ipc_taichi"

    spec = SPEC + """
        superbias = string(default=None)  # superbias file, when the ramp holds the bias
    """

    @classmethod
    def get_config_from_reference(cls, dataset, disable=None, crds_observatory=None):
        """No parameter reference file exists for this step: never ask CRDS
        (so ``strun`` and ``.call()`` work offline)."""
        return cls._empty_config()

    def coupling(self):
        """The coupling model of the parameters (:func:`.stepspec.coupling_of`)."""
        return coupling_of(self, "a JWST ramp")

    def options(self):
        """The :class:`~ipc_taichi.products.options.ProductOptions` of the
        parameters (those of ``ipc-taichi decouple``)."""
        return ProductOptions.from_kwargs(
            gain=self.gain, dq_bits=self.dq_bits, refpix=self.refpix,
            saturation=self.saturation, max_iter=self.max_iter, tol=self.tol, arch=self.arch,
            precision=self.precision, edge=self.edge, noise=self.noise)

    def process(self, step_input):
        """Decouple every group of a ramp (or a rate, rateints) as the command
        line decouples the same file, and record it as it does (IPC keywords,
        HISTORY). ``meta.cal_step.ipc`` is ``COMPLETE`` when every group met
        the stopping rule, else ``FAILED`` (the data are still corrected, to
        the last iteration's accuracy)."""
        result = self.prepare_output(step_input)
        if np.ndim(result.data) == 4 and np.asarray(result.data).dtype.kind != "f":
            result = self.prepare_output(step_input, open_as_ramp=True)  # raw: as a ramp
        if self.gain is None:
            raise ValueError("ipc_taichi: give the gain in e-/DN (gain=...)")
        coupling = self.coupling()
        bias = None
        if np.ndim(result.data) == 4 and result.meta.cal_step.superbias != "COMPLETE":
            if not self.superbias:
                raise ValueError("ipc_taichi: the ramp still holds the bias (superbias step "
                                 "not run): give superbias=FILE, or run after superbias")
            from stdatamodels.jwst.datamodels import SuperBiasModel

            with SuperBiasModel(self.superbias) as sb:
                bias = np.asarray(sb.data, dtype=np.float64)
        infos, prov = correct_model(result, coupling, self.options(), superbias=bias)
        log.info("ipc_taichi %s: %s, edge %s (%s), gain %g e-/DN, %d frames, at most %d "
                 "iterations", __version__, coupling.describe(), prov.model.edge,
                 prov.edge_reason, self.gain, len(infos), max(i.iterations for i in infos))
        if result.meta.cal_step.ipc == "FAILED":
            log.warning("ipc_taichi: %d of %d groups did not meet the stopping rule; "
                        "cal_step.ipc = FAILED", sum(1 for i in infos if not i.converged),
                        len(infos))
        return result


class Detector1TaichiPipeline(Detector1Pipeline):
    """``calwebb_detector1`` with :class:`IPCTaichiStep` in the ``ipc`` slot."""

    class_alias = "calwebb_detector1_taichi"

    step_defs = dict(Detector1Pipeline.step_defs, ipc=IPCTaichiStep)

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
taken as bias-free. The DQ and reference-pixel rules are those of
:mod:`ipc_taichi.products.conventions` (``pixeldq`` and ``groupdq``
honoured; the 4-pixel reference border of near-IR full frames, from the
``REFERENCE_PIXEL`` flags, never changed and treated as zero signal).
"""

import logging

import numpy as np

try:
    from jwst.pipeline import Detector1Pipeline
    from jwst.stpipe import Step
except ImportError as exc:  # the optional extra is not installed
    raise ImportError("the JWST step needs jwst: pip install 'ipc_taichi[jwst]'") from exc

from .. import __version__, iteration
from ..model import CouplingModel
from . import conventions as cv
from . import missions

__all__ = ["IPCTaichiStep", "Detector1TaichiPipeline", "correct_ramp"]

log = logging.getLogger(__name__)


def correct_ramp(ramp, coupling, gain, superbias=None, dq_bits=None, refpix=None,
                 max_iter=iteration.MAX_ITER, tol=iteration.TOL, arch=None, precision=None,
                 saturation=None):
    """Decouple a ``RampModel`` in place, group by group; returns the infos.

    Parameters
    ----------
    ramp : stdatamodels.jwst.datamodels.RampModel
        Groups in DN, shape (nints, ngroups, ny, nx).
    coupling : CouplingModel
    gain : float or ndarray
        e-/DN.
    superbias : ndarray, optional
        Subtracted before and added back after (for a ramp that holds the bias).
    dq_bits, refpix, max_iter, tol, arch, precision, saturation :
        As for :func:`ipc_taichi.products.process_fits`.
    """
    data = np.asarray(ramp.data)
    label = f"{ramp.meta.filename or 'ramp'}[SCI]"
    shape2d = data.shape[-2:]
    scale, _ = cv.charge_scale(cv.Units("dn", "DN"), gain, None, label)
    pixeldq = np.asarray(ramp.pixeldq, dtype=np.int64)
    groupdq = np.asarray(ramp.groupdq, dtype=np.int64)
    reference = (pixeldq & cv.REFERENCE_PIXEL) != 0
    if refpix is None and not reference.any():  # the detector's own border, by convention
        header = {"SUBARRAY": ramp.meta.subarray.name, "SUBSTRT1": ramp.meta.subarray.xstart,
                  "SUBSTRT2": ramp.meta.subarray.ystart}
        mission = missions.recognise({"TELESCOP": "JWST",
                                      "INSTRUME": ramp.meta.instrument.name or ""}, header)
        reference = missions.reference_mask(mission, header, header, shape2d)
    region, inside = cv.science_region(shape2d, refpix, reference)
    bits = cv.parse_dq_bits(dq_bits, missions.recognise({"TELESCOP": "JWST"}).dq_flags) \
        & ~cv.REFERENCE_PIXEL
    full_inside = None
    if inside is not None:
        full_inside = np.zeros(shape2d, dtype=bool)
        full_inside[region] = inside
    work = data if superbias is None else data - superbias
    mask = cv.untrusted([pixeldq, groupdq], bits, data.shape, full_inside, values=work,
                        saturation=saturation)
    inner, _ = cv.choose_edge(coupling, region, shape2d, True, True)
    out = np.empty(data.shape, dtype=data.dtype)
    _, infos = cv.correct_frames(work, "decouple", inner, mask=mask, region=region,
                                 scale=scale, out=out, max_iter=max_iter, tol=tol, arch=arch,
                                 precision=precision, label=label)
    if superbias is not None:
        out += superbias.astype(out.dtype)
        # pixels left alone (reference border, masked): exactly as they came
        untouched = np.ones(data.shape, dtype=bool)
        untouched[(Ellipsis,) + region] = False
        if mask is not None:
            untouched |= mask
        out[untouched] = data[untouched]
    ramp.data = out
    return infos


class IPCTaichiStep(Step):
    """Remove signal-dependent IPC (Donlon, Ninkov & Baum 2018) from a ramp."""

    class_alias = "ipc_taichi"

    spec = f"""
        model = string(default=None)  # coupling-model file (JSON, from ipc-taichi calibrate)
        law = string(default=None)  # coupling law alpha(S,N), in electrons (or model=)
        geometry = string(default=None)  # neighbour weights, e.g. horizontal=1,vertical=0.9
        edge = option('zero', 'isolated', default='zero')  # beyond the frame
        gain = float(default=None)  # e-/DN (required)
        superbias = string(default=None)  # superbias file, when the ramp holds the bias
        dq_bits = string(default='DO_NOT_USE,SATURATED')  # flags of pixels left out
        saturation = float(default=None)  # DN at or above which a pixel is left out
        refpix = integer(default=None)  # reference border; default: REFERENCE_PIXEL flags
        max_iter = integer(default={iteration.MAX_ITER})  # at most this many Jacobi iterations
        tol = float(default={iteration.TOL!r})  # stop when max|dS| <= tol * max|S|
        arch = string(default=None)  # Taichi arch: auto, cpu, cuda
        precision = string(default=None)  # f64 or f32
    """

    @classmethod
    def get_config_from_reference(cls, dataset, disable=None, crds_observatory=None):
        """No parameter reference file exists for this step: never ask CRDS
        (so ``strun`` and ``.call()`` work offline)."""
        return cls._empty_config()

    def coupling(self):
        """The coupling model of the parameters: ``model`` (a file) or ``law``
        (with ``geometry``, ``edge``); the paper's law is never a silent default."""
        if self.model:
            if self.law or self.geometry:
                raise ValueError("ipc_taichi: give model= or law=/geometry=, not both")
            return CouplingModel.load(self.model)
        if not self.law:
            raise ValueError("ipc_taichi: a JWST ramp needs its detector's coupling: give "
                             "model=FILE (from 'ipc-taichi calibrate') or law=...")
        return CouplingModel.resolve(self.law, self.geometry, self.edge)

    def process(self, step_input):
        """Decouple every group of the ramp. ``meta.cal_step.ipc`` is
        ``COMPLETE`` when every group met the stopping rule, else ``FAILED``
        (the data are still corrected, to the last iteration's accuracy)."""
        result = self.prepare_output(step_input, open_as_ramp=True)
        if self.gain is None:
            raise ValueError("ipc_taichi: give the gain in e-/DN (gain=...)")
        coupling = self.coupling()
        bias = None
        if result.meta.cal_step.superbias != "COMPLETE":
            if not self.superbias:
                raise ValueError("ipc_taichi: the ramp still holds the bias (superbias step "
                                 "not run): give superbias=FILE, or run after superbias")
            from stdatamodels.jwst.datamodels import SuperBiasModel

            with SuperBiasModel(self.superbias) as sb:
                bias = np.asarray(sb.data, dtype=np.float64)
        infos = correct_ramp(result, coupling, self.gain, superbias=bias, dq_bits=self.dq_bits,
                             refpix=self.refpix, max_iter=self.max_iter, tol=self.tol,
                             arch=self.arch, precision=self.precision,
                             saturation=self.saturation)
        unconverged = sum(1 for i in infos if not i.converged)
        log.info("ipc_taichi %s: %s, gain %g e-/DN, %d groups, at most %d iterations",
                 __version__, coupling.describe(), self.gain, len(infos),
                 max(i.iterations for i in infos))
        if unconverged and self.tol > 0:
            log.warning("ipc_taichi: %d of %d groups did not meet the stopping rule; "
                        "cal_step.ipc = FAILED", unconverged, len(infos))
            result.meta.cal_step.ipc = "FAILED"
        else:
            result.meta.cal_step.ipc = "COMPLETE"
        return result


class Detector1TaichiPipeline(Detector1Pipeline):
    """``calwebb_detector1`` with :class:`IPCTaichiStep` in the ``ipc`` slot."""

    class_alias = "calwebb_detector1_taichi"

    step_defs = dict(Detector1Pipeline.step_defs, ipc=IPCTaichiStep)

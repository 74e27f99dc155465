"""A JWST pipeline step: signal-dependent IPC on the ramp (``pip install ipc_taichi[jwst]``).

:class:`IPCTaichiStep` is an ``stpipe`` Step that works on a
``RampModel`` group by group, with the law, geometry, edge rule and gain as
step parameters (no reference file is fetched at run time):

.. code-block:: console

    strun ipc_taichi.products.jwst_step.IPCTaichiStep jw_ramp.fits --gain=2.0

:class:`Detector1TaichiPipeline` is ``calwebb_detector1`` with the built-in
``ipc`` step replaced by it (same place, same name, so ``--steps.ipc.*``
parameters reach it):

.. code-block:: console

    strun ipc_taichi.products.jwst_step.Detector1TaichiPipeline jw_uncal.fits \\
        --steps.ipc.gain=2.0 --steps.ipc.superbias=jwst_nircam_superbias.fits

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

from .. import __version__
from ..model import CouplingModel
from . import conventions as cv

__all__ = ["IPCTaichiStep", "Detector1TaichiPipeline", "correct_ramp"]

log = logging.getLogger(__name__)


def correct_ramp(model, coupling, gain, superbias=None, dq_bits="DO_NOT_USE", refpix=None,
                 max_iter=20, tol=1e-5, arch=None, precision=None):
    """Decouple a ``RampModel`` in place, group by group; returns the infos.

    Parameters
    ----------
    model : stdatamodels.jwst.datamodels.RampModel
        Groups in DN, shape (nints, ngroups, ny, nx).
    coupling : CouplingModel
    gain : float or ndarray
        e-/DN.
    superbias : ndarray, optional
        Subtracted before and added back after (for a ramp that holds the bias).
    dq_bits, refpix, max_iter, tol, arch, precision :
        As for :func:`ipc_taichi.products.process_fits`.
    """
    data = np.asarray(model.data)
    label = f"{model.meta.filename or 'ramp'}[SCI]"
    shape2d = data.shape[-2:]
    scale, _ = cv.charge_scale(cv.Units("dn", "DN"), gain, None, label)
    pixeldq = np.asarray(model.pixeldq, dtype=np.int64)
    groupdq = np.asarray(model.groupdq, dtype=np.int64)
    reference = (pixeldq & cv.REFERENCE_PIXEL) != 0
    region, inside = cv.science_region(shape2d, refpix, None if refpix is not None else reference)
    bits = cv.parse_dq_bits(dq_bits) & ~cv.REFERENCE_PIXEL
    mask = ((pixeldq & bits) != 0) | ((groupdq & bits) != 0)
    if inside is not None:
        mask[(Ellipsis,) + region] |= inside
    work = data if superbias is None else data - superbias
    out = np.empty(data.shape, dtype=data.dtype)
    _, infos = cv.correct_frames(work, "decouple", coupling, mask=mask, region=region,
                                 scale=scale, out=out, max_iter=max_iter, tol=tol, arch=arch,
                                 precision=precision, label=label)
    if superbias is not None:
        out += superbias.astype(out.dtype)
        # pixels left alone (reference border, masked): exactly as they came
        untouched = np.ones(data.shape, dtype=bool)
        untouched[(Ellipsis,) + region] = np.broadcast_to(mask, data.shape)[
            (Ellipsis,) + region]
        out[untouched] = data[untouched]
    model.data = out
    return infos


class IPCTaichiStep(Step):
    """Remove signal-dependent IPC (Donlon, Ninkov & Baum 2018) from a ramp."""

    class_alias = "ipc_taichi"

    spec = """
        law = string(default='donlon2018')  # coupling law alpha(S,N), in electrons
        geometry = string(default='nearest')  # neighbour weights, e.g. horizontal=1,vertical=0.9
        edge = option('zero', 'isolated', default='zero')  # beyond the frame
        gain = float(default=None)  # e-/DN (required)
        superbias = string(default=None)  # superbias file, when the ramp holds the bias
        dq_bits = string(default='DO_NOT_USE')  # flags of pixels left out
        refpix = integer(default=None)  # reference border; default: REFERENCE_PIXEL flags
        max_iter = integer(default=20)  # at most this many Jacobi iterations
        tol = float(default=1e-5)  # stop when max|dS| <= tol * max|S|
        arch = string(default=None)  # Taichi arch: auto, cpu, cuda
        precision = string(default=None)  # f64 or f32
    """

    def process(self, step_input):
        """Decouple every group of the ramp; ``meta.cal_step.ipc = 'COMPLETE'``."""
        result = self.prepare_output(step_input, open_as_ramp=True)
        if self.gain is None:
            raise ValueError("ipc_taichi: give the gain in e-/DN (gain=...)")
        coupling = CouplingModel.resolve(self.law, self.geometry, self.edge)
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
                             arch=self.arch, precision=self.precision)
        unconverged = sum(1 for i in infos if not i.converged)
        if unconverged and self.tol > 0:
            log.warning("ipc_taichi: %d of %d groups did not meet the stopping rule",
                        unconverged, len(infos))
        log.info("ipc_taichi %s: %s, gain %g e-/DN, %d groups, at most %d iterations",
                 __version__, coupling.describe(), self.gain, len(infos),
                 max(i.iterations for i in infos))
        result.meta.cal_step.ipc = "COMPLETE"
        return result


class Detector1TaichiPipeline(Detector1Pipeline):
    """``calwebb_detector1`` with :class:`IPCTaichiStep` in the ``ipc`` slot."""

    class_alias = "calwebb_detector1_taichi"

    step_defs = dict(Detector1Pipeline.step_defs, ipc=IPCTaichiStep)

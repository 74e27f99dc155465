"""A Roman pipeline step: signal-dependent IPC on Roman ASDF products (``pip install
ipc_taichi[roman,jwst]``: roman_datamodels and stpipe).

romancal has no IPC step (spacetelescope/romancal #237). :class:`RomanIPCTaichiStep`
(alias ``roman_ipc_taichi``, registered through stpipe's ``stpipe.steps`` entry point)
decouples a Roman ``RampModel`` (resultants in DN, after bias and reference-pixel
correction) or a level-2 ``ImageModel`` (DN/s) exactly as ``ipc-taichi decouple``
decouples the same ASDF file: the step writes the model it is given to a temporary
ASDF file and runs :func:`ipc_taichi.products.process_asdf` on it, the command line's
own code, so the plan (units, gain, DQ bits, reference pixels, edge), the correction
and the record (``meta.ipc_taichi``, ``meta.cal_step.ipc``) are those of the command
line, bit for bit. The cost is one write and one read of the model.

.. code-block:: console

    strun roman_ipc_taichi r0000101001001001001_0001_wfi01_refpix.asdf \\
        --gain=2.0 --model=wfi01_ipc.json

The step is an ``stpipe`` Step on ``roman_datamodels`` (romancal, whose ``RomanStep``
adds CRDS handling this step does not need, is not a dependency): no reference file
and no parameter file is fetched, so it runs offline. Like any stpipe Step it runs as
a post-hook of romancal's ``refpix`` step in the stock ``roman_elp``, where the
resultants hold collected charge (docs/products.md: the same last-dot rule as for
JWST; :func:`roman_configured_step` makes the configured subclass to name).
"""

import logging
import os
import tempfile

import numpy as np

try:
    import roman_datamodels.datamodels as rdm
    from stpipe import Step
except ImportError as exc:  # the optional extras are not installed
    raise ImportError("the Roman step needs roman_datamodels and stpipe: "
                      "pip install 'ipc_taichi[roman,jwst]'") from exc

from .. import __version__
from .hooks import configured_subclass
from .options import ProductOptions
from .roman import process_asdf
from .stepspec import SPEC, coupling_of

__all__ = ["RomanIPCTaichiStep", "roman_configured_step"]

log = logging.getLogger(__name__)


class RomanIPCTaichiStep(Step):
    """Remove signal-dependent IPC (Donlon, Ninkov & Baum 2018) from a Roman ramp or image."""

    class_alias = "roman_ipc_taichi"

    spec = SPEC + """
        output_ext = string(default='.asdf')  # Roman products are ASDF
    """

    @classmethod
    def _datamodels_open(cls, init, **kwargs):
        return rdm.open(init, **kwargs)

    @classmethod
    def get_config_from_reference(cls, dataset, disable=None, crds_observatory=None):
        """No parameter reference file exists for this step: never ask CRDS."""
        return cls._empty_config()

    def coupling(self):
        """The coupling model of the parameters (:func:`.stepspec.coupling_of`)."""
        return coupling_of(self, "a Roman ramp")

    def options(self):
        """The :class:`~ipc_taichi.products.options.ProductOptions` of the
        parameters, those ``ipc-taichi decouple`` makes of the same options."""
        return ProductOptions.from_kwargs(
            gain=self.gain, dq_bits=self.dq_bits, refpix=self.refpix,
            saturation=self.saturation, max_iter=self.max_iter, tol=self.tol, arch=self.arch,
            precision=self.precision, edge=self.edge, noise=self.noise, model_chosen=True)

    def process(self, step_input):
        """Decouple the model as ``ipc-taichi decouple`` decouples its file."""
        if self.gain is None:
            raise ValueError("roman_ipc_taichi: give the gain in e-/DN (gain=...)")
        coupling = self.coupling()
        with self.open_model(step_input) as dm:
            name = os.path.basename(str(dm.meta.get("filename") or "roman.asdf"))
            with tempfile.TemporaryDirectory(prefix="roman_ipc_taichi-") as tmp:
                src, dst = os.path.join(tmp, name), os.path.join(tmp, "out", name)
                os.mkdir(os.path.dirname(dst))
                dm.save(src)
                summary = process_asdf(src, dst, "decouple", model=coupling,
                                       options=self.options())
                with rdm.open(dst, lazy_tree=False, memmap=False) as out:
                    result = out.copy()
        infos = summary["infos"]
        log.info("roman_ipc_taichi %s: %s, edge %s, gain %g e-/DN, %d frames, at most %d "
                      "iterations", __version__, coupling.describe(), summary["edge"],
                      self.gain, len(infos), max(i.iterations for i in infos))
        if not all(i.converged for i in infos) and self.tol:
            log.warning("roman_ipc_taichi: %d of %d frames did not meet the stopping rule",
                             sum(1 for i in infos if not i.converged), len(infos))
        result.data = np.asarray(result.data)
        return result


def roman_configured_step(name, **parameters):
    """A subclass of :class:`RomanIPCTaichiStep` whose parameters default to
    ``parameters``, defined in the calling module: the post-hook string
    ``"module.name"`` with no dot in its arguments
    (:func:`ipc_taichi.products.hooks.configured_subclass`)."""
    return configured_subclass(RomanIPCTaichiStep, name, parameters)

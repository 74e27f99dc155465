"""What the JWST and the Roman Step share: their parameters and the rule that
makes a coupling model of them.

Both Steps take the options of ``ipc-taichi decouple`` under the same names
(:data:`SPEC`, a configobj spec the Steps extend), and both ask for the
detector's coupling explicitly (:func:`coupling_of`): a model file, or a law
with its geometry and edge; the paper's law is never a silent default.
"""

from .. import iteration
from ..model import CouplingModel

__all__ = ["SPEC", "coupling_of"]

SPEC = f"""
        model = string(default=None)  # coupling-model file (JSON, from ipc-taichi calibrate)
        law = string(default=None)  # coupling law alpha(S,N), in electrons (or model=)
        geometry = string(default=None)  # neighbour weights, e.g. horizontal=1,vertical=0.9
        edge = option('zero', 'isolated', default=None)  # asked for; default: from the frame
        gain = float(default=None)  # e-/DN (required)
        dq_bits = string(default='DO_NOT_USE,SATURATED')  # flags of pixels left out
        saturation = float(default=None)  # DN at or above which a pixel is left out
        refpix = integer(default=None)  # reference border; default: REFERENCE_PIXEL flags
        max_iter = integer(default={iteration.MAX_ITER})  # at most this many Jacobi iterations
        tol = float(default={iteration.TOL!r})  # stop when max|dS| <= tol * max|S|
        arch = string(default=None)  # Taichi arch: auto, cpu, cuda
        precision = string(default=None)  # f64 or f32
        noise = option('propagate', 'keep', default='propagate')  # err, var_*
"""
"""The Steps' shared parameters (each Step's ``spec`` adds its own)."""


def coupling_of(step, product):
    """The coupling model of ``step``'s parameters: ``model`` (a file) or
    ``law`` (with ``geometry``, ``edge``); ``product`` names what needs it in
    the refusal ("a JWST ramp")."""
    name = step.class_alias
    if step.model:
        if step.law or step.geometry or step.edge:
            raise ValueError(f"{name}: give model= or law=/geometry=/edge=, not both "
                             "(the model file holds its law, geometry and edge)")
        return CouplingModel.load(step.model)
    if not step.law:
        raise ValueError(f"{name}: {product} needs its detector's coupling: give "
                         "model=FILE (from 'ipc-taichi calibrate') or law=...")
    return CouplingModel.resolve(step.law, step.geometry, step.edge)

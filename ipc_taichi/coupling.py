"""The forward model: couple a signal frame into a measured frame (paper Eq. 3).

``M(p) = S(p) + sum_q [ w(q->p) alpha(S_q, S_p) S_q - w(p->q) alpha(S_p, S_q) S_p ]``

Edge rules
----------
``zero`` (default)
    Outside the frame are pixels with zero signal. They take charge from the
    frame's border pixels (``alpha(S, 0) * S``) and give none back, so total
    charge leaks out at the border, as it does into a real detector's
    reference pixels or beyond a subarray.
``isolated``
    No coupling across the frame edge: border pixels simply have fewer
    neighbours. Total charge is conserved exactly.

Bad pixels (NaN or inf) neither give nor take charge and stay NaN in the
output; they are treated like the outside of an ``isolated`` frame. Pixels
flagged in ``mask`` (e.g. from a DQ array) likewise neither give nor take
charge, and keep their input value.
"""

from ._engine import as_result, as_stack, run_couple, start
from .model import CouplingModel

__all__ = ["couple"]


def couple(signal, law=None, geometry=None, edge=None, arch=None, precision=None,
           layout=None, *, model=None, mask=None, out=None):
    """Apply signal-dependent IPC to ``signal`` (2-D frame or 3-D stack).

    Parameters
    ----------
    signal : array_like, shape (ny, nx) or (n, ny, nx)
        Collected charge per pixel (``signal[y, x]``), in electrons. Any real
        dtype or byte order; negative values are valid; NaN/inf mark bad
        pixels. A PyTorch tensor (CPU or CUDA), or a CuPy/JAX array (through
        DLPack and PyTorch), stays on its device: see :mod:`ipc_taichi._device`.
    law : str, float, law object or None
        See :func:`ipc_taichi.laws.get_law`. ``None``: the paper's law
        (``"donlon2018"``).
    geometry : Geometry, dict, str or None
        Neighbours and weights (``None``: 4 nearest, weight 1).
    edge : {"zero", "isolated"} or None
        What lies beyond the frame (see module docstring); ``None``: ``"zero"``.
    arch, precision : str, optional
        Passed to :func:`ipc_taichi.runtime.init`.
    layout : {None, "lanes", "sweep", "pixel"}
        Kernel loop layout (see :mod:`ipc_taichi._kernels`); ``None`` picks the
        one that suits the arch (``lanes`` on the CPU, ``pixel`` on CUDA). Results
        agree to rounding (``lanes`` and ``sweep`` bit for bit).
    model : CouplingModel, str or path-like, optional
        The law, geometry and edge as one value, or the path of a model file
        (:meth:`ipc_taichi.model.CouplingModel.load`); then ``law``,
        ``geometry`` and ``edge`` must be left ``None`` (else
        :class:`~ipc_taichi.errors.IPCInputError`).
    mask : array_like of bool, optional
        True where a pixel is not trusted (same shape as a frame or as the
        stack): it neither gives nor takes charge and keeps its input value.
        A NumPy masked array's own mask is used the same way. For a device
        array the mask may be a NumPy array or a boolean array of its kind.
    out : array, optional
        Where to write the result: the input's kind, its shape, the runtime
        precision, contiguous (e.g. a page-locked buffer from
        :func:`ipc_taichi.engine.pinned_empty` reused frame after frame). A
        NumPy ``out`` may also be any writeable floating-point array of the
        shape (another precision or byte order, strided), the result rounded
        into it as it is stored (on the CPU in the same pass; on CUDA by one
        more copy at the end).

    Returns
    -------
    measured : ndarray or the input's array kind
        Same shape, in the runtime precision (float64 by default), on the
        input's device; a masked array for a masked input.

    Examples
    --------
    >>> import numpy as np, ipc_taichi
    >>> s = np.zeros((5, 5)); s[2, 2] = 10000.0
    >>> m = ipc_taichi.couple(s, law="constant:0.01", arch="cpu")
    >>> float(round(m[2, 2], 6)), float(round(m[2, 3], 6))
    (9600.0, 100.0)
    """
    frames = as_stack(signal, "signal", mask)
    model = CouplingModel.resolve(law, geometry, edge, model=model)
    info = start(arch, precision)
    result = run_couple(frames, model, info, layout, out=out)
    return as_result(result, frames, out)

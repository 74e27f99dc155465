"""The inputs of :func:`ipc_taichi.couple` and :func:`ipc_taichi.decouple`:
validated once (:func:`as_stack`) as a stack of frames in their own kind (a
NumPy array, or a PyTorch tensor standing for every device kind, see
:mod:`ipc_taichi._device`), and the result handed back as the input was given
(:func:`as_result`).
"""

import dataclasses

import numpy as np

from ._device import DEVICE_KINDS, from_torch, kind_of, to_torch
from .errors import IPCInputError

__all__ = ["Frames", "as_stack", "as_result"]


@dataclasses.dataclass
class Frames:
    """A validated input: the stack ``(n, ny, nx)`` in its own kind.

    ``data`` is a NumPy array (kind ``numpy``) or a PyTorch tensor (every other
    kind, CuPy/JAX/DLPack already wrapped); ``bad`` the untrusted-pixel mask of
    the same kind and shape, or ``None``; ``like`` the object given (for the
    result's kind and mask).
    """

    data: object
    bad: object
    was_2d: bool
    kind: str
    like: object

    @property
    def shape(self):
        return tuple(self.data.shape)

    @property
    def on_device(self):
        return self.kind in DEVICE_KINDS


def as_stack(data, what, mask=None):
    """Validate ``data`` (and ``mask``) as a 2-D frame or a 3-D stack; returns :class:`Frames`."""
    kind = kind_of(data)
    like = data
    if kind != "numpy":
        return _device_stack(to_torch(data, kind), kind, like, what, mask)
    if isinstance(data, np.ma.MaskedArray):
        own = np.ma.getmaskarray(data)
        mask = own if mask is None else (own | _host_mask(mask))
        data = data.data
    try:
        arr = np.asarray(data)
    except Exception as exc:  # ragged lists and the like
        raise IPCInputError(f"{what}: cannot be read as an array ({exc})") from None
    _check_shape(arr.shape, arr.dtype.kind in "iuf", str(arr.dtype), what)
    if mask is not None:
        mask = _host_mask(mask)
        if mask.dtype != bool:
            raise IPCInputError(f"{what}: mask must be boolean (True = not trusted), got "
                                f"dtype {mask.dtype}")
        try:
            mask = np.broadcast_to(mask, arr.shape)
        except ValueError:
            raise IPCInputError(f"{what}: mask of shape {mask.shape} does not fit data of "
                                f"shape {arr.shape}") from None
        if not mask.any():
            mask = None
    was_2d = arr.ndim == 2
    if was_2d:
        arr = arr[np.newaxis]
        mask = None if mask is None else mask[np.newaxis]
    return Frames(arr, mask, was_2d, "numpy", like)


def _host_mask(mask):
    if kind_of(mask) != "numpy":
        return np.asarray(to_torch(mask, kind_of(mask)).cpu().numpy())
    return np.asarray(mask)


def _check_shape(shape, real, dtype, what):
    if not real:
        raise IPCInputError(f"{what}: dtype {dtype} is not a real number type")
    if len(shape) not in (2, 3):
        raise IPCInputError(f"{what}: expected a 2-D frame (ny, nx) or a 3-D stack "
                            f"(n, ny, nx), got {len(shape)}-D shape {tuple(shape)}")
    if int(np.prod(shape)) == 0:
        raise IPCInputError(f"{what}: empty array of shape {tuple(shape)}")


def _device_stack(tensor, kind, like, what, mask):
    import torch

    tensor = tensor.detach()  # the result is not differentiable
    dt = tensor.dtype
    real = (dt.is_floating_point or dt in _torch_integers(torch)) and not dt.is_complex
    _check_shape(tuple(tensor.shape), real, str(dt), what)
    bad = None
    if mask is not None:
        mk = kind_of(mask)
        bad = to_torch(mask, mk) if mk != "numpy" else torch.from_numpy(
            np.ascontiguousarray(np.asarray(mask)))
        if bad.dtype != torch.bool:
            raise IPCInputError(f"{what}: mask must be boolean (True = not trusted), got "
                                f"dtype {bad.dtype}")
        try:
            bad = torch.broadcast_to(bad.to(tensor.device), tensor.shape)
        except RuntimeError:
            raise IPCInputError(f"{what}: mask of shape {tuple(bad.shape)} does not fit data "
                                f"of shape {tuple(tensor.shape)}") from None
        if not bool(bad.any()):
            bad = None
    was_2d = tensor.dim() == 2
    if was_2d:
        tensor = tensor.unsqueeze(0)
        bad = None if bad is None else bad.unsqueeze(0)
    return Frames(tensor, bad, was_2d, kind, like)


def _torch_integers(torch):
    """PyTorch's integer dtypes (the unsigned 16/32/64-bit ones exist from 2.3),
    accepted as NumPy's integer dtypes are."""
    names = ("int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64")
    return tuple(getattr(torch, n) for n in names if hasattr(torch, n))


def as_result(stack, frames, out=None):
    """The result stack shaped and typed as the input was given: a frame for a
    2-D input, a masked array (with the input's mask) for a masked input, the
    input's kind for a device array; the caller's NumPy ``out`` itself when
    one was given (as NumPy's ``out=`` does)."""
    result = stack[0] if frames.was_2d else stack
    if isinstance(out, np.ndarray) and frames.kind == "numpy" \
            and not isinstance(frames.like, np.ma.MaskedArray):
        return out
    if frames.kind != "numpy":
        return from_torch(result, frames.kind, frames.like)
    if isinstance(frames.like, np.ma.MaskedArray):
        result = np.ma.MaskedArray(result, mask=np.ma.getmaskarray(frames.like).copy())
    return result

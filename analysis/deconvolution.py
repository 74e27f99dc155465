"""Linear deconvolution baselines for the paper's section 3.2: Lucy-Richardson and Wiener.

Both assume one fixed blur kernel for the whole frame, which signal-dependent
IPC is not; they get the constant-alpha kernel that best stands for the frame
(:func:`effective_alpha`). The restorations themselves are scikit-image's
:func:`skimage.restoration.richardson_lucy` and :func:`skimage.restoration.wiener`.

Scaling (what scikit-image expects, and what we do about it)
------------------------------------------------------------
Both functions are written for images in [0, 1] (``richardson_lucy`` starts
from a flat 0.5 estimate and, with ``clip=True``, clips the result to
[-1, 1]; ``wiener`` clips likewise). We divide the frame by a fixed scale
(its maximum), call them with ``clip=False`` so that no restored value is
cut off, and multiply back. Lucy-Richardson is defined for non-negative data
only (it divides by the blurred estimate and multiplies by ratios): pixels
that read noise has pushed below zero are set to zero first, and the number
of them is reported. Both treat the outside of the frame as zero: LR through
zero-padded convolution, Wiener (FFT-based, so periodic) by padding the frame
with :data:`WIENER_PAD` zeros before the transform and cropping after it.

Tuning without the truth: :func:`wiener_balance` gives Wiener's balance from
the measured frame and the known read noise (the Wiener-Hunt balance for white
noise and a Gaussian prior on the image's Laplacian), as LR's fixed iteration
count and the kernel of :func:`effective_alpha` do for LR.
"""

import numpy as np

__all__ = ["effective_alpha", "ipc_kernel", "lucy_richardson", "wiener_filter", "wiener_balance"]

WIENER_PAD = 16
"""Zeros added around the frame before Wiener's FFT [px]: the FFT treats the frame as
periodic; padded with zeros it sees what LR's zero-padded convolution sees beyond the edge."""


def effective_alpha(measured, law="donlon2018"):
    """The signal-weighted mean coupling of a frame over its nearest-neighbour pairs.

    ``sum alpha(M_p, M_q) (M_p + M_q) / sum (M_p + M_q)`` over all horizontal
    and vertical pairs: the constant alpha that moves the same total charge
    between the frame's neighbours as the law does (to first order). It uses
    only the measured frame, as a user without the truth would.
    """
    from ipc_taichi import get_law

    law = get_law(law)
    m = np.asarray(measured, dtype=np.float64)
    num = den = 0.0
    for a, b in ((m[:, :-1], m[:, 1:]), (m[:-1, :], m[1:, :])):
        w = np.clip(a, 0, None) + np.clip(b, 0, None)
        num += float(np.sum(law.alpha(a, b) * w))
        den += float(np.sum(w))
    return num / den


def ipc_kernel(alpha, geometry=None):
    """The constant-alpha IPC convolution kernel (:meth:`ipc_taichi.Geometry.kernel`)."""
    from ipc_taichi import Geometry

    geometry = Geometry.nearest() if geometry is None else geometry
    return geometry.kernel(alpha)


def lucy_richardson(measured, kernel, num_iter=30):
    """Lucy-Richardson restoration (scikit-image) with honest scaling.

    Returns
    -------
    restored : ndarray
        In the units of ``measured``.
    n_clipped : int
        Pixels below zero that were set to zero before the restoration.
    """
    from skimage.restoration import richardson_lucy

    m = np.asarray(measured, dtype=np.float64)
    n_clipped = int(np.count_nonzero(m < 0))
    m = np.clip(m, 0.0, None)
    scale = float(m.max()) or 1.0
    restored = richardson_lucy(m / scale, kernel, num_iter=int(num_iter), clip=False)
    return restored * scale, n_clipped


def wiener_filter(measured, kernel, balance, pad=WIENER_PAD):
    """Wiener(-Hunt) restoration (scikit-image, Laplacian regulariser) in data units.

    The frame is zero-padded by ``pad`` pixels before the FFT (so that, like
    LR, the restoration sees zeros beyond the frame, not the opposite edge) and
    cropped back after it.
    """
    from skimage.restoration import wiener

    m = np.asarray(measured, dtype=np.float64)
    scale = float(np.abs(m).max()) or 1.0
    p = int(pad)
    padded = np.pad(m / scale, p) if p else m / scale
    out = wiener(padded, kernel, balance, clip=False) * scale
    return out[p:out.shape[0] - p, p:out.shape[1] - p] if p else out


def wiener_balance(measured, read_noise):
    """Wiener's balance from the data and the known read noise, without the truth.

    ``read_noise**2 / var(L measured)`` with ``L`` the 4-neighbour Laplacian
    (scikit-image's default regulariser): the ratio of the noise variance to the
    variance of the image's Laplacian, the balance of the Wiener-Hunt filter for
    white noise and a Gaussian prior on the Laplacian. It is scale-free (the
    frame's scaling cancels) and 0 (the inverse filter) without read noise.
    """
    m = np.asarray(measured, dtype=np.float64)
    lap = (4 * m[1:-1, 1:-1] - m[:-2, 1:-1] - m[2:, 1:-1] - m[1:-1, :-2] - m[1:-1, 2:])
    var = float(lap.var())
    return float(read_noise) ** 2 / var if var > 0 else 0.0

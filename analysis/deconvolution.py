"""Linear deconvolution baselines for the paper's section 3.2: Lucy-Richardson and Wiener.

Both assume one fixed blur kernel for the whole frame, which signal-dependent
IPC is not; they get the constant-alpha kernel that best stands for the frame
(:func:`effective_alpha`). Wiener is scikit-image's
:func:`skimage.restoration.wiener`. Lucy-Richardson is the update of
:func:`skimage.restoration.richardson_lucy` written out (the same flat 0.5
start, the same ``1e-12`` guard, zero-padded "same" convolution; equal to
scikit-image's to rounding, tests/test_analysis_simulate.py), so that it can
report the iterates at several iteration counts from one run and stop at
convergence; the 3x3 kernel is applied by direct convolution, ~10x faster
than scikit-image's FFT path for this kernel.

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
from scipy import ndimage

__all__ = ["effective_alpha", "ipc_kernel", "lucy_richardson", "lucy_richardson_path",
           "wiener_filter", "wiener_balance"]

LR_EPS = 1e-12
"""Guard added to the blurred estimate before LR divides by it (scikit-image's value)."""

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
    """Lucy-Richardson restoration with honest scaling (:func:`lucy_richardson_path`).

    Returns
    -------
    restored : ndarray
        In the units of ``measured``, after ``num_iter`` iterations.
    n_clipped : int
        Pixels below zero that were set to zero before the restoration.
    """
    path = lucy_richardson_path(measured, kernel, (int(num_iter),))
    return path.restored[0], path.n_clipped


class LRPath:
    """Iterates of one Lucy-Richardson run (:func:`lucy_richardson_path`).

    Attributes
    ----------
    iterations : list of int
        The iteration count of each entry of ``restored``; the last entry is
        always the last iterate (at convergence, or after ``max_iter``).
    restored : list of ndarray
        The restorations, in the units of the measured frame.
    n_clipped : int
        Pixels below zero set to zero before the restoration.
    converged : bool
        Whether the run stopped because the largest change of one iteration
        fell below ``tol`` of the frame's maximum (always False without ``tol``).
    """

    def __init__(self, iterations, restored, n_clipped, converged):
        self.iterations, self.restored = iterations, restored
        self.n_clipped, self.converged = n_clipped, converged


def lucy_richardson_path(measured, kernel, checkpoints, tol=None, max_iter=None):
    """Lucy-Richardson iterates at several iteration counts, optionally to convergence.

    The update is scikit-image's: ``x <- x * (K^T * (m / (K * x + eps)))``
    from ``x = 0.5`` on the frame divided by its maximum (scikit-image expects
    [0, 1]), ``K *`` a zero-padded convolution of the frame's size; negative
    pixels (read noise) are set to zero first, since LR is defined for
    non-negative data only.

    Parameters
    ----------
    measured : 2-D array
    kernel : 2-D array
        The blur kernel (odd sides).
    checkpoints : sequence of int
        Iteration counts at which to keep the iterate.
    tol : float, optional
        Stop when ``max |x_k - x_(k-1)| < tol`` (in units of the frame's maximum).
    max_iter : int, optional
        At most this many iterations (default: the largest checkpoint).

    Returns
    -------
    LRPath
    """
    m = np.asarray(measured, dtype=np.float64)
    k = np.asarray(kernel, dtype=np.float64)
    n_clipped = int(np.count_nonzero(m < 0))
    m = np.clip(m, 0.0, None)
    scale = float(m.max()) or 1.0
    m = m / scale
    marks = sorted({int(c) for c in checkpoints})
    last = int(max_iter) if max_iter is not None else (marks[-1] if marks else 0)
    mirror = k[::-1, ::-1]
    x = np.full(m.shape, 0.5)
    iterations, restored, converged = [], [], False
    for it in range(1, last + 1):
        blurred = ndimage.convolve(x, k, mode="constant", cval=0.0) + LR_EPS
        new = x * ndimage.convolve(m / blurred, mirror, mode="constant", cval=0.0)
        change = float(np.abs(new - x).max())
        x = new
        if it in marks:
            iterations.append(it)
            restored.append(x * scale)
        if tol is not None and change < tol:
            converged = True
            break
    if last and (not iterations or iterations[-1] != it):
        iterations.append(it)  # the last iterate is always kept
        restored.append(x * scale)
    return LRPath(iterations, restored, n_clipped, converged)


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

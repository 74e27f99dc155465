"""The detector chain every simulation in this project shares.

::

    expected collected charge  --collect (shot noise)-->  signal [e-]
    signal  --IPC (couple with the CouplingModel)-->  node signal
    node signal  --response (optional, e.g. non-linearity)-->  read-out signal
    read-out signal  + read noise  -->  measured [e-]

IPC acts on the charge that sits on the pixel nodes, shot noise included, so
the Poisson draw comes before the coupling; read noise is added by the
read-out electronics after it and is not coupled. Effects acting on the charge
on its way to the node (diffusion, brighter-fatter, dark current) shape the
*expected* charge before :func:`collect`; the discovery workflow adds them
there (:mod:`ipc_taichi.discover.model`).

Draw order with a seeded generator: :func:`collect` draws the Poisson
variates first, :func:`read_noise` the Gaussian ones next, so a chain run with
the same seed gives the same numbers.
"""

from dataclasses import dataclass

import numpy as np

from .coupling import couple
from .model import CouplingModel

__all__ = ["collect", "read_noise", "read_out", "expose", "Exposure"]


def collect(expected, rng=None):
    """The collected charge [e-]: a Poisson draw of the expected charge
    (negative expectations count as zero), or a float64 copy when ``rng`` is
    ``None`` (no shot noise)."""
    expected = np.asarray(expected, dtype=np.float64)
    if rng is None:
        return expected.copy()
    return rng.poisson(np.clip(expected, 0.0, None)).astype(np.float64)


def read_noise(shape, sigma, rng):
    """One instance of Gaussian read noise of RMS ``sigma`` [e-] (zeros, and
    no draw, when ``sigma`` is 0)."""
    sigma = float(sigma)
    if not (np.isfinite(sigma) and sigma >= 0):
        raise ValueError(f"read noise must be finite and >= 0, got {sigma!r}")
    if sigma == 0:
        return np.zeros(shape)
    return rng.normal(0.0, sigma, shape)


def read_out(charge, model, response=None, arch=None, precision=None):
    """The node signal the electronics see: ``charge`` coupled by ``model``
    (a :class:`CouplingModel`, or anything :meth:`CouplingModel.resolve`
    takes), then ``response`` (a callable on the coupled signal) if given."""
    model = CouplingModel.resolve(model)
    m = np.asarray(couple(charge, model=model, arch=arch, precision=precision), dtype=np.float64)
    return m if response is None else response(m)


@dataclass
class Exposure:
    """One simulated exposure (all ``image[y, x]``, electrons).

    Attributes
    ----------
    signal : ndarray
        Collected charge (with shot noise when it was drawn): the truth IPC acts on.
    noise : ndarray
        The read-noise instance.
    measured : ndarray
        ``read_out(signal) + noise``.
    """

    signal: np.ndarray
    noise: np.ndarray
    measured: np.ndarray


def expose(expected, model, readnoise, rng, shot_noise=True, response=None, arch=None,
           precision=None):
    """Run the whole chain on the expected collected charge; returns an :class:`Exposure`."""
    signal = collect(expected, rng if shot_noise else None)
    noise = read_noise(signal.shape, readnoise, rng)
    measured = read_out(signal, model, response, arch, precision) + noise
    return Exposure(signal, noise, measured)

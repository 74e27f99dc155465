"""An independent generator of flat ramps with a hidden non-linear IPC and brighter-fatter.

Imports nothing from ``ipc_taichi``. Written from the physics:

- **Collection.** Charge is collected in ``substeps`` equal steps per group.
  In each step pixel ``p`` gains ``Poisson(rate_p dt)`` electrons with

      rate_p = I r_p (1 + sum_d a(d) Q(p + d)),

  ``I`` the mean photo-current [e- per step], ``r_p`` a fixed pixel response
  map (1 % rms, the same for every integration), ``Q`` the charge already
  collected (zero beyond the frame) and ``a`` a hidden brighter-fatter kernel
  per electron (pixel area ``1 + sum_d a(d) Q(p + d)``; ``sum a = 0``,
  ``a(0,0) < 0``). Without brighter-fatter the steps of a group are one
  Poisson draw (a sum of Poisson draws is a Poisson draw).
- **Readout.** At the end of each group the charge is read through a
  non-linear IPC: one coupling step :func:`tests.independent.ipcgen.couple`
  on the charge present at that read, by a hidden law of this module
  (:data:`LAWS`, registered in ``ipcgen.LAWS`` under ``ramp_<name>``) and
  the anisotropic weights :data:`WEIGHTS`; then Gaussian read noise [e-] and
  division by the gain [e-/DN].

To first order the brighter-fatter covariance of the charge at lag ``d != 0``
after collecting ``Q`` electrons is ``a(d) Q^2`` (each pixel's rate follows
its neighbour's accumulated shot noise), while IPC at readout gives
``~ 2 w(d) alpha Q``; :func:`brighter_fatter_covariance` gives it to all
orders of the linear response.

The hidden laws are symmetric, ``alpha(S, N) = alpha(N, S)``, functions of the
mean charge ``m = (S + N) / 2`` and of the asymmetry ``t = |S - N| / (S + N +
2000)``, of families the project does not ship:

- ``rising``: ``0.0044 + 0.0018 (2/pi) arctan(m / 20000) + 0.0003 t^2``
  (alpha(S, S) x 1.28 from 2 ke- to 50 ke-);
- ``falling``: ``0.0047 + 0.0021 exp(-(m / 30000)^2) + 0.0003 t^2``
  (alpha(S, S) x 0.71 from 2 ke- to 50 ke-).
"""

import os

import numpy as np

from . import ipcgen

__all__ = ["LAWS", "WEIGHTS", "BF_KERNEL", "AXES", "hidden_alpha", "truth_alpha_ss",
           "brighter_fatter_kernel", "brighter_fatter_covariance", "collect", "read_out",
           "flat_ramps", "flat_ramp_set"]

WEIGHTS = {(0, 1): 1.10, (0, -1): 1.10, (1, 0): 0.90, (-1, 0): 0.90,
           (1, 1): 0.07, (1, -1): 0.07, (-1, 1): 0.07, (-1, -1): 0.07,
           (0, 2): 0.025, (0, -2): 0.025, (2, 0): 0.015, (-2, 0): 0.015}
"""Hidden IPC geometry: x stronger than y by 22 %, diagonals and second neighbours."""

AXES = ipcgen.AXES
"""Named terms and one offset ``(dy, dx)`` of each."""

_BF_TERMS = {(0, 1): 4.0e-7, (1, 0): 3.4e-7, (1, 1): 1.1e-7, (0, 2): 0.5e-7,
             (2, 0): 0.35e-7, (1, 2): 0.25e-7, (2, 1): 0.2e-7, (2, 2): 0.1e-7}
"""Hidden brighter-fatter terms per electron for ``dy, dx >= 0`` (mirrored to all signs)."""


def brighter_fatter_kernel():
    """The hidden brighter-fatter kernel ``a`` [1/e-], 5x5 indexed ``[2+dy][2+dx]``,
    symmetric under ``dy -> -dy`` and ``dx -> -dx``, summing to 0."""
    a = np.zeros((5, 5))
    for (dy, dx), value in _BF_TERMS.items():
        for sy in (1, -1):
            for sx in (1, -1):
                a[2 + sy * dy, 2 + sx * dx] = value
    a[2, 2] = 0.0
    a[2, 2] = -a.sum()
    return a


BF_KERNEL = brighter_fatter_kernel()


def _mean_and_asymmetry(s, n):
    total = s + n
    return 0.5 * total, np.abs(s - n) / (total + 2000.0)


def _rising(s, n):
    m, t = _mean_and_asymmetry(s, n)
    return 0.0044 + 0.0018 * (2.0 / np.pi) * np.arctan(m / 20000.0) + 0.0003 * t ** 2


def _falling(s, n):
    m, t = _mean_and_asymmetry(s, n)
    return 0.0047 + 0.0021 * np.exp(-(m / 30000.0) ** 2) + 0.0003 * t ** 2


LAWS = {"rising": _rising, "falling": _falling}
for _name, _law in LAWS.items():
    ipcgen.LAWS.setdefault(f"ramp_{_name}", _law)


def hidden_alpha(law):
    """The hidden law ``alpha(S, N)`` (a fraction; ``S``, ``N`` in electrons)."""
    return LAWS[law]


def truth_alpha_ss(law, signal):
    """``w(term) alpha(S, S)`` of each named term (fractions) at charge ``signal`` [e-]."""
    s = np.asarray(signal, dtype=np.float64)
    a = LAWS[law](s, s)
    return {name: WEIGHTS[d] * a for name, d in AXES.items()}


def _area_change(charge, kernel):
    """``sum_d a(d) Q(p + d)`` with zero charge beyond the frame."""
    ny, nx = charge.shape
    padded = np.zeros((ny + 4, nx + 4))
    padded[2:-2, 2:-2] = charge
    out = np.zeros((ny, nx))
    for iy in range(5):
        for ix in range(5):
            if kernel[iy, ix] != 0.0:
                out += kernel[iy, ix] * padded[iy:iy + ny, ix:ix + nx]
    return out


def collect(charge, mean_rate, kernel, substeps, rng):
    """Collect one group's charge [e-] onto ``charge``.

    ``mean_rate`` is ``I r_p`` [e- per group]; ``kernel`` the brighter-fatter
    kernel or ``None``.
    """
    if kernel is None:
        return charge + rng.poisson(mean_rate)
    step = mean_rate / substeps
    for _ in range(substeps):
        charge = charge + rng.poisson(step * (1.0 + _area_change(charge, kernel)))
    return charge


def read_out(charge, law, gain, read_noise, rng):
    """One read [DN]: ``charge`` [e-] coupled by the hidden law (none when ``law``
    is ``None``), Gaussian read noise [e-] added, divided by the gain [e-/DN]."""
    measured = charge if law is None else ipcgen.couple(charge, f"ramp_{law}", WEIGHTS)
    return (measured + rng.normal(0.0, read_noise, charge.shape)) / gain


def _on_grid(offsets, size):
    grid = np.zeros((size, size))
    for (dy, dx), value in offsets.items():
        grid[dy % size, dx % size] += value
    return grid


def brighter_fatter_covariance(law, charge, steps, size=64):
    """What brighter-fatter adds to the covariance of a read [e-^2] on a flat.

    Linear response of the generator's collection: a fluctuation of charge
    ``dQ`` changes the neighbours' rates by ``I a(d) dQ``, so after ``n``
    equal steps of ``q = charge / n`` the power of the charge at spatial
    frequency ``k`` is ``q ((1 + x)^(2n) - 1) / ((1 + x)^2 - 1)``, with
    ``x = a_k q`` (``charge`` without brighter-fatter). The read sees it
    through the linearised IPC kernel ``K`` (``w(d) alpha(S, S)``, centre
    ``1 - sum``), power times ``K_k^2``.

    Parameters
    ----------
    law : {"rising", "falling"}
        The hidden IPC law at readout.
    charge : float
        Mean charge of the read [e-].
    steps : int
        Collection steps up to the read (groups x sub-steps).
    size : int
        The periodic grid (64 is far beyond the kernels' reach).

    Returns
    -------
    numpy.ndarray
        ``(5, 5)`` indexed ``[2+dy][2+dx]``: covariance with minus without
        brighter-fatter [e-^2].
    """
    bf = {(iy - 2, ix - 2): BF_KERNEL[iy, ix] for iy in range(5) for ix in range(5)}
    a_k = np.fft.fft2(_on_grid(bf, size)).real
    alpha = LAWS[law](charge, charge)
    ipc = _on_grid({d: w * alpha for d, w in WEIGHTS.items()}, size)
    ipc[0, 0] = 1.0 - ipc.sum()
    k2 = np.fft.fft2(ipc).real ** 2
    q = charge / steps
    x = a_k * q
    growth = np.where(np.abs(x) > 1e-12, ((1.0 + x) ** (2 * steps) - 1.0)
                      / np.where(np.abs(x) > 1e-12, (1.0 + x) ** 2 - 1.0, 1.0), steps)
    cov = np.fft.ifft2(q * (growth - steps) * k2).real
    return np.roll(cov, (2, 2), axis=(0, 1))[:5, :5]


def flat_ramps(law, bf, nints, ngroups, shape, level, gain, read_noise, substeps, seed):
    """The ramps (nints, ngroups, ny, nx) float32 [DN]; the last read collects ``level`` [e-]
    on average. ``law`` ``None`` reads without coupling."""
    rng = np.random.default_rng(seed)
    response = 1.0 + 0.01 * np.random.default_rng(seed + 1000).standard_normal(shape)
    mean_rate = (level / ngroups) * response
    kernel = BF_KERNEL if bf else None
    sci = np.empty((nints, ngroups) + tuple(shape), np.float32)
    for i in range(nints):
        charge = np.zeros(shape)
        for g in range(ngroups):
            charge = collect(charge, mean_rate, kernel, substeps, rng)
            sci[i, g] = read_out(charge, law, gain, read_noise, rng)
    return sci


def flat_ramp_set(folder, law="rising", bf=False, nints=16, ngroups=12, shape=(256, 256),
                  level=50000.0, gain=2.0, read_noise=12.0, substeps=4, seed=0):
    """Write one FITS file of flat ramps with a hidden non-linear IPC (and brighter-fatter).

    Parameters
    ----------
    folder : str
        Where the file goes (created if needed).
    law : {"rising", "falling"} or None
        The hidden IPC law at readout; ``None`` reads without coupling.
    bf : bool
        Collect with the hidden brighter-fatter kernel :data:`BF_KERNEL`.
    nints, ngroups : int
        Integrations and groups (one read at the end of each group).
    shape : tuple of int
        ``(ny, nx)``.
    level : float
        Mean charge of the last read [e-].
    gain : float
        [e-/DN].
    read_noise : float
        Per read [e-].
    substeps : int
        Collection steps per group (brighter-fatter only).
    seed : int
        Random seed (the response map comes from ``seed + 1000``).

    Returns
    -------
    dict
        ``path``, ``gain``, ``levels`` (mean charge of each read [e-]) and
        ``truth``: ``alpha_ss`` (callable ``S -> {term: w alpha(S, S)}``),
        ``bf_kernel`` (5x5 array [1/e-] or ``None``), ``weights``.
    """
    from astropy.io import fits

    sci = flat_ramps(law, bf, nints, ngroups, shape, level, gain, read_noise, substeps, seed)
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, f"ramp_{law}_{'bf' if bf else 'nobf'}.fits")
    primary = fits.PrimaryHDU()
    primary.header["TELESCOP"] = "BLIND"
    primary.header["GAIN"] = gain
    hdu = fits.ImageHDU(sci, name="SCI")
    hdu.header["BUNIT"] = "DN"
    hdu.header["GAIN"] = gain
    fits.HDUList([primary, hdu]).writeto(path, overwrite=True)
    truth = {"alpha_ss": None if law is None else (lambda s: truth_alpha_ss(law, s)),
             "bf_kernel": BF_KERNEL.copy() if bf else None, "weights": dict(WEIGHTS)}
    levels = level * np.arange(1, ngroups + 1) / ngroups
    return {"path": path, "gain": gain, "levels": levels, "truth": truth}

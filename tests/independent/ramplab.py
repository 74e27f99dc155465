"""An independent generator of ramp lab files (``docs/discovery_format.md``,
"Ramps") for ``ipc-taichi discover``'s ramp statistics.

Imports nothing from ``ipc_taichi`` (NumPy and astropy only). Written from
the physics, read by read:

- Scene: a uniform background rate, flat square patches at a few rates and
  single hot pixels, e- per second (SCENE is this rate).
- Collection: between reads each pixel gains a Poisson number of electrons
  of mean ``rate x TFRAME`` (read 0 at ``TFIRST = TFRAME``), summed.
- Persistence (optional): an after-image of an earlier minute of the same
  scene, an extra rate ``A q exp(-t / tau)`` with ``q`` the earlier charge
  (linear in it), collected like light.
- IPC: a constant 3x3 kernel (``alpha`` to each nearest neighbour, zero
  beyond the frame) on the charge present at each read.
- Brighter-fatter (optional, ``brighter_fatter=(kx, ky)``): the charge is
  collected in sub-steps; before each, the boundary between two neighbours
  has moved into the fuller one by ``k Q0 tanh((Q_p - Q_q) / Q0) / 50 ke-``
  pixels (``Q0`` = 200 ke-, the charge collected so far), and the strip it
  swept hands the shrinking pixel's light to the other one.
- Signal-dependent IPC (optional, ``sdipc=g``): the coupling between two
  neighbours holding ``S`` and ``N`` is ``ALPHA (1 + g (2/pi) arctan(m /
  25 ke-))`` with ``m = (S + N)/2``, on the charge present at each read
  (pairwise, so it conserves charge inside the frame).
- Classical non-linearity (optional, ``nonlinearity=Qs``): each read value
  ``v`` becomes ``Qs (1 - exp(-v / Qs))`` (an exponential saturation, e-),
  pixel by pixel after the coupling.
- Read noise: Gaussian per read and pixel; optionally a row offset per read
  shared by every pixel of a row (correlated read noise, the 1/f picture of a
  readout channel), telegraph pixels whose level jumps between two values
  from read to read, and one-way steps at a random read (cosmic-ray hits).
"""

import numpy as np
from astropy.io import fits

ALPHA = 0.0125


def scene_rate(n, rng, background=20.0, rates=(200.0, 800.0, 2500.0), hot=3000.0):
    """A rate map (e-/s) of background, square patches and isolated hot pixels."""
    rate = np.full((n, n), background)
    cell = 8
    k = 0
    for y in range(2, n - cell, cell):
        for x in range(2, n - cell, cell):
            if k % 2 == 0:
                rate[y:y + 4, x:x + 4] = rates[(k // 2) % len(rates)]
            else:
                rate[y + 2, x + 2] = hot * (0.5 + rng.random())
            k += 1
    return rate


def _couple(q, alpha):
    out = (1.0 - 4.0 * alpha) * q
    out[:, 1:, :] += alpha * q[:, :-1, :]
    out[:, :-1, :] += alpha * q[:, 1:, :]
    out[:, :, 1:] += alpha * q[:, :, :-1]
    out[:, :, :-1] += alpha * q[:, :, 1:]
    return out


BF_SUBSTEPS = 6  # collection sub-steps per read with brighter-fatter
BF_Q0 = 200000.0  # e-: where the boundary shift starts to saturate
SDIPC_SCALE = 25000.0  # e-


def _collect_bf(rate, times, kx, ky, rng):
    """Charge at each read collected with moving boundaries (module docstring)."""
    edges = np.concatenate([[0.0], times])
    q = np.zeros(rate.shape)
    out = []
    for i in range(len(times)):
        dt = (edges[i + 1] - edges[i]) / BF_SUBSTEPS
        for _ in range(BF_SUBSTEPS):
            arrive = rate * dt
            gain = arrive.copy()
            for axis, k in ((1, kx), (0, ky)):
                a = [slice(None)] * 2
                b = [slice(None)] * 2
                a[axis], b[axis] = slice(None, -1), slice(1, None)
                a, b = tuple(a), tuple(b)
                shift = np.clip(k * BF_Q0 * np.tanh((q[a] - q[b]) / BF_Q0) / 50000.0,
                                -0.25, 0.25)
                moved = np.where(shift > 0, shift * arrive[a], shift * arrive[b])
                gain[a] -= moved
                gain[b] += moved
            q = q + rng.poisson(np.clip(gain, 0.0, None))
        out.append(q.copy())
    return np.array(out)


def _couple_sd(q, g, linear=False):
    """Pairwise coupling by the signal-dependent alpha (module docstring;
    ``linear``: ``ALPHA (1 + g m / 25 ke-)`` instead, a law outside the
    paper's family)."""
    def alpha(s, nb):
        m = 0.5 * (s + nb) / SDIPC_SCALE
        return ALPHA * (1.0 + g * (m if linear else (2.0 / np.pi) * np.arctan(m)))

    out = q.copy()
    pad = np.pad(q, ((0, 0), (1, 1), (1, 1)))
    ny, nx = q.shape[1:]
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nb = pad[:, 1 + dy:1 + dy + ny, 1 + dx:1 + dx + nx]
        out += alpha(q, nb) * (nb - q)
    return out


def make_ramp(n, nreads, tframe, readnoise, rng, persistence=None, row_noise=0.0,
              telegraph=None, steps_up=None, brighter_fatter=None, sdipc=None,
              nonlinearity=None, sdipc_linear=False):
    """``(rate, reads)`` of one ramp (module docstring). ``persistence`` is
    ``(A, tau)`` (per second, s), ``row_noise`` the row offsets' RMS (e-),
    ``telegraph`` ``(fraction of pixels, jump in e-)``, ``steps_up`` likewise
    for one-way steps, ``brighter_fatter`` ``(kx, ky)`` (fraction of a
    pixel's arrivals per boundary at 50 ke- difference), ``sdipc`` ``g``,
    ``nonlinearity`` ``Qs`` (e-), ``sdipc_linear`` the coupling linear in
    the pair's mean charge."""
    rate = scene_rate(n, rng)
    times = tframe * np.arange(1, nreads + 1)
    extra = np.zeros((nreads, n, n))
    if persistence is not None:
        amp, tau = persistence
        earlier = rate * 60.0  # the same scene for a minute before
        edges = np.concatenate([[0.0], times])
        decay = tau * (np.exp(-edges[:-1] / tau) - np.exp(-edges[1:] / tau))
        extra = amp * earlier[None] * decay[:, None, None]
    if brighter_fatter is not None:
        charge = _collect_bf(rate, times, *brighter_fatter, rng)
        if persistence is not None:
            charge = charge + np.cumsum(rng.poisson(extra), axis=0)
    else:
        charge = np.cumsum(rng.poisson(rate[None] * tframe + extra).astype(np.float64), axis=0)
    reads = _couple(charge, ALPHA) if sdipc is None else _couple_sd(charge, sdipc, sdipc_linear)
    if nonlinearity is not None:
        reads = nonlinearity * (1.0 - np.exp(-reads / nonlinearity))
    reads += rng.normal(0.0, readnoise, reads.shape)
    if row_noise:
        reads += rng.normal(0.0, row_noise, (nreads, n, 1))
    if telegraph is not None:
        fraction, jump = telegraph
        pixels = rng.random((n, n)) < fraction
        state = rng.random((nreads, n, n)) < 0.5
        reads += np.where(pixels[None] & state, jump, 0.0)
    if steps_up is not None:  # one-way steps at a random read (cosmic-ray hits)
        fraction, size = steps_up
        pixels = rng.random((n, n)) < fraction
        when = rng.integers(1, nreads, (n, n))
        reads += np.where(pixels[None] & (np.arange(nreads)[:, None, None] >= when[None]),
                          size, 0.0)
    return rate, reads


def make_file(path, n=32, nreads=8, tframe=2.0, pairs=1, seed=0, readnoise=10.0, **hidden):
    """Write a ramp lab file (``pairs`` ramps) and return what was hidden."""
    rng = np.random.default_rng(seed)
    hdus = [fits.PrimaryHDU()]
    hdus[0].header["READNOIS"] = readnoise
    hdus[0].header["SHOTNOIS"] = True
    hdus[0].header["IPCLAW"] = f"constant:{ALPHA}"
    for k in range(pairs):
        rate, reads = make_ramp(n, nreads, tframe, readnoise, rng, **hidden)
        s = fits.ImageHDU(rate.astype(">f4"), name="SCENE")
        s.header["EXTVER"] = k + 1
        m = fits.ImageHDU(reads.astype(">f4"), name="MEASURED")
        m.header["EXTVER"] = k + 1
        m.header["TFRAME"] = tframe
        hdus += [s, m]
    fits.HDUList(hdus).writeto(path, overwrite=True)
    return hidden

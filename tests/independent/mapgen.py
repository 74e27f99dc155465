"""An independent generator of lab files with a hidden IPC map (imports nothing from ipc_taichi).

The detector: a constant coupling ``ALPHA`` (0.60 %) between nearest
neighbours, multiplied per neighbour pair by a hidden map

    g(y, x) = (1 + GRADIENT (2 x / (nx - 1) - 1)) * (1 - WEAK if (y, x) in the disc)

evaluated at the pair's midpoint (a +-12 % gradient across x and a disc where
IPC is 40 % weaker). Written from the physics, not from the project's code:
each pair ``(p, q)`` is a capacitance that moves ``ALPHA g (S_p - S_q)`` from
``p`` to ``q`` (one step on the true charge; zero charge beyond the frame,
which therefore takes charge at the edge), done with NumPy slices of a
zero-padded frame, one pass per axis.

Files (FITS, JWST-like, in DN with a ``GAIN`` keyword):

- dark ramps ``SCI (1, ngroups, ny, nx)`` with isolated hot pixels (log-uniform
  final charge) and a dark current;
- flat ramps ``SCI (nints, ngroups, ny, nx)``: Poisson charge of a fixed
  response map (1 % rms) times a mean rate, read through the coupling at every
  group (no brighter-fatter);

with Gaussian read noise per read. ``neighbour_read_corr`` adds read noise
correlated between nearest neighbours (a correlated part ``c`` shared by
each pixel with its x neighbour: the lag-(0, 1) correlation is ``c``).
"""

import os

import numpy as np

__all__ = ["ALPHA", "GRADIENT", "WEAK", "map_factor", "in_disc", "truth_bonds",
           "truth_kernels", "couple", "dark_ramp", "flat_ramps", "write_map_set"]

ALPHA = 0.0060
"""Nearest-neighbour coupling of the uniform detector (fraction per pair)."""
GRADIENT = 0.12
"""The map's gradient: +-12 % from the left edge to the right."""
WEAK = 0.40
"""Inside the disc the coupling is this much weaker."""


def _disc(shape):
    ny, nx = shape
    return 0.55 * ny, 0.35 * nx, 0.2 * min(ny, nx)


def in_disc(y, x, shape):
    """True where ``(y, x)`` (pixels, may be fractional) lies in the weak disc."""
    cy, cx, r = _disc(shape)
    return (np.asarray(y, float) - cy) ** 2 + (np.asarray(x, float) - cx) ** 2 <= r * r


def map_factor(y, x, shape, mapped=True):
    """The hidden factor ``g`` at ``(y, x)`` (1 everywhere when not ``mapped``)."""
    y, x = np.broadcast_arrays(np.asarray(y, float), np.asarray(x, float))
    if not mapped:
        return np.ones(y.shape)
    nx = shape[1]
    g = 1.0 + GRADIENT * (2.0 * x / (nx - 1) - 1.0)
    return np.where(in_disc(y, x, shape), (1.0 - WEAK) * g, g)


def truth_bonds(shape, mapped=True):
    """The hidden factor of each bond: ``{(0, 1): (ny, nx), (1, 0): (ny, nx)}``,
    the value at ``[y, x]`` belonging to the pair ``(y, x) -- (y + dy, x + dx)``."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    return {(0, 1): map_factor(yy, xx + 0.5, shape, mapped),
            (1, 0): map_factor(yy + 0.5, xx, shape, mapped)}


def truth_kernels(shape, mapped=True):
    """Per-pixel 3x3 forward (scatter) kernels ``(3, 3, ny, nx)`` of the truth:
    ``K_p(d)`` = fraction of pixel ``p``'s charge moved to ``p + d`` (centre:
    what stays), as a JWST 4-D or Roman IPC4D reference would hold them."""
    ny, nx = shape
    yy, xx = np.mgrid[0:ny, 0:nx].astype(float)
    k = np.zeros((3, 3, ny, nx))
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        k[1 + dy, 1 + dx] = ALPHA * map_factor(yy + dy / 2, xx + dx / 2, shape, mapped)
    k[1, 1] = 1.0 - k.sum(axis=(0, 1))
    return k


def couple(charge, mapped=True):
    """One coupling step on the true charge [e-] (see the module docstring)."""
    s = np.asarray(charge, dtype=np.float64)
    ny, nx = s.shape
    padded = np.zeros((ny + 2, nx + 2))
    padded[1:-1, 1:-1] = s
    out = padded.copy()
    yy, xx = np.mgrid[-1:ny + 1, -1:nx + 1].astype(float)  # padded coordinates
    # x pairs: padded columns i, i + 1; midpoint at x = i - 1 + 1/2
    gx = map_factor(yy[:, :-1], xx[:, :-1] + 0.5, (ny, nx), mapped)
    t = ALPHA * gx * (padded[:, :-1] - padded[:, 1:])
    out[:, :-1] -= t
    out[:, 1:] += t
    gy = map_factor(yy[:-1, :] + 0.5, xx[:-1, :], (ny, nx), mapped)
    t = ALPHA * gy * (padded[:-1, :] - padded[1:, :])
    out[:-1, :] -= t
    out[1:, :] += t
    return out[1:-1, 1:-1]


def _read_noise(rng, shape, sigma, corr):
    noise = rng.normal(0.0, sigma, shape)
    if corr:
        # a part shared with the x neighbour: n = a e + b (s(x) + s(x-1)), corr(lag 1) = c
        b2 = corr / 2.0
        shared = rng.normal(0.0, sigma, (shape[0], shape[1] + 1))
        noise = (np.sqrt(1.0 - 2.0 * b2) * noise
                 + np.sqrt(b2) * (shared[:, 1:] + shared[:, :-1]))
    return noise


def _hot_positions(rng, shape, n, spacing=5, margin=8):
    ny, nx = shape
    taken = np.zeros(shape, bool)
    pos = []
    for _ in range(60 * n):
        if len(pos) >= n:
            break
        y, x = int(rng.integers(margin, ny - margin)), int(rng.integers(margin, nx - margin))
        if taken[max(y - spacing, 0):y + spacing + 1, max(x - spacing, 0):x + spacing + 1].any():
            continue
        taken[y, x] = True
        pos.append((y, x))
    return np.array(pos, dtype=int).reshape(-1, 2)


def dark_ramp(shape=(256, 256), ngroups=6, n_hot=900, gain=2.0, read_noise=12.0,
              dark_rate=0.5, mapped=True, neighbour_read_corr=0.0, charge_scale=1.0, seed=1):
    """A dark ramp [DN] ``(1, ngroups, ny, nx)`` float32 and its hot pixels.

    ``charge_scale`` multiplies every charge (hot pixels, dark current) before
    the read, as a detector with a different full scale would see it.
    """
    rng = np.random.default_rng(seed)
    hot = _hot_positions(rng, shape, n_hot)
    rate = np.full(shape, float(dark_rate))
    final = np.exp(rng.uniform(np.log(3000.0), np.log(60000.0), len(hot))) * charge_scale
    rate[hot[:, 0], hot[:, 1]] = final / ngroups
    charge = np.zeros(shape)
    sci = np.zeros((1, ngroups) + tuple(shape), np.float32)
    for g in range(ngroups):
        charge = charge + rng.poisson(rate)
        measured = couple(charge, mapped) + _read_noise(rng, shape, read_noise,
                                                        neighbour_read_corr)
        sci[0, g] = measured / gain
    return {"sci": sci, "hot": hot, "final": final}


def flat_ramps(shape=(256, 256), nints=12, ngroups=10, level=40000.0, gain=2.0,
               read_noise=12.0, mapped=True, neighbour_read_corr=0.0, seed=2):
    """Flat ramps [DN] ``(nints, ngroups, ny, nx)`` float32; the last read holds ``level`` e-."""
    rng = np.random.default_rng(seed)
    response = 1.0 + 0.01 * np.random.default_rng(seed + 1000).standard_normal(shape)
    rate = (level / ngroups) * response
    sci = np.empty((nints, ngroups) + tuple(shape), np.float32)
    for i in range(nints):
        charge = np.zeros(shape)
        for g in range(ngroups):
            charge = charge + rng.poisson(rate)
            sci[i, g] = (couple(charge, mapped)
                         + _read_noise(rng, shape, read_noise, neighbour_read_corr)) / gain
    return sci


def _write(path, sci, gain):
    from astropy.io import fits

    primary = fits.PrimaryHDU()
    primary.header["TELESCOP"] = "MAPLAB"
    primary.header["GAIN"] = gain
    hdu = fits.ImageHDU(sci, name="SCI")
    hdu.header["BUNIT"] = "DN"
    hdu.header["GAIN"] = gain
    fits.HDUList([primary, hdu]).writeto(path, overwrite=True)


def write_map_set(folder, shape=(256, 256), mapped=True, n_hot=900, ngroups=6, nints=12,
                  flat_groups=10, level=40000.0, gain=2.0, read_noise=12.0,
                  neighbour_read_corr=0.0, seed=0):
    """Write a dark, flat ramps and a held-out dark (new hot pixels) into ``folder``.

    Returns
    -------
    dict
        ``dark``, ``flats`` (one path), ``held_out`` (path), ``held_out_hot``
        (positions), ``gain``, ``read_noise``, ``shape``, ``mapped``.
    """
    os.makedirs(folder, exist_ok=True)
    tag = "map" if mapped else "flat"
    common = {"gain": gain, "read_noise": read_noise, "mapped": mapped,
              "neighbour_read_corr": neighbour_read_corr}
    dark = dark_ramp(shape, ngroups, n_hot, seed=seed + 1, **common)
    held = dark_ramp(shape, ngroups, n_hot, seed=seed + 3, **common)
    flats = flat_ramps(shape, nints, flat_groups, level, seed=seed + 2, **common)
    paths = {k: os.path.join(folder, f"{k}_{tag}.fits") for k in ("dark", "flats", "held_out")}
    _write(paths["dark"], dark["sci"], gain)
    _write(paths["held_out"], held["sci"], gain)
    _write(paths["flats"], flats, gain)
    return {**paths, "held_out_hot": held["hot"], "held_out_final": held["final"],
            "gain": gain, "read_noise": read_noise, "shape": tuple(shape), "mapped": mapped}

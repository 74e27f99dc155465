"""An independent generator of blind calibration files (imports nothing from ipc_taichi).

Its coupling is written here from the physics, not taken from the project's
law code: every ordered pair of pixels ``(p, q = p + d)`` exchanges
``w(d) * alpha(S_p, S_q) * S_p`` (one step on the true charge, zero charge
beyond the frame), evaluated with explicit NumPy loops over the offsets. The
hidden laws are of families the project does not ship (a tanh that rises
with the summed charge, a rational function that falls with it, with a term
quadratic in the asymmetry ``|S-N| / (S+N)``, and a constant), with
anisotropic nearest-neighbour weights, diagonal and second-neighbour terms.

Files written (FITS, the structure of JWST products):

- a dark ramp in DN (gain given apart): SCI (1, ngroups, ny, nx) float32,
  ``BUNIT = 'DN'``, PIXELDQ with DO_NOT_USE junk pixels (whose SCI holds
  garbage: NaN, huge or negative values), GROUPDQ;
- one flat file per level, SCI (nframes, ny, nx) float32 in DN with a DQ
  plane, made from a fixed response map (1 %) times the level.
"""

import os

import numpy as np

__all__ = ["LAWS", "WEIGHTS", "hidden_alpha", "couple", "dark_ramp", "flat_frames",
           "write_blind_set", "truth_per_axis"]

WEIGHTS = {(0, 1): 1.08, (0, -1): 1.08, (1, 0): 0.92, (-1, 0): 0.92,
           (1, 1): 0.08, (1, -1): 0.08, (-1, 1): 0.08, (-1, -1): 0.08,
           (0, 2): 0.02, (0, -2): 0.02, (2, 0): 0.015, (-2, 0): 0.015}
"""Hidden geometry: x stronger than y by 17 %, diagonals and second neighbours."""

AXES = {"x": (0, 1), "y": (1, 0), "diagonal": (1, 1), "second_x": (0, 2), "second_y": (2, 0)}


def _rising(s, n):
    total = s + n
    asym = np.abs(s - n) / (total + 2000.0)
    return 0.0046 + 0.0016 * np.tanh(total / 50000.0) + 0.0003 * asym ** 2


def _falling(s, n):
    total = s + n
    asym = np.abs(s - n) / (total + 2000.0)
    return 0.0050 + 0.0014 / (1.0 + total / 15000.0) + 0.0004 * asym ** 2


def _constant(s, n):
    return np.full(np.broadcast(s, n).shape, 0.0055)


LAWS = {"rising": _rising, "falling": _falling, "constant": _constant}


def hidden_alpha(kind):
    """The hidden law ``alpha(S, N)`` (fractions, electrons) of one family."""
    return LAWS[kind]


def truth_per_axis(kind, signal, neighbour):
    """``w(axis) * alpha(S, N)`` for each named axis."""
    a = LAWS[kind](np.asarray(signal, float), np.asarray(neighbour, float))
    return {name: WEIGHTS[d] * a for name, d in AXES.items()}


def couple(signal, kind, weights=WEIGHTS):
    """One coupling step on the true charge (zero charge outside the frame).

    For each pair of offsets ``{d, -d}`` the law is evaluated once per pixel
    pair ``(x, x + d)``, ``a = alpha(S_x, S_{x+d})``; ``x`` sends ``w(d) a S_x`` to
    ``x + d`` and receives ``w(-d) a S_{x+d}`` (the hidden laws are symmetric).
    """
    s = np.asarray(signal, dtype=np.float64)
    alpha = LAWS[kind]
    ny, nx = s.shape
    pad = 2
    P = np.zeros((ny + 2 * pad, nx + 2 * pad))
    P[pad:-pad, pad:-pad] = s
    out = P.copy()
    H, W = P.shape
    done = set()
    for (dy, dx), w in weights.items():
        if (-dy, -dx) in done:
            continue
        done.add((dy, dx))
        back = weights.get((-dy, -dx), 0.0)
        a_sl = (slice(max(-dy, 0), H - max(dy, 0)), slice(max(-dx, 0), W - max(dx, 0)))
        b_sl = (slice(max(dy, 0), H + min(dy, 0)), slice(max(dx, 0), W + min(dx, 0)))
        A = alpha(P[a_sl], P[b_sl])
        forward = w * A * P[a_sl]   # x -> x + d
        backward = back * A * P[b_sl]  # x + d -> x
        out[a_sl] += backward - forward
        out[b_sl] += forward - backward
    return out[pad:-pad, pad:-pad]


def _hot_positions(rng, shape, n, spacing=5, margin=6):
    ny, nx = shape
    taken = np.zeros(shape, bool)
    pos = []
    tries = 0
    while len(pos) < n and tries < 50 * n:
        tries += 1
        y, x = rng.integers(margin, ny - margin), rng.integers(margin, nx - margin)
        if taken[max(y - spacing, 0):y + spacing + 1, max(x - spacing, 0):x + spacing + 1].any():
            continue
        taken[y, x] = True
        pos.append((y, x))
    return np.array(pos)


def dark_ramp(kind, shape=(512, 512), ngroups=8, n_hot=700, gain=2.0, read_noise=12.0,
              dark_rate=0.5, n_junk=300, n_pairs=30, seed=1):
    """A dark ramp in DN with hot pixels, junk and a few hot pairs.

    Returns
    -------
    dict
        ``sci`` (1, ngroups, ny, nx) float32 DN, ``pixeldq`` uint32, ``groupdq``
        uint8, ``hot`` positions (isolated ones), ``gain``, ``read_noise`` [e-].
    """
    rng = np.random.default_rng(seed)
    hot = _hot_positions(rng, shape, n_hot)
    rate = np.full(shape, float(dark_rate))  # e- per group
    final = np.exp(rng.uniform(np.log(2500.0), np.log(60000.0), len(hot)))
    rate[hot[:, 0], hot[:, 1]] = final / ngroups
    # pairs of adjacent hot pixels (not isolated: the finder must leave them out)
    for _ in range(n_pairs):
        y, x = rng.integers(10, shape[0] - 10), rng.integers(10, shape[1] - 10)
        rate[y, x] = rate[y, x + 1] = rng.uniform(500, 5000)
    charge = np.zeros(shape)
    sci = np.zeros((1, ngroups) + tuple(shape), np.float32)
    for g in range(ngroups):
        charge = charge + rng.poisson(rate)
        measured = couple(charge, kind) + rng.normal(0.0, read_noise, shape)
        sci[0, g] = measured / gain
    pixeldq = np.zeros(shape, np.uint32)
    junk = rng.integers(0, shape[0], (n_junk, 2))
    pixeldq[junk[:, 0], junk[:, 1]] = 1  # DO_NOT_USE
    values = rng.choice([np.nan, 1e6, -5e4, 3e4], size=n_junk)
    sci[0, :, junk[:, 0], junk[:, 1]] = values[:, None]
    groupdq = np.zeros(sci.shape, np.uint8)
    return {"sci": sci, "pixeldq": pixeldq, "groupdq": groupdq, "hot": hot, "gain": gain,
            "read_noise": read_noise}


def flat_frames(kind, level, response, nframes=8, gain=2.0, read_noise=12.0, seed=2):
    """Flats at one level [e-] in DN: Poisson charge of ``level * response``, coupled,
    read noise added."""
    rng = np.random.default_rng(seed)
    frames = np.empty((nframes,) + response.shape, np.float32)
    for i in range(nframes):
        charge = rng.poisson(level * response).astype(np.float64)
        frames[i] = (couple(charge, kind) + rng.normal(0.0, read_noise, response.shape)) / gain
    return frames


def _write(path, sci, extra):
    from astropy.io import fits

    hdus = [fits.PrimaryHDU()]
    hdus[0].header["TELESCOP"] = "BLIND"
    h = fits.ImageHDU(sci, name="SCI")
    h.header["BUNIT"] = "DN"
    hdus.append(h)
    for name, data in extra.items():
        hdus.append(fits.ImageHDU(data, name=name))
    fits.HDUList(hdus).writeto(path, overwrite=True)


def write_blind_set(folder, kind, shape=(512, 512), ngroups=8, n_hot=700,
                    levels=(2000.0, 5000.0, 10000.0, 20000.0, 35000.0, 55000.0), nframes=8,
                    gain=2.0, read_noise=12.0, seed=0):
    """Write the dark ramp and the flats of one hidden law into ``folder``.

    Returns
    -------
    dict
        ``dark`` (path), ``flats`` (paths), ``gain``, ``read_noise``, ``hot``.
    """
    os.makedirs(folder, exist_ok=True)
    ramp = dark_ramp(kind, shape, ngroups, n_hot, gain, read_noise, seed=seed + 1)
    dark = os.path.join(folder, f"dark_{kind}.fits")
    _write(dark, ramp["sci"], {"PIXELDQ": ramp["pixeldq"], "GROUPDQ": ramp["groupdq"]})
    rng = np.random.default_rng(seed + 2)
    response = 1.0 + 0.01 * rng.standard_normal(shape)
    flats = []
    for k, level in enumerate(levels):
        frames = flat_frames(kind, level, response, nframes, gain, read_noise,
                             seed=seed + 10 + k)
        dq = np.zeros(shape, np.uint32)
        bad = rng.integers(0, shape[0], (100, 2))
        dq[bad[:, 0], bad[:, 1]] = 1
        frames[:, bad[:, 0], bad[:, 1]] = np.nan
        path = os.path.join(folder, f"flat_{kind}_{int(level)}.fits")
        _write(path, frames, {"DQ": dq})
        flats.append(path)
    return {"dark": dark, "flats": flats, "gain": gain, "read_noise": read_noise,
            "hot": ramp["hot"]}

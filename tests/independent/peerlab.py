"""An independent generator of lab files for ``ipc-taichi discover``.

Written without the project's effect code (nothing from ``ipc_taichi`` is
imported here: the files are written with astropy alone): the detector
physics is GalSim's, a peer simulator, and where GalSim has no such effect,
plain NumPy with forms that differ from the project's.

- Scene: a uniform background, flat rectangular patches, hot pixels (a
  uniform 1x1-pixel source, "top-hat", or all the light at the pixel centre,
  "point", as a pinhole projector makes them) and Moffat stars (GalSim
  ``drawImage``, pixel integrated), on a grid so they stay apart. A "sky"
  scene has only background and stars.
- SCENE sampling: with ``oversample = N`` SCENE is written ``N`` times finer
  than MEASURED (``OVERSAMP = N``): stars drawn by GalSim at ``scale = 1/N``,
  boxes by their exact overlap with each sub-pixel, a point's light in the
  sub-pixel that holds it.
- Collection: with ``silicon`` a GalSim ``SiliconSensor`` photon-shoots the
  scene: brighter-fatter from the field of the charge already collected
  (pixel boundaries computed from a solved electrostatic model) and/or
  lateral diffusion of the carriers (``diffusion_factor``). Otherwise a
  Poisson draw (``galsim.PoissonNoise``) of the expected charge, after
  GalSim's reciprocity failure (``addReciprocityFailure``) when asked.
- With ``mc_diffusion`` (NumPy instead of GalSim): every electron of the
  Poisson-drawn charge is placed at a uniform random point of its pixel,
  displaced by a Gaussian step and counted where it lands (a Monte Carlo,
  not a kernel).
- With ``squares_bf`` (NumPy): brighter-fatter as a symmetric flow between
  nearest neighbours, ``c (C_p^2 - C_q^2)`` in one shot, with ``c`` given
  by the charge an isolated 50 ke- pixel loses (``squares_bf`` is that
  fraction).
- Per-pixel response: a gain map (one per file, log-normal, NumPy),
  multiplying the collected charge.
- Persistence: GalSim's ``applyPersistence`` with the earlier pairs' charge.
- IPC: GalSim's ``applyIPC`` with a constant 3x3 kernel (``IPCLAW`` says
  ``constant:ALPHA``), optional diagonal terms.
- Non-linearity: GalSim's ``applyNonlinearity`` with ``x - beta x^2``.
- Read noise: GalSim's ``GaussianNoise``, optionally larger than ``READNOIS``.
- Misregistration: MEASURED made from the scene re-drawn with every source
  displaced by ``shift`` pixels, while SCENE holds the undisplaced one; with
  ``shift_hot = False`` the hot pixels (the detector's own) stay in place
  while the sky moves.

The true values are returned to the caller (the test); the file holds only
what the format allows.
"""

import math

import galsim
import numpy as np
from astropy.io import fits

ALPHA = 0.0125  # nearest-neighbour coupling of the generator's constant IPC kernel
CELL = 11  # px: one scene element per cell


def _moffat(flux, fwhm):
    return galsim.Moffat(beta=3.5, fwhm=fwhm, flux=flux)


def draw_scene(n, rng, sky=False, levels=(4000.0, 15000.0, 30000.0, 45000.0), hot="tophat"):
    """A list of scene elements ``(kind, y, x, a, b)`` for an ``n`` x ``n`` frame.

    kinds: ``background`` (a = e-), ``patch`` (y, x corner, a = side, b = e-),
    ``hot`` (a = e-, uniform across the pixel), ``point`` (a = e-, all at the
    pixel centre), ``star`` (a = flux e-, b = FWHM px). ``hot``: the hot
    pixels' kind, ``"tophat"``, ``"point"`` or ``"mixed"`` (alternating).
    """
    out = [("background", 0, 0, float(rng.uniform(80, 150)), 0.0)]
    cells = [(cy, cx) for cy in range(n // CELL) for cx in range(n // CELL)]
    order = rng.permutation(len(cells))
    levels = [] if sky else list(levels)
    for i, k in enumerate(order):
        cy, cx = cells[k]
        y0, x0 = cy * CELL + 2, cx * CELL + 2
        if i < len(levels):
            out.append(("patch", y0, x0, 7, levels[i]))
            continue
        u = rng.random()
        if not sky and u < 0.45:
            y, x = y0 + int(rng.integers(1, 7)), x0 + int(rng.integers(1, 7))
            level = float(math.exp(rng.uniform(math.log(2e3), math.log(6e4))))
            nhot = sum(e[0] in ("hot", "point") for e in out)
            kind = {"tophat": "hot", "point": "point"}.get(hot, ("hot", "point")[nhot % 2])
            out.append((kind, y, x, level, 0.0))
        else:
            fwhm = float(rng.uniform(1.8, 2.8))
            peak = float(math.exp(rng.uniform(math.log(1e3), math.log(5e4))))
            flux = peak * 1.2 * fwhm * fwhm  # about the peak of a Moffat(3.5) of this FWHM
            out.append(("star", y0 + 3 + rng.uniform(-1.5, 1.5), x0 + 3 + rng.uniform(-1.5, 1.5),
                        flux, fwhm))
    return out


def expected(elements, n, shift=(0.0, 0.0), oversample=1, shift_hot=True):
    """The expected charge of the elements, displaced by ``shift``, integrated
    over each pixel (``oversample = 1``) or over each of its ``N x N``
    sub-pixels (``N`` times finer grid; sub-pixel ``i`` covers
    ``[i/N - 1/2, (i+1)/N - 1/2]`` in pixel coordinates)."""
    f = int(oversample)
    m = n * f
    img = galsim.ImageD(m, m, xmin=0, ymin=0, scale=1.0 / f)
    arr = np.zeros((m, m))
    edges = np.arange(m + 1) / f - 0.5
    for kind, y, x, a, b in elements:
        dy, dx = shift if (shift_hot or kind not in ("hot", "point")) else (0.0, 0.0)
        if kind == "background":
            arr += a / (f * f)
        elif kind in ("patch", "hot"):
            side, level = (a, b) if kind == "patch" else (1, a)
            # exact overlap of a displaced box with each (sub-)pixel
            oy = np.clip(np.minimum(edges[1:], y - 0.5 + side + dy)
                         - np.maximum(edges[:-1], y - 0.5 + dy), 0, None)
            ox = np.clip(np.minimum(edges[1:], x - 0.5 + side + dx)
                         - np.maximum(edges[:-1], x - 0.5 + dx), 0, None)
            arr += level * np.outer(oy, ox)
        elif kind == "point":
            iy = int(math.floor((y + dy + 0.5) * f + 1e-9))
            ix = int(math.floor((x + dx + 0.5) * f + 1e-9))
            arr[iy, ix] += a
        elif kind == "star":
            img.setZero()
            _moffat(a, b).drawImage(img, center=galsim.PositionD((x + dx + 0.5) * f - 0.5,
                                                                 (y + dy + 0.5) * f - 0.5),
                                    method="auto")
            arr += img.array
    return arr


def photon_shoot(elements, n, sensor, seed, shift=(0.0, 0.0), shift_hot=True):
    """Collected charge: every element photon-shot through a GalSim ``sensor``,
    displaced by ``shift``."""
    img = galsim.ImageF(n, n, xmin=0, ymin=0, scale=1.0)
    ud = galsim.BaseDeviate(seed)
    order = sorted(elements, key=lambda e: {"background": 0, "patch": 1, "star": 2,
                                            "hot": 3, "point": 3}[e[0]])
    for kind, y, x, a, b in order:
        dy, dx = shift if (shift_hot or kind not in ("hot", "point")) else (0.0, 0.0)
        if kind == "background":
            prof, cy, cx = galsim.Box(n, n, flux=a * n * n), (n - 1) / 2, (n - 1) / 2
        elif kind == "patch":
            prof, cy, cx = galsim.Box(a, a, flux=b * a * a), y + (a - 1) / 2, x + (a - 1) / 2
        elif kind == "hot":
            prof, cy, cx = galsim.Box(1, 1, flux=a), y, x
        elif kind == "point":
            prof, cy, cx = galsim.DeltaFunction(flux=a), y, x
        else:
            prof, cy, cx = _moffat(a, b), y, x
        prof.drawImage(img, method="phot", sensor=sensor, add_to_image=True, rng=ud,
                       center=galsim.PositionD(cx + dx, cy + dy), poisson_flux=True,
                       maxN=200000)
    return img.array.astype(np.float64)


def mc_diffuse(charge, sigma, rng):
    """Move every electron: uniform in its pixel, plus a Gaussian step of RMS ``sigma``."""
    n_y, n_x = charge.shape
    counts = np.rint(np.clip(charge, 0, None)).astype(np.int64)
    iy, ix = np.nonzero(counts)
    reps = counts[iy, ix]
    y = np.repeat(iy, reps) + rng.uniform(-0.5, 0.5, reps.sum()) + rng.normal(0, sigma, reps.sum())
    x = np.repeat(ix, reps) + rng.uniform(-0.5, 0.5, reps.sum()) + rng.normal(0, sigma, reps.sum())
    yi = np.clip(np.rint(y).astype(np.int64), 0, n_y - 1)
    xi = np.clip(np.rint(x).astype(np.int64), 0, n_x - 1)
    out = np.zeros((n_y, n_x))
    np.add.at(out, (yi, xi), 1.0)
    return out


def squares_flow(charge, loss_at_50ke):
    """Symmetric nearest-neighbour flow ``c (C_p^2 - C_q^2)``; an isolated 50 ke-
    pixel loses ``loss_at_50ke`` of its charge (``4 c 50000 = loss``)."""
    c = loss_at_50ke / (4 * 50000.0)
    out = charge.copy()
    fx = c * (charge[:, :-1] ** 2 - charge[:, 1:] ** 2)
    fy = c * (charge[:-1, :] ** 2 - charge[1:, :] ** 2)
    out[:, :-1] -= fx
    out[:, 1:] += fx
    out[:-1, :] -= fy
    out[1:, :] += fy
    return out


def _pair_hdus(k, scene, measured, oversample):
    """The SCENE and MEASURED HDUs of pair ``k``."""
    out = []
    for name, data in (("SCENE", scene.astype(">f4")), ("MEASURED", measured)):
        h = fits.ImageHDU(data, name=name)
        h.header["EXTVER"] = k + 1
        if name == "SCENE" and oversample > 1:
            h.header["OVERSAMP"] = int(oversample)
        out.append(h)
    return out


def make_file(path, n=64, pairs=2, seed=0, readnoise=12.0, true_readnoise=None, sky=False,
              silicon=None, reciprocity_alpha=0.0, gain_rms=0.0, persistence=(),
              diagonal=0.0, nonlinearity_beta=0.0, shift=(0.0, 0.0),
              levels=(4000.0, 15000.0, 30000.0, 45000.0), mc_diffusion=0.0, squares_bf=0.0,
              hot="tophat", oversample=1, shift_hot=True, totals_path=None):
    """Write a lab file and return what was hidden in it.

    Parameters
    ----------
    levels : sequence of float
        e- of the flat patches (one patch each).
    silicon : dict, optional
        ``SiliconSensor`` arguments (``strength`` for brighter-fatter,
        ``diffusion_factor``); ``None`` draws Poisson charge without a sensor.
    persistence : sequence of float
        Coefficients of the 1st, 2nd, ... earlier pair's charge added to a pair.
    diagonal : float
        Coupling to each diagonal neighbour in the IPC kernel.
    nonlinearity_beta : float
        ``x - beta x^2`` applied after IPC.
    shift : (dy, dx)
        MEASURED is made from the scene displaced by this many pixels.
    hot : str
        The hot pixels' light: ``"tophat"`` (uniform across the pixel),
        ``"point"`` (at its centre) or ``"mixed"``.
    oversample : int
        SCENE sub-pixels per pixel along each axis (``OVERSAMP``).
    shift_hot : bool
        Whether the hot pixels move with ``shift`` (False: a sky displaced
        under the detector's fixed hot pixels).
    totals_path : str, optional
        Also write there the same file with pixel-total SCENEs (the same
        MEASURED frames; what ``oversample = 1`` writes).
    """
    rng = np.random.default_rng(seed)
    rn = readnoise if true_readnoise is None else true_readnoise
    kernel = np.array([[diagonal, ALPHA, diagonal],
                       [ALPHA, 1.0 - 4 * ALPHA - 4 * diagonal, ALPHA],
                       [diagonal, ALPHA, diagonal]])
    gain = np.exp(rng.normal(0.0, gain_rms, (n, n))) if gain_rms else None
    sensor = None if silicon is None else galsim.SiliconSensor(rng=galsim.BaseDeviate(seed + 7),
                                                               **silicon)
    hdus, charges = [fits.PrimaryHDU()], []
    hdus[0].header["READNOIS"] = readnoise
    hdus[0].header["SHOTNOIS"] = True
    hdus[0].header["IPCLAW"] = f"constant:{ALPHA}"
    totals = [fits.PrimaryHDU(header=hdus[0].header.copy())]
    for k in range(pairs):
        elements = draw_scene(n, rng, sky=sky, levels=levels, hot=hot)
        scene = expected(elements, n, oversample=oversample)
        total = None if totals_path is None else expected(elements, n)
        if sensor is not None:
            charge = photon_shoot(elements, n, sensor, seed * 100 + k + 1, shift, shift_hot)
        else:
            light = expected(elements, n, shift, shift_hot=shift_hot)
            img = galsim.ImageD(light, xmin=0, ymin=0, scale=1.0)
            if reciprocity_alpha:
                img.addReciprocityFailure(exp_time=1.0, alpha=reciprocity_alpha, base_flux=1.0)
            img.addNoise(galsim.PoissonNoise(galsim.BaseDeviate(seed * 100 + k + 1)))
            charge = img.array.copy()
            if mc_diffusion:
                charge = mc_diffuse(charge, mc_diffusion, rng)
            if squares_bf:  # on the charge as it arrives, diffused
                charge = squares_flow(charge, squares_bf)
        if gain is not None:
            charge = charge * gain
        charges.insert(0, charge)
        img = galsim.ImageD(charge.copy(), xmin=0, ymin=0, scale=1.0)
        if persistence and k > 0:
            m = min(len(persistence), k)
            img.applyPersistence([galsim.ImageD(c, xmin=0, ymin=0, scale=1.0)
                                  for c in charges[1:m + 1]], list(persistence[:m]))
        img.applyIPC(galsim.Image(kernel), edge_treatment="extend")
        if nonlinearity_beta:
            img.applyNonlinearity(lambda x, b=nonlinearity_beta: x - b * x * x)
        img.addNoise(galsim.GaussianNoise(galsim.BaseDeviate(seed * 100 + 50 + k), sigma=rn))
        measured = img.array.astype(">f4")
        hdus += _pair_hdus(k, scene, measured, oversample)
        if total is not None:
            totals += _pair_hdus(k, total, measured, 1)
    fits.HDUList(hdus).writeto(path, overwrite=True)
    if totals_path is not None:
        fits.HDUList(totals).writeto(totals_path, overwrite=True)
    return {"readnoise": rn, "gain_rms": gain_rms, "shift": shift, "oversample": oversample}

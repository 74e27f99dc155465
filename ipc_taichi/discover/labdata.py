"""The lab data format of ``ipc-taichi discover`` and a generator for it.

Format (``docs/discovery_format.md``): a PRIMARY HDU with ``READNOIS``
(required, e- RMS), ``SHOTNOIS`` (default T) and ``IPCLAW`` (default
``donlon2018``), then K >= 1 pairs of 2-D image HDUs ``EXTNAME='SCENE'`` and
``EXTNAME='MEASURED'`` with the same ``EXTVER`` and shape. Data may be
float32 or float64, either byte order; NaN marks a bad pixel. A SCENE may
carry ``OVERSAMP = N`` (integer >= 1, default 1): it is then sampled ``N``
times finer than its MEASURED along each axis (:mod:`.sampling`).

:func:`read_lab` validates a file and gives one-line errors naming the HDU.
:func:`make_scene` draws a lab-like scene: a smooth background, flat patches
at several levels (non-linearity, dark current), single-pixel events (hot
pixels, the classic IPC probe) and point sources. :func:`simulate_lab`
writes a file from scenes through a :class:`~.model.DetectorModel` with
hidden effects; nothing about the hidden effects is written to the file.
"""

import math
import os
from dataclasses import dataclass

import numpy as np

from ..datasets import add_gaussian_spot
from ..errors import IPCInputError, LawError
from ..fitsio import atomic_output
from ..laws import get_law
from .effects import EFFECTS
from .model import DetectorModel

__all__ = ["LabData", "LabPair", "read_lab", "read_header", "write_lab", "make_scene",
           "simulate_lab", "effect_params", "ipclaw", "FLAT_LEVELS"]

FLAT_LEVELS = (3000.0, 10000.0, 20000.0, 35000.0, 50000.0)  # e-, one patch each per frame
_CELL = 8  # px: scene elements sit one per cell, so they stay isolated


@dataclass(frozen=True)
class LabPair:
    """One SCENE/MEASURED pair of a lab file.

    ``scene`` and ``measured`` are float64 native-endian 2-D arrays (NaN = bad
    pixel); ``oversample`` is the SCENE's ``OVERSAMP`` (1 when not given): a
    SCENE of ``OVERSAMP = N`` has ``N`` times MEASURED's shape.
    """

    extver: int
    scene: np.ndarray
    measured: np.ndarray
    oversample: int = 1


@dataclass
class LabData:
    """A validated lab file: header values and its SCENE/MEASURED pairs
    (:class:`LabPair`, in ``EXTVER`` order)."""

    path: str
    readnoise: float
    shot_noise: bool
    law: str
    pairs: list

    def model(self):
        """The starting model the file's header describes."""
        return DetectorModel(self.law, self.readnoise, self.shot_noise)


def _as_bool(value, label):
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    text = str(value).strip().upper()
    if text in ("T", "TRUE", "1", "Y", "YES"):
        return True
    if text in ("F", "FALSE", "0", "N", "NO"):
        return False
    raise IPCInputError(f"{label}: SHOTNOIS = {value!r} is not a boolean")


def read_header(head, path):
    """``(READNOIS, SHOTNOIS, IPCLAW)`` of a lab file's PRIMARY header
    (``path`` names the file in the one-line errors)."""
    where = f"{path}[PRIMARY]"
    if "READNOIS" not in head:
        raise IPCInputError(f"{where}: keyword READNOIS (read noise, e- RMS) is missing")
    try:
        readnoise = float(head["READNOIS"])
    except (TypeError, ValueError):
        raise IPCInputError(f"{where}: READNOIS = {head['READNOIS']!r} is not a "
                            "number") from None
    if not (math.isfinite(readnoise) and readnoise >= 0):
        raise IPCInputError(f"{where}: READNOIS = {readnoise} must be finite and >= 0")
    shot_noise = _as_bool(head.get("SHOTNOIS", True), where)
    law = str(head.get("IPCLAW", "donlon2018")).strip()
    try:
        get_law(law)
    except LawError as exc:
        raise IPCInputError(f"{where}: IPCLAW {law!r}: {exc}") from None
    return readnoise, shot_noise, law


def read_lab(path):
    """Read and validate a lab file; return :class:`LabData`.

    Raises :class:`~ipc_taichi.errors.IPCInputError` with one line naming the
    file and HDU for: a missing file, a missing or invalid ``READNOIS``, an
    unknown ``IPCLAW``, a SCENE without its MEASURED (or the reverse), shapes
    that differ within a pair (``OVERSAMP`` times MEASURED's for a SCENE), an
    image that is not 2-D, an all-NaN frame, an ``OVERSAMP`` that is not an
    integer >= 1, and on an oversampled SCENE a value that is infinite or
    negative (NaN marks a bad sub-pixel, and so a bad pixel).
    """
    from astropy.io import fits

    if not os.path.exists(path):
        raise IPCInputError(f"{path}: no such file")
    try:
        hdul = fits.open(path, memmap=False)
    except Exception as exc:
        raise IPCInputError(f"{path}: not a readable FITS file ({type(exc).__name__})") from None
    with hdul:
        readnoise, shot_noise, law = read_header(hdul[0].header, path)
        frames = {"SCENE": {}, "MEASURED": {}}
        for index, hdu in enumerate(hdul):
            name = str(hdu.header.get("EXTNAME", "")).strip().upper()
            if name not in frames:
                continue
            ver = int(hdu.header.get("EXTVER", 1))
            label = f"{path}[{name},{ver}]"
            if ver in frames[name]:
                raise IPCInputError(f"{label}: EXTVER {ver} appears twice (HDU {index})")
            if not hdu.is_image or hdu.data is None or hdu.data.ndim != 2:
                shape = None if getattr(hdu, "data", None) is None else hdu.data.shape
                raise IPCInputError(f"{label}: expected a 2-D image, got shape {shape}"
                                    + (" (a ramp: ipc_taichi.discover.ramps reads it)"
                                       if shape is not None and len(shape) == 3 else ""))
            data = np.asarray(hdu.data, dtype=np.float64)  # native order, BSCALE applied
            if not np.isfinite(data).any():
                raise IPCInputError(f"{label}: no finite pixel (all NaN)")
            n = _oversamp(hdu.header, label) if name == "SCENE" else 1
            if n > 1 and (np.isinf(data).any() or (data < 0).any()):
                bad = "infinite" if np.isinf(data).any() else "negative"
                raise IPCInputError(f"{label}: OVERSAMP = {n} SCENE has {bad} values (expected "
                                    "charge per sub-pixel: finite and >= 0, NaN if bad)")
            frames[name][ver] = (label, data, n)
    scenes, measured = frames["SCENE"], frames["MEASURED"]
    if not scenes and not measured:
        raise IPCInputError(f"{path}: no SCENE/MEASURED image HDUs")
    for a, b in (("SCENE", "MEASURED"), ("MEASURED", "SCENE")):
        for ver in sorted(set(frames[a]) - set(frames[b])):
            raise IPCInputError(f"{path}[{a},{ver}]: unpaired: no {b} HDU with EXTVER={ver}")
    pairs = []
    for ver in sorted(scenes):
        (slabel, s, n), (mlabel, m, _) = scenes[ver], measured[ver]
        if n == 1 and s.shape != m.shape:
            raise IPCInputError(f"{mlabel}: shape {m.shape} differs from {slabel} shape {s.shape}")
        if s.shape != (n * m.shape[0], n * m.shape[1]):
            raise IPCInputError(f"{slabel}: shape {s.shape} is not OVERSAMP = {n} times {mlabel} "
                                f"shape {m.shape}")
        pairs.append(LabPair(ver, s, m, n))
    return LabData(path, readnoise, shot_noise, law, pairs)


def _oversamp(header, label):
    """``OVERSAMP`` of a SCENE header: an integer >= 1 (1 when absent)."""
    value = header.get("OVERSAMP", 1)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or value < 1:
        raise IPCInputError(f"{label}: OVERSAMP = {value!r} must be an integer >= 1 (the SCENE's "
                            "sub-pixels per pixel along each axis)")
    return int(value)


def write_lab(path, pairs, readnoise, law="donlon2018", shot_noise=True, overwrite=False,
              dtype=np.float64, history=(), oversample=1):
    """Write ``pairs`` (``[(scene, measured), ...]``) in the lab format, atomically.

    ``oversample`` (one integer, or one per pair) is written as ``OVERSAMP``
    in the SCENE headers where it exceeds 1; such a SCENE must be that many
    times finer than its MEASURED.
    """
    from astropy.io import fits

    primary = fits.PrimaryHDU()
    primary.header["READNOIS"] = (float(readnoise), "read noise, e- RMS")
    primary.header["SHOTNOIS"] = (bool(shot_noise), "MEASURED includes shot noise")
    primary.header["IPCLAW"] = (str(law), "coupling law of the starting model")
    for line in history:
        primary.header.add_history(line)
    hdus = [primary]
    pairs = list(pairs)
    factors = [int(oversample)] * len(pairs) if np.ndim(oversample) == 0 else \
        [int(n) for n in oversample]
    for k, ((scene, measured), n) in enumerate(zip(pairs, factors), start=1):
        for name, data in (("SCENE", scene), ("MEASURED", measured)):
            hdu = fits.ImageHDU(np.asarray(data, dtype=dtype), name=name)
            hdu.header["EXTVER"] = k
            hdu.header["BUNIT"] = "electron"
            if name == "SCENE" and n > 1:
                hdu.header["OVERSAMP"] = (n, "sub-pixels per pixel along each axis")
            hdus.append(hdu)
    with atomic_output(path, overwrite) as tmp:
        fits.HDUList(hdus).writeto(tmp)


def make_scene(shape, rng, hot_fraction=0.55, source_fraction=0.35, oversample=1):
    """A lab-like expected-charge scene (electrons).

    A background of 60-200 e- with gradients; one flat 10x10 patch at each
    level of :data:`FLAT_LEVELS`; and, on a grid of 8x8-pixel cells, either a
    hot pixel (single-pixel event, 1.5-60 ke-, log-uniform, uniform across
    its pixel), a point source (pixel-integrated Gaussian, FWHM 1.6-2.6 px,
    peak 0.5-50 ke-) or nothing. With ``oversample = N > 1`` the same scene
    (same draws from ``rng``) is returned on the sub-pixel grid of
    :mod:`.sampling`, shape ``(N ny, N nx)``: its ``N x N`` blocks sum to the
    ``oversample = 1`` scene (to 1e-4 of its peak: the spots are cut at 4 px
    from their centre on either grid).
    """
    ny, nx = shape
    n = int(oversample)
    if n < 1:
        raise IPCInputError(f"oversample {oversample!r}: must be an integer >= 1")
    if ny < 48 or nx < 48:
        raise IPCInputError(f"scene shape {shape}: needs at least 48x48 pixels")
    if n == 1:
        yy, xx = np.mgrid[0:ny, 0:nx]
    else:  # sub-pixel centres, in pixel coordinates (a linear gradient: exact)
        yy, xx = np.mgrid[0:n * ny, 0:n * nx]
        yy, xx = (yy + 0.5) / n - 0.5, (xx + 0.5) / n - 0.5
    scene = 60.0 + 90.0 * xx / nx + 50.0 * yy / ny
    if n > 1:
        scene = scene / (n * n)

    def fine(v):  # a pixel coordinate on the sub-pixel grid
        return v if n == 1 else (v + 0.5) * n - 0.5

    ncy, ncx = ny // _CELL, nx // _CELL
    used = np.zeros((ncy, ncx), dtype=bool)
    for level in FLAT_LEVELS:
        for _ in range(200):
            cy, cx = rng.integers(1, ncy - 2), rng.integers(1, ncx - 2)
            if not used[cy:cy + 2, cx:cx + 2].any():
                break
        else:
            raise IPCInputError(f"scene shape {shape}: too small for the flat patches")
        used[cy:cy + 2, cx:cx + 2] = True
        y0, x0 = cy * _CELL + 3, cx * _CELL + 3
        scene[n * y0:n * (y0 + 10), n * x0:n * (x0 + 10)] += level / (n * n)
    for cy in range(ncy):
        for cx in range(ncx):
            if used[cy, cx]:
                continue
            u = rng.random()
            yc, xc = cy * _CELL + 4, cx * _CELL + 4
            if u < hot_fraction:
                y, x = yc + rng.integers(-1, 2), xc + rng.integers(-1, 2)
                level = math.exp(rng.uniform(math.log(1500.0), math.log(60000.0)))
                scene[n * y:n * (y + 1), n * x:n * (x + 1)] += level / (n * n)
            elif u < hot_fraction + source_fraction:
                fwhm = rng.uniform(1.6, 2.6)
                peak = math.exp(rng.uniform(math.log(500.0), math.log(50000.0)))
                sigma = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
                flux = peak * 2.0 * math.pi * sigma ** 2
                add_gaussian_spot(scene, fine(yc + rng.uniform(-0.5, 0.5)),
                                  fine(xc + rng.uniform(-0.5, 0.5)), flux, fwhm * n,
                                  radius=4 * n)
    return scene


def effect_params(name, value, readnoise=None):
    """Model parameters of a hidden effect from its ``--effect NAME=VALUE`` value:
    its record's :meth:`~.record.Effect.from_value` (each record's docstring
    in :mod:`.effects` says what the value is: an absolute coupling at zero
    signal, an anisotropy ``(h - v) / mean``, a deficit at 50 ke-, a
    deflection at 50 ke- along x and y, sigma in pixels, electrons, the RMS
    of the response map, alpha per decade, the true read noise in e- RMS, a
    shift along x in pixels). ``signal_dependent_ipc`` takes a law name and is
    handled by :func:`simulate_lab` (:meth:`~.record.Effect.hidden`).
    """
    return EFFECTS[name].from_value(value, readnoise)


def ipclaw(law):
    """The ``IPCLAW`` text of a law: its name for the paper's laws and the
    constant ones, ``parametric:AMP_DIFF,SCALE_DIFF,AMP_LEVEL,SCALE_LEVEL,FLOOR``
    for another parametric law (read back by :func:`~ipc_taichi.laws.get_law`);
    a tabulated law has no header form (:class:`IPCInputError`)."""
    law = get_law(law)
    if getattr(law, "kind", "") != "parametric":
        raise IPCInputError(f"law {law.name!r}: a tabulated law cannot be written to IPCLAW")
    def coefficients(x):
        return (x.amp_diff, x.scale_diff, x.amp_level, x.scale_level, x.floor)

    for spec in (law.name, f"constant:{law.floor!r}"):
        try:
            if coefficients(get_law(spec)) == coefficients(law):
                return spec
        except LawError:
            pass
    return "parametric:" + ",".join(repr(float(v)) for v in (
        law.amp_diff, law.scale_diff, law.amp_level, law.scale_level, law.floor))


def simulate_lab(path, effects=None, readnoise=12.0, seed=0, law="donlon2018", pairs=2,
                 shape=(128, 128), shot_noise=True, nan_fraction=0.0, dtype=np.float64,
                 overwrite=False, oversample=1, coupling=None, document=None):
    """Write a lab file whose MEASURED frames hide ``effects``.

    Parameters
    ----------
    effects : dict
        ``{effect name: value}`` (see :func:`effect_params`);
        ``signal_dependent_ipc`` takes a law spec (e.g. ``"donlon2018"``): the
        frames are made with that law while ``IPCLAW`` says ``law``.
    law : str
        The starting model's law, written to ``IPCLAW``.
    coupling : CouplingModel, optional
        Replaces ``law``: the frames are made with its law, geometry and
        edge (:meth:`DetectorModel.from_coupling`) plus ``effects``, and
        ``IPCLAW`` holds its law (:func:`ipclaw`).
    document : dict, optional
        The coupling-model file's document: its measured ``brighter_fatter``
        and ``classical_nonlinearity`` sections make the frames too
        (:func:`~.model.effects_from_document`), unless ``effects`` names them.
    nan_fraction : float
        Fraction of pixels of each MEASURED frame set to NaN (bad pixels).
    dtype : numpy dtype
        On-disk type (FITS stores big-endian).
    oversample : int
        ``N``: the scenes are drawn on the sub-pixel grid (:func:`make_scene`),
        the detector model works from it (:mod:`.sampling`), and SCENE is
        written with ``OVERSAMP = N``.

    Returns
    -------
    DetectorModel
        The model that made the data (for the caller's records; not written).
    """
    effects = dict(effects or {})
    unknown = set(effects) - set(EFFECTS)
    if unknown:
        raise IPCInputError(f"unknown effect(s) {', '.join(sorted(unknown))}; "
                            f"known: {', '.join(EFFECTS)}")
    start = None if coupling is None else DetectorModel.from_coupling(coupling, readnoise,
                                                                       shot_noise, document)
    if start is not None:
        law = ipclaw(coupling.law)
    data_law = get_law(law)
    params = {}
    for name, value in effects.items():  # an effect may make the data's law instead
        hidden, data_law = EFFECTS[name].hidden(value, readnoise, data_law)
        if hidden is not None:
            params[name] = hidden
    if start is not None:
        truth = DetectorModel(data_law, readnoise, shot_noise, {**start.effects, **params},
                              start.edge)
    else:
        truth = DetectorModel(data_law, readnoise, shot_noise, params)
    rng = np.random.default_rng(seed)
    out = []
    scenes = np.stack([make_scene(shape, rng, oversample=oversample) for _ in range(int(pairs))])
    # one call for all pairs: they share the file's response map (flat_field)
    for scene, measured in zip(scenes, truth.simulate(scenes, rng, oversample)):
        measured = measured.copy()
        if nan_fraction > 0:
            measured[rng.random(measured.shape) < nan_fraction] = np.nan
        out.append((scene, measured))
    write_lab(path, out, readnoise, law=str(get_law(law).name if law is not None else law),
              shot_noise=shot_noise, overwrite=overwrite, dtype=dtype, oversample=oversample)
    return truth

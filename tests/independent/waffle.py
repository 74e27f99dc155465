"""Flat ramps made by the Roman project's own flat simulator (solid-waffle).

Nothing from ``ipc_taichi`` is imported here: every electron comes from
``solid_waffle.flat_simulator.simulate_flat.Simulation`` (solid-waffle 26.0.0,
Hirata, Choi, Freudenburg et al., MIT licence), run unchanged from a
configuration text. This module only writes the configuration, runs the
simulator once per ramp and stacks its per-ramp files into one FITS file in
the structure of a JWST ramp.

What the simulator does (read from its source, 26.0.0):

- FORMAT 1001: a 512 x 512 array whose 4-pixel border is reference pixels
  (they hold the reset level and read noise, no charge, no IPC).
- Charge: ``NREADS`` reads; read 0 holds only the reset level ``RESET_E``;
  each later read adds ``ILLUMINATION * QE * DT`` electrons on average,
  collected in ``SUBSTEPS`` Poisson steps per read. With ``BFE: true`` each
  step's mean is multiplied by the pixel area ``1 + sum_d a(d) Q(p + d)``
  (``calc_area_defect``) with ``Q`` the charge of the previous step and ``a``
  the infrared kernel ``TestKernels.get_bfe_kernel_5x5_ir()``.
- Then, on every read: IPC (``L_IPC: true 0.01``, a 3x3 kernel with 1 % to
  each of the 4 nearest neighbours, symmetric padding at the edge of the
  active area), then the classical non-linearity ``M = Q - beta Q^2``
  (``NL: quadratic 1.5`` means beta = 1.5 ppm per electron), then Gaussian read
  noise of 10 e- (any ``NOISE`` word other than none/last/full), then
  ``DN = uint16(clip(M / GAIN, 0, 65535))``.
- The simulator's arrays are indexed ``[t, i, j]`` and written with fitsio in
  C order, so ``i`` is the FITS y axis (the row of ``image[y, x]``) and ``j``
  the x axis, whatever the simulator's own variable names say.

Two properties of the simulator shape the configuration chosen here:

- ``RNGSEED`` without ``LEGACY`` calls ``numpy.random.Generator(seed=...)``,
  which NumPy refuses (a TypeError in 26.0.0), so the legacy
  ``RandomState`` generator is used (as solid-waffle's own test does).
- The non-linearity acts on reset level plus charge, so a reset level ``R``
  turns into a gain change ``1 - 2 beta R``; ``R = 100 e-`` (10 times the
  read noise, as in solid-waffle's own test) keeps read 0 off the clip at
  0 DN and that change at 3e-4.
"""

import os

import numpy as np
from astropy.io import fits
from solid_waffle.flat_simulator.detector_functions import TestKernels
from solid_waffle.flat_simulator.simulate_flat import Simulation

__all__ = ["ALPHA", "BETA", "GAIN", "KINDS", "RAMP_KINDS", "REFPIX", "bf_kernel", "dark_ramps",
           "discover_ramp_file", "flat_ramps", "simulate_ramp"]

FORMAT = 1001  # solid-waffle's smallest array: 512 x 512
SIDE = 512
REFPIX = 4  # reference border (px) of FORMAT 1001
GAIN = 1.5  # e-/DN
ALPHA = 0.01  # IPC: fraction of a pixel's charge moved to each nearest neighbour
BETA = 1.5e-6  # classical non-linearity, 1/e-: M = Q - BETA Q^2
READ_NOISE = 10.0  # e- per read (the simulator's Gaussian noise)
RESET = 100.0  # e-: reset level in every read
SUBSTEPS = 2  # Poisson steps per read (brighter-fatter updates)
DT = 3.0  # s per read
QE = 1.0
EDGE = 2  # px: a discover file's cut masks this border of MEASURED (the 5x5 kernel's reach)

KINDS = {
    "ipc": {"bfe": False, "nl": False},
    "ipc_bf": {"bfe": True, "nl": False},
    "ipc_bf_nl": {"bfe": True, "nl": True},
}
"""The three sets: constant IPC; plus brighter-fatter; plus quadratic non-linearity."""

RAMP_KINDS = {**KINDS, "ipc_nl": {"bfe": False, "nl": True}}
"""Every set :func:`simulate_ramp` makes: :data:`KINDS` (calibrate's) and the
quadratic non-linearity without brighter-fatter (discover's ramp files)."""

SEEDS = {"ipc": 101, "ipc_bf": 201, "ipc_bf_nl": 301}
"""Default first ``RNGSEED`` of each set (ramp ``i`` uses ``seed + i``)."""


def bf_kernel():
    """The simulator's brighter-fatter kernel in this project's convention.

    Returns
    -------
    numpy.ndarray
        5x5, per electron: ``a[2 + dy, 2 + dx]`` is the fractional change of
        the area of pixel ``(y, x)`` per electron in pixel ``(y + dy, x + dx)``
        (``image[y, x]``). The simulator convolves the charge with
        ``TestKernels.get_bfe_kernel_5x5_ir()`` (``scipy.signal.convolve``), so
        its coefficient for offset ``d`` sits at ``[2 - dy, 2 - dx]``: ours is
        that array turned by 180 degrees (its table as printed in the source,
        before the ``fliplr``, turned upside down).
    """
    return np.asarray(TestKernels.get_bfe_kernel_5x5_ir(), dtype=np.float64)[::-1, ::-1].copy()


def _config(kind, output, nreads, level, seed, dark=False):
    """The simulator's configuration text for one ramp."""
    effects = RAMP_KINDS[kind]
    per_read = 0.0 if dark else level / (nreads - 1)  # e- collected per read
    lines = [
        f"FORMAT: {FORMAT}",
        f"NREADS: {nreads}",
        f"SUBSTEPS: {SUBSTEPS}",
        f"DT: {DT}",
        f"GAIN: {GAIN}",
        f"ILLUMINATION: {per_read / (QE * DT)!r}",
        f"QE: {QE}",
        f"RNGSEED: {seed}",
        "LEGACY",
        "NOISE: gaussian",
        f"RESET_E: {RESET}",
        "WAVEMODE: ir",
        f"BFE: {'true' if effects['bfe'] else 'false'}",
        f"L_IPC: true {ALPHA}",
        f"NL: {'quadratic' if effects['nl'] else 'false'} {BETA * 1e6}",
        f"OUTPUT: {output}",
    ]
    return "\n".join(lines) + "\n"


def simulate_ramp(output, kind, nreads=20, level=42000.0, seed=1, dark=False):
    """One ramp written by the simulator to ``output`` (its own file format,
    solid-waffle's FORMAT 1001: primary HDU (nreads, 512, 512) uint16 DN).

    Parameters
    ----------
    output : str or path-like
    kind : {"ipc", "ipc_bf", "ipc_bf_nl", "ipc_nl"}
    nreads : int
        Reads, read 0 included (it holds no charge).
    level : float
        Mean collected charge at the last read, e-.
    seed : int
        The simulator's ``RNGSEED`` (>= 0).
    dark : bool
        No illumination (the dark exposures solid-waffle's analysis pairs
        with each flat).

    Returns
    -------
    str
        ``output``.
    """
    output = os.fspath(output)
    Simulation(_config(kind, output, nreads, level, seed, dark)).run()
    return output


def _read(path):
    with fits.open(path) as hdul:
        return np.asarray(hdul[0].data)


def _write_ramp_file(path, ramps):
    """JWST-like ramp: primary HDU + SCI (nints, ngroups, ny, nx) float32 DN,
    ``GAIN`` in the SCI header and no ``BUNIT``. The simulator's uint16 values
    are kept exactly; float32 as in a ramp after the bias steps, since an
    integer 4-D ramp is read as raw data (``_uncal``) and refused."""
    sci = fits.ImageHDU(ramps, name="SCI")
    sci.header["GAIN"] = (GAIN, "e-/DN (solid-waffle flat simulator)")
    primary = fits.PrimaryHDU()
    primary.header["ORIGIN"] = "solid-waffle 26.0.0 flat simulator"
    fits.HDUList([primary, sci]).writeto(path, overwrite=True)


def flat_ramps(folder, kind, nramps=8, nreads=20, level=42000.0, seed=None, keep_ramps=False):
    """A set of flat ramps from the simulator, in one JWST-like FITS file.

    Parameters
    ----------
    folder : str or path-like
        Where the file (and, with ``keep_ramps``, the simulator's per-ramp
        files) is written.
    kind : {"ipc", "ipc_bf", "ipc_bf_nl"}
        Constant IPC 1 %; plus the simulator's infrared brighter-fatter
        kernel; plus the quadratic non-linearity 1.5 ppm/e-.
    nramps, nreads : int
        Integrations and reads per integration (read 0 included).
    level : float
        Mean collected charge at the last read, e-.
    seed : int, optional
        ``RNGSEED`` of the first ramp (ramp ``i`` uses ``seed + i``); default
        :data:`SEEDS` of ``kind``.
    keep_ramps : bool
        Keep the simulator's own files (one per ramp, FORMAT 1001) for
        solid-waffle's analysis; otherwise they are removed.

    Returns
    -------
    dict
        ``path`` (SCI (nramps, nreads, 512, 512) float32 DN), ``gain`` (e-/DN,
        the file's GAIN keyword), ``refpix`` (border width), ``ramps`` (the
        per-ramp files, empty unless ``keep_ramps``), ``truth``: ``alpha``
        (nearest-neighbour IPC, all levels), ``bf_kernel`` (5x5 list,
        :func:`bf_kernel`, or None), ``beta`` (1/e-, 0.0 when off),
        ``level`` (e-), ``read_noise`` (e-), ``reset`` (e-).
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    folder = os.fspath(folder)
    seed = SEEDS[kind] if seed is None else int(seed)
    ramps = np.empty((nramps, nreads, SIDE, SIDE), dtype=np.float32)
    files = []
    for i in range(nramps):
        one = os.path.join(folder, f"waffle_{kind}_ramp{i + 1:03d}.fits")
        ramps[i] = _read(simulate_ramp(one, kind, nreads, level, seed + i))
        if keep_ramps:
            files.append(one)
        else:
            os.remove(one)
    path = os.path.join(folder, f"waffle_{kind}.fits")
    _write_ramp_file(path, ramps)
    effects = KINDS[kind]
    truth = {"alpha": ALPHA,
             "bf_kernel": bf_kernel().tolist() if effects["bfe"] else None,
             "beta": BETA if effects["nl"] else 0.0,
             "level": float(level), "read_noise": READ_NOISE, "reset": RESET}
    return {"path": path, "gain": GAIN, "refpix": REFPIX, "ramps": files, "truth": truth}


def dark_ramps(folder, kind, nramps=8, nreads=20, seed=None):
    """The simulator's dark ramps (no illumination; reset level and read noise
    only), one file per ramp in its own format: solid-waffle's analysis pairs
    each flat with a dark.

    Returns
    -------
    list of str
    """
    folder = os.fspath(folder)
    seed = SEEDS[kind] + 1000 if seed is None else int(seed)
    return [simulate_ramp(os.path.join(folder, f"waffle_{kind}_dark{i + 1:03d}.fits"), kind,
                          nreads, 0.0, seed + i, dark=True)
            for i in range(nramps)]


def _electrons(dn):
    """DN to electrons. The simulator's ``uint16`` conversion truncates, so a
    value ``v`` DN stands for ``[v, v + 1)`` DN: its mean ``(v + 0.5) GAIN``."""
    return (np.asarray(dn, dtype=np.float64) + 0.5) * GAIN


def _reference_level(ramp):
    """Each read's mean over the 4-pixel reference border, e- (``(nreads,)``):
    the reset level as a lab reads it (the border holds no charge, IPC or
    non-linearity)."""
    border = np.ones(ramp.shape[1:], dtype=bool)
    border[REFPIX:-REFPIX, REFPIX:-REFPIX] = False
    return ramp[:, border].mean(axis=1)


def _cut_reads(one, kind, nreads, level, seed, side):
    """One simulated ramp (written to ``one``, then removed) as the reads of
    a ramp file: electrons, less the reference level, read 0 left out, the
    central ``side`` x ``side`` pixels with their outer ``EDGE`` NaN."""
    try:
        ramp = _electrons(_read(simulate_ramp(one, kind, nreads, level, seed)))
    finally:
        if os.path.exists(one):
            os.remove(one)
    lo = (SIDE - side) // 2
    reads = ramp[1:, lo:lo + side, lo:lo + side] - _reference_level(ramp)[1:, None, None]
    reads[:, :EDGE] = reads[:, -EDGE:] = reads[:, :, :EDGE] = reads[:, :, -EDGE:] = np.nan
    return reads


def discover_ramp_file(path, kind, seed, nreads=6, level=40000.0, side=64, nramps=1):
    """Flat ramps of the simulator written as a discovery ramp file
    (``docs/discovery_format.md``, "Ramps"), by astropy from the format text.

    Per ramp: the simulator's DN to electrons (:func:`_electrons`), each read
    less its reference border's mean (:func:`_reference_level`); read 0 (the
    reset, no charge, at t = 0) is left out, so MEASURED holds reads 1 ...
    ``nreads - 1`` at ``TFIRST = TFRAME = DT``; only the central ``side`` x
    ``side`` pixels of the active area are kept (the reference border is
    not in the file), and MEASURED's outer ``EDGE`` pixels are NaN: the
    flat goes on beyond the cut, which a model of the file alone cannot know
    (it would couple those pixels to nothing outside). SCENE is the flat's
    rate ``ILLUMINATION * QE``, e-/s.
    The header states what the simulator was told: ``IPCLAW`` its constant
    1 %, ``READNOIS`` its 10 e- with the DN quantization's ``GAIN^2 / 12``.

    Parameters
    ----------
    path : str or path-like
        The ramp file (written to ``path + ".tmp"`` and renamed).
    kind : {"ipc", "ipc_bf", "ipc_nl", "ipc_bf_nl"}
        :data:`RAMP_KINDS`.
    seed : int
        ``RNGSEED`` of the first ramp (ramp ``i`` uses ``seed + i``).
    nreads : int
        The simulator's reads, read 0 included (the file holds ``nreads - 1``).
    level : float
        Mean collected charge at the last read, e-.
    side : int
        Pixels kept along each axis (even, at most ``SIDE - 2 REFPIX``).
    nramps : int
        Integrations (ramp pairs of the file).

    Returns
    -------
    dict
        ``path``, ``rate`` (e-/s), ``truth``: ``alpha``, ``bf_kernel`` (or
        None), ``beta`` (1/e-), ``deficit_at_50ke`` (``beta`` x 50 ke-),
        ``read_noise`` (e-).
    """
    if kind not in RAMP_KINDS:
        raise ValueError(f"kind must be one of {', '.join(RAMP_KINDS)}, got {kind!r}")
    if side % 2 or not 0 < side <= SIDE - 2 * REFPIX:
        raise ValueError(f"side must be even and in 2..{SIDE - 2 * REFPIX}, got {side}")
    path = os.fspath(path)
    rate = level / (nreads - 1) / DT  # e-/s: ILLUMINATION * QE of _config
    readnoise = float(np.sqrt(READ_NOISE ** 2 + GAIN ** 2 / 12.0))
    primary = fits.PrimaryHDU()
    primary.header["READNOIS"] = (readnoise, "e-: the simulator's 10 e- and DN quantization")
    primary.header["SHOTNOIS"] = True
    primary.header["IPCLAW"] = (f"constant:{ALPHA}", "the simulator's L_IPC")
    primary.header["ORIGIN"] = "solid-waffle 26.0.0 flat simulator"
    hdus = [primary]
    for k in range(1, nramps + 1):
        reads = _cut_reads(f"{path}.sim{k}.fits", kind, nreads, level, seed + k - 1, side)
        scene = fits.ImageHDU(np.full((side, side), rate), name="SCENE")
        scene.header["EXTVER"] = k
        scene.header["BUNIT"] = "electron/s"
        measured = fits.ImageHDU(reads, name="MEASURED")
        measured.header["EXTVER"] = k
        measured.header["TFRAME"] = (DT, "s")
        measured.header["TFIRST"] = (DT, "s: read 1 of the simulator")
        measured.header["BUNIT"] = "electron"
        hdus += [scene, measured]
    tmp = path + ".tmp"
    fits.HDUList(hdus).writeto(tmp, overwrite=True)
    os.replace(tmp, path)
    effects = RAMP_KINDS[kind]
    beta = BETA if effects["nl"] else 0.0
    return {"path": path, "rate": rate,
            "truth": {"alpha": ALPHA, "beta": beta, "deficit_at_50ke": beta * 5.0e4,
                      "bf_kernel": bf_kernel().tolist() if effects["bfe"] else None,
                      "read_noise": READ_NOISE}}

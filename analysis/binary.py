"""The binary-star study of the paper's section 4, and the fitting-method comparison.

**Grid** (:class:`BinaryGrid`). A primary of brightness ``bright``, ``mid`` or
``dim`` and a secondary ``ratio`` times fainter (1, 1/2, 1/4, 1/8), separated
by ``separation`` pixels along x (2.0 to 5.0 in steps of 0.5, and 20 as the
isolated reference). The primary sits at the 16 sub-pixel offsets
``(dx, dy)``, ``dx, dy in {0, .25, .5, .75}``. Each scene is made noise-free
and with noise (Poisson on the scene, read noise added after IPC, several
seeded realisations), and three frames are made from it by
:func:`analysis.simulate.simulate`, the paper's flow chart (section 3.1), with
no sky background or dark signal:

- ``truth``: the scene (plus the same read-noise instance),
- ``coupled``: :func:`ipc_taichi.couple` of the scene, plus read noise,
- ``decoupled``: :func:`ipc_taichi.decouple` of the coupled frame (paper's
  stopping rule: 20 iterations or ``1e-5`` relative change).

Every frame is fitted the same way, with photutils (:func:`analysis.photometry.fit_stars`:
both stars in one group, ``fit_shape`` 9x9, initial guesses 0.1 px and 5 %
off the truth) and the effective PSF an observer would build from isolated
stars in that kind of frame (:data:`FITS`): the truth ePSF for truth frames,
the coupled ePSF at the primary's flux for coupled frames, the decoupled ePSF
for decoupled frames; plus ``coupled_optical``: coupled frames fitted with the
IPC-free PSF, as the paper did ("fitting of the F405N WebbPSF to the IPC
coupled data"), and ``coupled_brightpsf``: coupled frames fitted with the
coupled ePSF of a bright isolated star (the abstract's scenario of a field
star's PSF used on a fainter blend; run for the 4:1 pair 3 px apart).

Detection (:func:`analysis.photometry.detect_stars`, IRAFStarFinder) runs on
the noise-free coupled and truth frames (only) at each ``min_separation`` of
:data:`DETECT_MIN_SEPARATIONS`, so that what merges a close pair (the finder's
setting, the optics, or IPC) can be told apart.

**Fitter choices** (:func:`fitter_choices`): the paper's separation error of
a coupled 3 px pair fitted with the IPC-free PSF under the choices a user
makes (one group or each star alone, fit box, pixel-integrated or
point-sampled frames and PSF).

**Methods** (:class:`MethodStudy`): a 4:1 pair 3 px apart with Poisson noise
and growing read noise, fitted (a) plainly on the coupled frame with the
coupled ePSF, (b) after decoupling with the decoupled ePSF, (c) by the
IPC-aware forward model (:mod:`analysis.photometry_forward`) on the coupled
frame with the IPC-free ePSF. (a)-(c) use one least-squares fitter on the same
pixels, weighted by the noise model (Poisson + read noise) on noisy frames;
(a) and (b) are repeated with photutils (unweighted) as a cross-check.

**Runtime.** Tasks (one scene at the 16 offsets) run in a pool of processes
(``spawn``: Taichi has one runtime per process and initialises lazily in each
worker) with a tqdm bar. Each task's result is cached in an ``.npz`` under a
key made of the task's parameters and a hash of the sources it depends on
(this package, ``ipc_taichi``, the photutils version), so re-runs and the
``quick`` subset reuse finished tasks.
"""

import hashlib
import json
import os
import time
import warnings
from dataclasses import asdict, dataclass, field

import numpy as np

from .photometry import detect_stars, fit_stars, image_psf, pair_errors
from .photometry_forward import fit_stars_forward
from .simulate import MAGNITUDES, flux_from_mag, simulate

__all__ = ["FLUX", "SEPARATIONS", "RATIOS", "OFFSETS", "FITS", "METHODS", "DETECT_MIN_SEPARATIONS",
           "BinaryGrid", "MethodStudy", "pair_frames", "run_study", "summarise",
           "fitter_choices"]

FLUX = {name: float(flux_from_mag(mag)) for name, mag in MAGNITUDES.items()}
"""Total counts of each primary in 10 ks (:mod:`analysis.simulate`'s zero point: the
bright star's central pixel holds 60,000 e-): bright 4.13e5, mid 8.63e4, dim 1.14e4."""

SEPARATIONS = (2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 20.0)
RATIOS = (1.0, 0.5, 0.25, 0.125)
OFFSETS = tuple((dx, dy) for dy in (0.0, 0.25, 0.5, 0.75) for dx in (0.0, 0.25, 0.5, 0.75))

FITS = {"truth": ("truth", "truth", None), "coupled": ("coupled", "coupled", None),
        "coupled_optical": ("coupled", "truth", None),
        "decoupled": ("decoupled", "decoupled", None),
        "coupled_brightpsf": ("coupled", "coupled", "bright")}
"""Fit name -> (frame fitted, stage of the effective PSF used, brightness whose flux the
PSF's IPC saw: ``None`` = the primary's own). ``coupled_brightpsf`` is the abstract's
scenario: the PSF measured on a bright isolated field star, used on every pair."""

DETECT_MIN_SEPARATIONS = (1.0, 2.0, 3.0, 5.25)
"""``min_separation`` values [px] of the detection sweep; 5.25 = 2.5 x FWHM, photutils'
default, which merges any closer pair whatever the image holds."""
DETECT_FRAMES = ("coupled", "truth")

METHODS = ("plain", "decoupled", "forward", "plain_photutils", "decoupled_photutils")

# Initial guesses: offsets from the truth in x, y [px] and flux factors, primary then
# secondary, as a finder's centroids and aperture fluxes of a resolved pair would be.
_INIT_DX, _INIT_DY, _INIT_FLUX = (0.1, -0.1), (0.05, -0.05), (1.05, 0.95)
# files of this package (``analysis/`` in the repository, ``ipc_taichi_analysis`` installed)
_SOURCES = ("binary.py", "photometry.py", "photometry_forward.py", "psf.py", "simulate.py")


@dataclass(frozen=True)
class BinaryGrid:
    """Parameters of the binary-star grid (defaults: the paper's section 4)."""

    brightness: tuple = ("bright", "mid", "dim")
    ratios: tuple = RATIOS
    separations: tuple = SEPARATIONS
    offsets: tuple = OFFSETS
    n_noise: int = 2
    read_noise: float = 10.0
    seed: int = 2018
    law: str = "donlon2018"
    fit_shape: tuple = (9, 9)
    half: int = 12
    psf_source: str = "jwst_f405n"
    oversample: int = 4
    kind: str = field(default="grid", init=False)

    @classmethod
    def quick(cls):
        """A subset for tests: bright 4:1 pair at 3 and 20 px, one noise realisation."""
        return cls(brightness=("bright",), ratios=(0.25,), separations=(3.0, 20.0), n_noise=1)

    def tasks(self):
        """One task per (brightness, ratio, separation, realisation); -1 = noise-free."""
        for name in self.brightness:
            for ratio in self.ratios:
                for sep in self.separations:
                    for realisation in range(-1, self.n_noise):
                        yield {"kind": self.kind, "brightness": name, "ratio": ratio,
                               "separation": sep, "realisation": realisation,
                               "read_noise": self.read_noise if realisation >= 0 else 0.0,
                               "offsets": [list(o) for o in self.offsets], "seed": self.seed,
                               "law": self.law, "fit_shape": list(self.fit_shape),
                               "half": self.half}


@dataclass(frozen=True)
class MethodStudy:
    """Parameters of the fitting-method comparison versus read noise."""

    brightness: tuple = ("bright", "mid", "dim")
    ratio: float = 0.25
    separation: float = 3.0
    read_noise: tuple = (0.0, 5.0, 10.0, 20.0, 40.0, 80.0)
    offsets: tuple = OFFSETS
    n_noise: int = 4
    seed: int = 4018
    law: str = "donlon2018"
    fit_shape: tuple = (9, 9)
    half: int = 12
    psf_source: str = "jwst_f405n"
    oversample: int = 4
    kind: str = field(default="methods", init=False)

    @classmethod
    def quick(cls):
        """A subset for tests: dim primary, read noise 0 and 40, one realisation."""
        return cls(brightness=("dim",), read_noise=(0.0, 40.0), offsets=OFFSETS[:4], n_noise=1)

    def tasks(self):
        """One noise-free task per brightness (``realisation`` -1, ``read_noise`` -1),
        then one per (brightness, read noise, realisation) with Poisson and read noise."""
        for name in self.brightness:
            levels = [(-1.0, -1)] + [(rn, r) for rn in self.read_noise for r in range(self.n_noise)]
            for rn, realisation in levels:
                    yield {"kind": self.kind, "brightness": name, "ratio": self.ratio,
                           "separation": self.separation, "realisation": realisation,
                           "read_noise": rn, "offsets": [list(o) for o in self.offsets],
                           "seed": self.seed, "law": self.law, "fit_shape": list(self.fit_shape),
                           "half": self.half}


def pair_frames(psf, brightness, ratio, separation, offsets, law="donlon2018", half=12, seed=None,
                read_noise=0.0, oversample=4, sampling="integrated"):
    """The truth, coupled and decoupled frames of a pair at several sub-pixel offsets.

    Each frame comes from :func:`analysis.simulate.simulate` (the paper's flow
    chart) with no sky background or dark signal, as in the paper's PSF study.

    Parameters
    ----------
    psf : ndarray
        Optical PSF (:func:`analysis.psf.optical_psf`).
    brightness : str
        Primary: ``"bright"``, ``"mid"`` or ``"dim"`` (:data:`FLUX`).
    ratio : float
        Secondary counts as a fraction of the primary's.
    separation : float
        Along x, in pixels (a multiple of ``1/oversample``).
    offsets : sequence of (dx, dy)
        Sub-pixel offsets of the primary from pixel ``(half, half)``.
    law : str
        Coupling law of :func:`ipc_taichi.couple` / :func:`ipc_taichi.decouple`.
    half : int
        Pixels from the primary to the frame's left, top and bottom edges (and
        from the secondary to the right edge).
    seed : int, optional
        With a seed, Poisson noise is drawn on the scene before coupling and
        one read-noise instance is added to both truth and coupled frames
        (paper section 3.1), offset ``k`` seeded with ``seed + k``; without,
        the frames are noise-free.
    read_noise : float
        RMS read noise [e-].
    oversample : int
    sampling : {"integrated", "point"}
        Detector model (:func:`analysis.psf.point_source_image`).

    Returns
    -------
    positions : ndarray, shape (n, 2, 2)
        ``[k, star, (x, y)]`` of primary and secondary for each offset.
    fluxes : ndarray, shape (2,)
        Counts of primary and secondary.
    frames : dict of ndarray, shape (n, ny, nx)
        ``truth``, ``coupled``, ``decoupled``.
    """
    import ipc_taichi

    mag1 = MAGNITUDES[brightness]
    mags = (mag1, mag1 - 2.5 * np.log10(ratio))
    shape = (2 * half + 1, 2 * half + 1 + int(np.ceil(separation)))
    positions = np.array([[[half + dx, half + dy], [half + dx + separation, half + dy]]
                          for dx, dy in offsets])
    frames = {"truth": [], "coupled": [], "decoupled": []}
    with warnings.catch_warnings():
        # a noisy frame may stop at 20 iterations: the paper's rule, not an error here
        warnings.simplefilter("ignore", ipc_taichi.ConvergenceWarning)
        for k, ((x1, y1), (x2, y2)) in enumerate(positions):
            images = simulate([(x1, y1, mags[0]), (x2, y2, mags[1])], shape, psf=psf,
                              background=0.0, dark=0.0, poisson=seed is not None,
                              read_noise=read_noise if seed is not None else 0.0, law=law,
                              seed=0 if seed is None else seed + k, oversample=oversample,
                              sampling=sampling)
            for name in frames:
                frames[name].append(getattr(images, name))
    return positions, images.fluxes, {name: np.stack(v) for name, v in frames.items()}


# ----------------------------------------------------------------------------- workers

_STATE = {}


def _build_state(study):
    """Optical PSF and effective PSFs (truth; coupled and decoupled per brightness)."""
    from .psf import effective_psf, optical_psf

    psf = optical_psf(study.psf_source, study.oversample)
    epsf = {("truth", None): effective_psf(psf, 1.0, stage="truth", oversample=study.oversample)}
    for name in sorted(set(study.brightness) | {"bright"}):
        for stage in ("coupled", "decoupled"):
            epsf[(stage, name)] = effective_psf(psf, FLUX[name], stage=stage, law=study.law,
                                                oversample=study.oversample)
    return {"psf": psf, "epsf": epsf, "oversample": study.oversample}


def _init_worker(state):
    _STATE.clear()
    _STATE.update(state)
    _STATE["models"] = {}


def _epsf(stage, name):
    return _STATE["epsf"][("truth", None) if stage == "truth" else (stage, name)]


def _fit_psf(fit, name):
    """Frame stage and photutils model of a fit in :data:`FITS` for primary ``name``."""
    frame_stage, psf_stage, level = FITS[fit]
    return frame_stage, _psf_model(psf_stage, level or name)


def _psf_model(stage, name):
    key = (stage, name)
    if key not in _STATE["models"]:
        _STATE["models"][key] = image_psf(_epsf(stage, name), _STATE["oversample"])
    return _STATE["models"][key]


def _task_seed(task):
    if task["realisation"] < 0:
        return None
    # from the task's values, not its place in a grid, so a subset draws the same noise
    entropy = [task["seed"], sorted(MAGNITUDES).index(task["brightness"]),
               int(round(task["ratio"] * 1e6)), int(round(task["separation"] * 1e3)),
               int(round(task["read_noise"] * 1e3)), task["realisation"]]
    return int(np.random.SeedSequence(entropy).generate_state(1)[0])


def _init_guess(pos, flux):
    x = pos[:, 0] + _INIT_DX
    y = pos[:, 1] + _INIT_DY
    return x, y, flux * np.asarray(_INIT_FLUX)


def _scenario(task):
    """Where the abstract's bright-star-PSF scenario is run: the 4:1 pair 3 px apart."""
    return task["ratio"] == 0.25 and task["separation"] == 3.0


def _grid_task(task):
    name, ratio = task["brightness"], task["ratio"]
    positions, flux, frames = pair_frames(_STATE["psf"], name, ratio, task["separation"],
                                          task["offsets"], task["law"], task["half"],
                                          _task_seed(task), task["read_noise"],
                                          _STATE["oversample"])
    n = len(positions)
    out = {"flux_error": np.empty((len(FITS), n, 2)), "separation_error": np.empty((len(FITS), n)),
           "flags": np.empty((len(FITS), n), dtype=int),
           "detected": np.empty((len(DETECT_FRAMES), len(DETECT_MIN_SEPARATIONS), n), dtype=int)}
    # detection threshold: a fifth of the secondary's peak (noise-free), or 5 sigma
    peak2 = 0.11 * flux[1]
    threshold = 5 * task["read_noise"] if task["read_noise"] > 0 else 0.2 * peak2
    for k, pos in enumerate(positions):
        x0, y0, f0 = _init_guess(pos, flux)
        for i, fit_name in enumerate(FITS):
            if fit_name == "coupled_brightpsf" and (name == "bright" or not _scenario(task)):
                # the bright primary's own PSF is the bright star's: the same fit; elsewhere
                # the scenario is not run (it would cost a fifth more fits for no table)
                same = name == "bright"
                out["flux_error"][i, k] = (out["flux_error"][list(FITS).index("coupled"), k]
                                           if same else np.nan)
                out["separation_error"][i, k] = (
                    out["separation_error"][list(FITS).index("coupled"), k] if same else np.nan)
                out["flags"][i, k] = out["flags"][list(FITS).index("coupled"), k] if same else 0
                continue
            frame_stage, model = _fit_psf(fit_name, name)
            fit = fit_stars(frames[frame_stage][k], model, x0, y0, f0,
                            fit_shape=tuple(task["fit_shape"]))
            out["flux_error"][i, k], out["separation_error"][i, k] = pair_errors(
                fit, pos[:, 0], pos[:, 1], flux)
            out["flags"][i, k] = fit.flags.max()
        if task["realisation"] >= 0:
            # detection is studied on noise-free frames only (a finder call costs more
            # than a fit here); noisy tasks mark it as not run
            out["detected"][..., k] = -1
            continue
        for f, frame_stage in enumerate(DETECT_FRAMES):
            for j, min_sep in enumerate(DETECT_MIN_SEPARATIONS):
                xd, yd = detect_stars(frames[frame_stage][k], fwhm=2.1,
                                      threshold=max(threshold, 1e-9), min_separation=min_sep)
                out["detected"][f, j, k] = sum(bool(np.any(np.hypot(xd - x, yd - y) < 0.5))
                                               for x, y in pos)
    return out


def _method_task(task):
    name, ratio = task["brightness"], task["ratio"]
    positions, flux, frames = pair_frames(_STATE["psf"], name, ratio, task["separation"],
                                          task["offsets"], task["law"], task["half"],
                                          _task_seed(task), max(task["read_noise"], 0.0),
                                          _STATE["oversample"])
    n, shape = len(positions), tuple(task["fit_shape"])
    out = {"flux_error": np.empty((len(METHODS), n, 2)),
           "separation_error": np.empty((len(METHODS), n)),
           "flags": np.empty((len(METHODS), n), dtype=int)}
    # noisy frames: every least-squares fit is weighted by the noise model (Poisson +
    # read noise); noise-free frames have none, and are fitted unweighted
    rn = task["read_noise"] if task["realisation"] >= 0 else None
    for k, pos in enumerate(positions):
        x0, y0, f0 = _init_guess(pos, flux)
        fits = {
            "plain": fit_stars_forward(frames["coupled"][k], _epsf("coupled", name), x0, y0, f0,
                                       law=None, fit_shape=shape, read_noise=rn),
            "decoupled": fit_stars_forward(frames["decoupled"][k], _epsf("decoupled", name),
                                           x0, y0, f0, law=None, fit_shape=shape, read_noise=rn),
            "forward": fit_stars_forward(frames["coupled"][k], _epsf("truth", name), x0, y0, f0,
                                         law=task["law"], fit_shape=shape, read_noise=rn),
            "plain_photutils": fit_stars(frames["coupled"][k], _psf_model("coupled", name),
                                         x0, y0, f0, fit_shape=shape),
            "decoupled_photutils": fit_stars(frames["decoupled"][k], _psf_model("decoupled", name),
                                             x0, y0, f0, fit_shape=shape),
        }
        for i, method in enumerate(METHODS):
            out["flux_error"][i, k], out["separation_error"][i, k] = pair_errors(
                fits[method], pos[:, 0], pos[:, 1], flux)
            out["flags"][i, k] = fits[method].flags.max()
    return out


def fitter_choices(psf, brightness="bright", ratio=0.25, separation=3.0, offsets=OFFSETS,
                   law="donlon2018", fit_shapes=(5, 7, 9, 11), oversample=4, half=12):
    """Separation and flux errors of a coupled pair fitted with the IPC-free PSF, per fitter choice.

    The paper's fit ("the F405N WebbPSF fitted to the IPC coupled data") on
    noise-free coupled frames, repeated over the choices its text leaves
    open: the detector model of the frames and of the PSF (``integrated``:
    pixel-integrated frames fitted with the pixel-integrated ePSF;
    ``point``: the paper's point-sampled frames (its Eq. 10) fitted with the
    4x optical PSF used directly as an ePSF, as a WebbPSF file would be; and
    ``mixed``: pixel-integrated frames fitted with the point-sampled PSF),
    grouping (``grouped``: both stars in one simultaneous fit; ``alone``:
    each star fitted on its own, the other's light left in its box) and the
    fit box.

    The truth frames are fitted the same way: ``coupled - truth`` is what IPC
    adds to the error of that choice, the rest being PSF mismatch.

    Returns
    -------
    list of dict
        One per choice: ``sampling``, ``grouping``, ``fit_shape``, and for
        ``coupled`` and ``truth`` frames ``separation_error_mpix`` and
        ``flux_error_pct`` (primary, secondary) as ``[mean, std]`` over ``offsets``.
    """
    from .psf import effective_psf

    epsf = {"integrated": effective_psf(psf, 1.0, stage="truth", oversample=oversample),
            "point": effective_psf(psf, 1.0, stage="truth", oversample=oversample,
                                   sampling="point")}
    # the point-sampled ePSF sums to o**2 only as a Riemann sum does; ImagePSF needs it exact
    epsf["point"] *= oversample ** 2 / epsf["point"].sum()
    frames = {}
    for sampling in ("integrated", "point"):
        pos, flux, fr = pair_frames(psf, brightness, ratio, separation, offsets, law, half,
                                    oversample=oversample, sampling=sampling)
        frames[sampling] = fr
    setups = {"integrated": ("integrated", "integrated"), "point": ("point", "point"),
              "mixed": ("integrated", "point")}
    # an ungrouped fit is tried at the middle box only: its faint star slides onto the primary
    choices = ([("grouped", size) for size in fit_shapes]
               + [("alone", fit_shapes[len(fit_shapes) // 2])])
    out = []
    for sampling, (frame_kind, psf_kind) in setups.items():
        model = image_psf(epsf[psf_kind], oversample)
        for grouping, size in choices:
            row = {"sampling": sampling, "grouping": grouping, "fit_shape": size}
            for stage in ("coupled", "truth"):
                flux_err, sep_err = [], []
                for k, p in enumerate(pos):
                    x0, y0, f0 = _init_guess(p, flux)
                    fit = fit_stars(frames[frame_kind][stage][k], model, x0, y0, f0,
                                    fit_shape=(size, size),
                                    min_separation=None if grouping == "grouped" else 0.5)
                    fe, se = pair_errors(fit, p[:, 0], p[:, 1], flux)
                    flux_err.append(fe)
                    sep_err.append(se)
                flux_err, sep_err = np.array(flux_err), np.array(sep_err)
                row[stage] = {"separation_error_mpix": [float(sep_err.mean()),
                                                        float(sep_err.std())],
                              "flux_error_pct": [[float(flux_err[:, j].mean()),
                                                  float(flux_err[:, j].std())] for j in (0, 1)]}
            out.append(row)
    return out


def _run_task(task):
    return _grid_task(task) if task["kind"] == "grid" else _method_task(task)


# ----------------------------------------------------------------------------- runner

def source_hash(root=None):
    """Hash of the sources a result depends on (this study, the PSF, ipc_taichi, photutils);
    ``root``: the folder of this package's files (default: where it is)."""
    import photutils

    import ipc_taichi

    root = root or os.path.dirname(os.path.abspath(__file__))
    paths = [os.path.join(root, p) for p in _SOURCES]
    core = os.path.dirname(os.path.abspath(ipc_taichi.__file__))
    paths += sorted(os.path.join(core, f) for f in os.listdir(core) if f.endswith(".py"))
    h = hashlib.sha256(photutils.__version__.encode())
    for p in paths:
        with open(p, "rb") as f:
            h.update(f.read())
    return h.hexdigest()[:16]


def _task_key(task, sources):
    text = json.dumps(task, sort_keys=True) + sources
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _load_cache(path):
    if not path or not os.path.exists(path):
        return {}
    try:
        with np.load(path) as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError):
        return {}  # an unreadable cache is only a slower run


def _save_cache(path, cache):
    from ipc_taichi.fitsio import atomic_output

    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with atomic_output(path, overwrite=True) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **cache)


def run_study(study, workers=2, cache_path=None, progress=True):
    """Run every task of a :class:`BinaryGrid` or :class:`MethodStudy`.

    Parameters
    ----------
    study : BinaryGrid or MethodStudy
    workers : int
        Processes (``0`` runs in this process, as tests do).
    cache_path : str, optional
        ``.npz`` of per-task results; tasks found there (same parameters, same
        source hash) are not recomputed, new ones are added.
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    tasks : list of dict
    results : list of dict of ndarray
        In the order of ``tasks``; see :func:`summarise`.
    """
    from tqdm import tqdm

    tasks = list(study.tasks())
    sources = source_hash()
    keys = [_task_key(t, sources) for t in tasks]
    cache = _load_cache(cache_path)
    results = [None] * len(tasks)
    todo = []
    for i, key in enumerate(keys):
        if all(f"{key}/{name}" in cache for name in _result_names(tasks[i])):
            results[i] = {name: cache[f"{key}/{name}"] for name in _result_names(tasks[i])}
        else:
            todo.append(i)
    bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), disable=not progress,
               desc=f"binary {study.kind}", unit="task")
    if todo:
        state = _build_state(study)
        if workers <= 0:
            _init_worker(state)
            for i in todo:
                results[i] = _run_task(tasks[i])
                bar.update()
        else:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor, as_completed

            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=_init_worker, initargs=(state,)) as pool:
                futures = {pool.submit(_run_task, tasks[i]): i for i in todo}
                last = time.monotonic()
                for future in as_completed(futures):
                    i = futures[future]
                    results[i] = future.result()
                    bar.update()
                    # save finished tasks now and then: an interrupted run keeps them
                    if cache_path and time.monotonic() - last > _SAVE_EVERY:
                        _store(cache, keys, results, cache_path)
                        last = time.monotonic()
        if cache_path:
            _store(cache, keys, results, cache_path)
    bar.close()
    return tasks, results


_SAVE_EVERY = 60.0  # seconds between cache saves in a pooled run


def _store(cache, keys, results, cache_path):
    for key, result in zip(keys, results):
        if result is not None:
            for name, value in result.items():
                cache[f"{key}/{name}"] = value
    _save_cache(cache_path, cache)


def _result_names(task):
    names = ("flux_error", "separation_error", "flags")
    return names + ("detected",) if task["kind"] == "grid" else names


def summarise(study, tasks, results):
    """Means and spreads over sub-pixel offsets (and noise realisations).

    Returns
    -------
    dict
        ``{"study": parameters, "rows": [...]}``, one row per (brightness,
        ratio, separation, noise) for a grid and per (brightness, read noise)
        for a method study, with, per fit or method, ``flux_error_pct``
        ``[[mean, std] primary, [mean, std] secondary]``,
        ``separation_error_mpix`` ``[mean, std]``, ``n``, and ``flagged``.
        Method rows also give, per method, ``vs_forward``: mean and std of the
        paired differences from the forward fit on the same frames (the
        shared noise cancels, leaving what the method itself adds).
        Noise-free grid rows also give ``detected[frame][min_separation]``: the
        fraction of the pair's stars that IRAFStarFinder found within 0.5 px on
        the coupled and on the truth frame, at each ``min_separation`` of
        :data:`DETECT_MIN_SEPARATIONS` (keys formatted with ``%g``); ``None`` on
        rows with noise (detection is not run there).
    """
    groups = {}
    for task, res in zip(tasks, results):
        if task["kind"] == "grid":
            key = (task["brightness"], task["ratio"], task["separation"], task["realisation"] >= 0)
        else:
            key = (task["brightness"], task["read_noise"])
        groups.setdefault(key, []).append(res)
    names = list(FITS) if study.kind == "grid" else list(METHODS)
    rows = []
    for key, items in groups.items():
        flux = np.concatenate([r["flux_error"] for r in items], axis=1)
        sep = np.concatenate([r["separation_error"] for r in items], axis=1)
        flags = np.concatenate([r["flags"] for r in items], axis=1)
        row = ({"brightness": key[0], "ratio": key[1], "separation": key[2], "noise": key[3]}
               if study.kind == "grid" else {"brightness": key[0], "read_noise": key[1]})
        for i, name in enumerate(names):
            row[name] = {
                "flux_error_pct": [[float(flux[i, :, s].mean()), float(flux[i, :, s].std())]
                                   for s in (0, 1)],
                "separation_error_mpix": [float(sep[i].mean()), float(sep[i].std())],
                "n": int(sep.shape[1]), "flagged": int(np.count_nonzero(flags[i]))}
        if study.kind == "grid":
            detected = np.concatenate([r["detected"] for r in items], axis=-1)
            row["detected"] = (None if key[3] else
                               {frame: {f"{m:g}": float(detected[f, j].mean() / 2)
                                        for j, m in enumerate(DETECT_MIN_SEPARATIONS)}
                                for f, frame in enumerate(DETECT_FRAMES)})
        else:
            # the methods see the same noise: their paired differences isolate what
            # each does beyond the forward fit (e.g. the decoupled read-noise correlation)
            f = names.index("forward")
            for i, name in enumerate(names):
                dflux, dsep = flux[i] - flux[f], sep[i] - sep[f]
                row[name]["vs_forward"] = {
                    "flux_error_pct": [[float(dflux[:, s].mean()), float(dflux[:, s].std())]
                                       for s in (0, 1)],
                    "separation_error_mpix": [float(dsep.mean()), float(dsep.std())]}
        rows.append(row)
    params = asdict(study)
    return {"study": {k: (list(v) if isinstance(v, tuple) else v) for k, v in params.items()},
            "flux": FLUX, "rows": rows}


"""``calibrate``: darks, flats and reference files in; a coupling-model file out.

The steps are those of a detector laboratory:

1. **Hot pixels** in the darks give alpha(S, 0) per direction
   (:mod:`.hotpixels`); they see the coupling of the charge present at
   readout and, to first order, no brighter-fatter (their neighbours are
   empty).
2. **Flat ramps** (:mod:`.ramps`) separate what flats mix: the gain,
   classical non-linearity, the IPC kernel with its change with signal
   (non-linear IPC) and the brighter-fatter kernel, from the time structure
   of the ramps; their alpha(S, S) points have brighter-fatter removed.
   Flats of frames at one level (:mod:`.flats`) cannot separate them: the
   report says so, and where they rise while the hot pixels stay flat it
   names brighter-fatter as the likely cause and leaves them out of the law.
3. **The law** (:mod:`.lawfit`): a symmetric alpha(S, N) through both
   cross-sections, chosen by held-out evidence (folds of hot pixels by
   position and of flat-ramp blocks), with its uncertainty band.
4. **Transfer** (:mod:`.transfer`): the chosen law and the best constant,
   fitted on half the hot pixels, decouple the other half.
5. The model (law, geometry, edge) is written with
   :meth:`ipc_taichi.model.CouplingModel.save`, with the brighter-fatter
   kernel, the non-linearity and the law's band as named sections that the
   forward simulators may use and ``decouple`` never does; the report
   (:mod:`.report`) says what was measured, assumed and not measured.

6. **The map** (:mod:`.maps`): the coupling of each neighbour pair across
   the detector, per super-pixel from flats and hot pixels, written only
   when held-out data prefer it to the uniform law; two assumptions
   (read-noise correlation between neighbours, hot pixels without
   brighter-fatter) are tested (:mod:`.assumptions`).

A reference file (:mod:`.reffiles`) alone gives its model (a constant law, and
the detector's map for a per-pixel file); with measurements it is reported
beside them for comparison.
"""

import os
import warnings

import numpy as np

from ..errors import IPCInputError
from ..fitsio import check_output_path
from ..model import CouplingModel
from . import (
    assumptions,
    hotpixels,
    lawfit,
    maps,
    ramps,
    records,
    reffiles,
    report,
    stream,
    transfer,
    verdicts,
)
from . import flats as flatmod
from .inputs import DEFAULT_DQ_BITS, read_frames

__all__ = ["calibrate"]

SAME_ILLUMINATION = 0.1
"""Flat ramps whose mean charge per group differs by less than this fraction
are integrations of one illumination (measured together)."""

PIXELS_PER_FOLD = 6
"""Fewest hot pixels per held-out fold (a bin's error needs 3 pixels)."""

BF_LIKELY_SIGMA = 3.0
"""Flats of one level rising by this many sigma while hot pixels stay flat:
brighter-fatter is named as the likely cause."""


class _HotPixels:
    """The darks' hot pixels: every measurement, the integrations they came
    from (for the transfer check), the signal bins of the full data."""

    def __init__(self, darks, threshold, not_measured):
        events, self.integrations, read_noise, self.found, noise = [], [], [], 0, []
        for f in darks:
            for i, integ in enumerate(f.data):
                noise.append(hotpixels.frame_noise(integ[-1], f.mask[i, -1]))
                positions = hotpixels.find_hot_pixels(integ[-1], f.mask[i, -1],
                                                      threshold=threshold)
                self.found += len(positions)
                if len(positions):
                    events.append(hotpixels.measure_events(integ, positions, f.mask[i]))
                    self.integrations.append((integ, positions))
                rn = hotpixels.read_noise_from_darks(integ, f.mask[i])
                if rn is not None:
                    read_noise.append(rn)
        self.read_noise = float(np.median(read_noise)) if read_noise else None
        noise = [n for n in noise if n is not None]
        self.floors = hotpixels.floors(float(np.median(noise)) if noise else None)
        self.events = ({k: np.concatenate([e[k] for e in events]) for k in events[0]}
                       if events else None)
        self.rows = (hotpixels.summarise_events(self.events, min_signal=self.floors["bins"])
                     if self.events else [])
        self.bins = (np.array([r["signal_range"][0] for r in self.rows]
                              + [self.rows[-1]["signal_range"][1]]) if self.rows else None)
        if darks and not self.rows:
            not_measured.append("alpha(S,0): no isolated hot pixel in the darks (threshold "
                                f"{threshold:g} sigma; {self.found} candidates)")

    def folds(self, wanted):
        """The number of folds: ``wanted``, fewer when the hot pixels are few
        (at least :data:`PIXELS_PER_FOLD` per fold, and 2 folds)."""
        if self.events is None:
            return wanted
        pixels = np.unique(self.events["pixel"]).size
        return max(2, min(wanted, pixels // PIXELS_PER_FOLD))

    def rows_for(self, folds, k):
        """Bins measured on the hot pixels of the given folds (all when None)."""
        if not self.rows:
            return []
        if folds is None:
            return self.rows
        keep = np.isin(hotpixels.fold_of(self.events["pixel"], k), list(folds))
        rows = hotpixels.summarise_events(hotpixels.select_events(self.events, keep),
                                          bins=self.bins, min_count=3,
                                          min_signal=self.floors["bins"])
        full = {r["signal_range"][0]: r for r in self.rows}
        out = []
        for r in rows:
            ref = full.get(r["signal_range"][0])
            out.append(_scaled_errors(r, ref, hotpixels.DIRECTIONS, r["n_pixels"],
                                      ref["n_pixels"] if ref else 1))
        return out

    def slope(self):
        """Weighted slope of the nearest-neighbour alpha(S, 0) per 10 ke- and its significance."""
        rows = [r for r in self.rows if r["x"]["error"] and r["y"]["error"]]
        if len(rows) < 2:
            return None
        s = np.array([r["signal"] for r in rows]) / 1e4
        v = np.array([0.5 * (r["x"]["value"] + r["y"]["value"]) for r in rows])
        e = np.array([0.5 * np.hypot(r["x"]["error"], r["y"]["error"]) for r in rows])
        return flatmod.weighted_slope(s, v, e)


class _Flats:
    """Flat inputs: ramps (one :class:`.ramps.FlatRamps` per illumination) and
    frames at one level (one row per file), with their held-out folds."""

    def __init__(self, flat_files, read_noise, not_measured, notes, collection_steps=None):
        self.read_noise = read_noise
        self.sets = []
        ramp_files = [f for f in flat_files if f.meta.get("stack") == "ramp"]
        self.frame_files = [f for f in flat_files if f.meta.get("stack") != "ramp"]
        for group in _by_illumination(ramp_files):
            data = stream.concatenate([f.data for f in group])
            mask = stream.concatenate([f.mask for f in group])
            sat = [f.meta.get("saturation") for f in group if f.meta.get("saturation")]
            label = ", ".join(f.label for f in group)
            flat_less = _no_shot_noise(data, mask, read_noise)
            if flat_less:
                not_measured.append(f"{label}: flat ramps: {flat_less}")
                continue
            self.sets.append((label, ramps.FlatRamps.from_ramps(
                data, mask, saturation=min(sat) if sat else None,
                collection_steps=collection_steps)))
        self.measured = [(label, _measured(label, s, read_noise)) for label, s in self.sets]
        self.kernels = [m["brighter_fatter"].get("kernel") if m["brighter_fatter"].get("measured")
                        else None for _, m in self.measured]
        self.ramp_rows = []
        for (label, s), kernel in zip(self.sets, self.kernels):
            rows = s.levels(bf_kernel=kernel, read_noise=read_noise)
            for r in rows:
                r["file"] = label
                r["source"] = "flat ramp"
            self.ramp_rows += rows
        self.frame_rows = _measure_frames(self.frame_files, read_noise, not_measured)
        usable = [r for r in self.ramp_rows + self.frame_rows if r.get("terms")]
        if flat_files and not usable:
            not_measured.append("alpha(S,S): no usable flat level")
        elif len(usable) == 1:
            not_measured.append("alpha(S,S) at one level only: its change with signal is not "
                                "measured (held constant)")
        if self.frame_files:
            notes.append("flats of frames at one level have no time structure: they cannot "
                         "tell brighter-fatter and non-linear IPC apart (give flat ramps)")

    @property
    def rows(self):
        return self.ramp_rows + self.frame_rows

    def rows_for(self, folds, k, use_frames=True):
        """Flat points of the given folds (blocks of each ramp set, stripes of
        each frame file); all when None."""
        if folds is None:
            return self.ramp_rows + (self.frame_rows if use_frames else [])
        rows = []
        for (label, s), kernel in zip(self.sets, self.kernels):
            blocks = [b for b in range(s.n_blocks) if b % k in folds]
            if not blocks:
                continue
            full = [r for r in self.ramp_rows if r["file"] == label]
            part = s.levels(blocks=blocks, bf_kernel=kernel, read_noise=self.read_noise)
            rows += [_scaled_errors(r, f, flatmod.TERMS, len(blocks), s.n_blocks,
                                    nested="terms") for r, f in zip(part, full)]
        if use_frames:
            for f in self.frame_files:
                rows += _measure_frames([f], self.read_noise, [], stripes=(folds, k))
        return rows


def _scaled_errors(row, full, names, n_part, n_full, nested=None):
    """``row`` (measured on part of the data) with each error replaced by the
    full data's error scaled by ``sqrt(n_full / n_part)``: the error a part
    of that size should have. Errors from the scatter of a few pixels or
    blocks are themselves noisy, and one that comes out far too small would
    decide a held-out comparison alone."""
    if full is None or not (row.get(nested) if nested else True):
        return row
    scale = np.sqrt(n_full / max(n_part, 1))
    out = dict(row)
    src, ref = (row[nested], full[nested]) if nested else (row, full)
    new = {name: {**src[name], "error": ref[name]["error"] * scale} for name in names
           if name in src and name in ref}
    if nested:
        out[nested] = {**src, **new}
    else:
        out.update(new)
    return out


def _by_illumination(files):
    """Ramp files grouped by frame shape, groups and charge per group."""
    groups = []
    for f in files:
        rate = _charge_per_group(f)
        for g in groups:
            if (g[0].data.shape[1:] == f.data.shape[1:]
                    and abs(rate / _charge_per_group(g[0]) - 1) < SAME_ILLUMINATION):
                g.append(f)
                break
        else:
            groups.append([f])
    return groups


def _charge_per_group(f):
    d = f.data
    return float(np.nanmedian(d[:, -1] - d[:, 0]) / max(d.shape[1] - 1, 1))


def _no_shot_noise(data, mask, read_noise):
    """Why flat ramps (e-) hold no shot noise to measure (the increments'
    variance across pixels within twice the read noise squared), else None:
    a noiseless or saturated flat, refused before the covariance fit."""
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-masked group
        var, mean = stream.increment_variances(data, mask)
    floor = 2.0 * float(read_noise or 0.0) ** 2 + 1e-9 * float(mean or 0.0) ** 2
    largest = float(np.nanmax(var)) if np.isfinite(var).any() else 0.0
    if largest <= floor:
        return (f"no shot noise left (the increments' variance {largest:.3g} e-^2 <= twice "
                "the read noise squared): saturated or not a flat")
    return None


def _measured(label, flat_ramps, read_noise):
    """The joint fit of one illumination's flat ramps; a fit that cannot start
    or finish (SciPy's ValueError) refused in one line naming the files."""
    try:
        return flat_ramps.measure(read_noise=read_noise)
    except IPCInputError:
        raise
    except ValueError as exc:
        raise IPCInputError(f"{label}: the flat ramps' covariance fit failed ({exc}); are "
                            "they flats of a detector (shot noise, IPC)?") from None


def _measure_frames(flat_files, read_noise, not_measured, stripes=None):
    """Flats of frames at one level: one row per file (:func:`.flats.measure_level`);
    ``stripes=(folds, k)`` keeps the horizontal stripes ``y * k // ny`` in ``folds``."""
    rows = []
    for f in flat_files:
        stack = f.data.reshape((-1,) + f.shape2d)
        mask = f.mask.reshape(stack.shape)
        if stripes is not None:
            folds, k = stripes
            ny = stack.shape[-2]
            keep = np.isin(np.arange(ny) * k // ny, list(folds))
            mask = mask | ~keep[None, :, None]
        if stack.shape[0] < 2:
            not_measured.append(f"{f.label}: one frame only; a level needs >= 2 frames to "
                                "cancel the fixed pattern")
            continue
        try:
            row = flatmod.measure_level(stack, mask, read_noise,
                                        saturation=f.meta.get("saturation"))
        except IPCInputError as exc:
            not_measured.append(f"{f.label}: {exc}")
            continue
        row["file"] = f.path
        row["source"] = "flat frames"
        if row.get("terms") is None:
            not_measured.append(f"{f.label}: level {row['level']:.4g} e-: {row['problem']}")
        rows.append(row)
    return rows


def _combine_kernels(measured):
    """The brighter-fatter kernels of several ramp sets, weighted by their errors."""
    kernels = [(np.array(m["brighter_fatter"]["kernel"]),
                np.array(m["brighter_fatter"]["kernel_error"]))
               for _, m in measured if m["brighter_fatter"].get("measured")]
    if not kernels:
        return None, None
    w = np.array([1.0 / np.maximum(e, 1e-30) ** 2 for _, e in kernels])
    k = np.array([k for k, _ in kernels])
    return (w * k).sum(axis=0) / w.sum(axis=0), 1.0 / np.sqrt(w.sum(axis=0))


def _effects(flats, hot, gain_given):
    """The report's ``gain``, ``classical_nonlinearity``, ``brighter_fatter``
    and the flat ramps' evidence on non-linear IPC."""
    out = {"gain": {"given": gain_given["given"], "used": gain_given["value"],
                    "source": gain_given["source"], "measured": None, "error": None},
           "classical_nonlinearity": {"measured": False, "detected": False, "beta": None,
                                      "error": None, "significance": None,
                                      "form": "M = Q - beta Q^2 (Q collected, M measured, e-)"},
           "brighter_fatter": {"measured": False, "detected": False, "significance": None,
                               "kernel": None, "kernel_error": None,
                               "note": "no flat ramps given (hot pixels and flats "
                                       "of one level cannot measure it)"},
           "flat_ramp_nonlinear_ipc": None}
    if flats is None or not flats.measured:
        return out
    label, best = max(flats.measured, key=lambda lm: lm[1].get("n_pixels", 0))
    ratio = best["gain_ratio"]
    base = gain_given["value"] if gain_given["value"] is not None else 1.0
    out["gain"].update(measured=base * ratio["value"], error=base * ratio["error"],
                       ratio=ratio["value"], ratio_error=ratio["error"], file=label)
    out["classical_nonlinearity"] = {**out["classical_nonlinearity"],
                                     **best["classical_nonlinearity"]}
    kernel, err = _combine_kernels(flats.measured)
    bf = dict(best["brighter_fatter"])
    if kernel is not None and len(flats.measured) > 1:
        bf.update(kernel=kernel.tolist(), kernel_error=err.tolist())
    out["brighter_fatter"] = bf
    out["flat_ramp_nonlinear_ipc"] = best["nonlinear_ipc"]
    return out


def _frames_rise_like_bf(flats, hot):
    """Sentence when one-level flats rise while hot pixels stay flat (else None)."""
    if flats is None or flats.sets or len(flats.frame_rows) < 2 or not hot.rows:
        return None
    growth = flatmod.growth_with_signal(flats.frame_rows)
    nearest = [growth[t]["significance"] for t in ("x", "y") if t in growth]
    slope = hot.slope()
    if not nearest or min(nearest) < BF_LIKELY_SIGMA or slope is None:
        return None
    if abs(slope["significance"]) >= BF_LIKELY_SIGMA:
        return None
    return (f"the flats' nearest covariances rise with signal ({nearest[0]:+.1f} sigma along "
            f"x, {nearest[1]:+.1f} along y) while the hot pixels' alpha(S,0) stays flat "
            f"({slope['significance']:+.1f} sigma): the likely cause is brighter-fatter, which "
            "frames at one level cannot separate from IPC; the flats were left out of the "
            "law (give flat ramps to measure both)")


def _gain_used(files, gain):
    """The gain the user gave, the one the inputs were converted with and where
    it came from."""
    for f in files:
        if f.meta.get("gain") is not None:
            return {"given": gain, "value": float(np.mean(f.meta["gain"])),
                    "source": f.meta.get("gain_source")}
    return {"given": gain, "value": None, "source": None}


def calibrate(darks=(), flats=(), reference=None, output=None, *, report_path=None,
              figures=None, gain=None, bunit=None, hdu=None, read_noise=None,
              dq_bits=DEFAULT_DQ_BITS, refpix=None, threshold=30.0, folds=10,
              collection_steps=None, overwrite=False, measure_map=True):
    """Measure a detector's coupling and write its model file.

    Parameters
    ----------
    darks : sequence of str
        Dark products: 2-D frames, 3-D stacks or 4-D ramps (each ramp's hot
        pixels are followed group by group).
    flats : sequence of str
        Flat products: ramps (the main input: a 4-D SCI, or a 3-D cube of
        reads whose mean rises; ramps of one illumination are measured
        together as integrations) or frames at one level (one file per
        level, >= 2 frames each).
    reference : str, optional
        A JWST ``ipc`` (FITS) or Roman IPC (ASDF) reference file.
    output : str, optional
        The model file to write (JSON, see :mod:`ipc_taichi.model`).
    report_path, figures : str, optional
        The report (JSON) and a folder for figures.
    gain : float or str, optional
        e-/DN for inputs in DN (default: each file's GAIN keyword), every
        input's; refused for an input in electrons, as ``decouple`` refuses
        it. A file without BUNIT is taken as DN when a gain is known, else as
        electrons (the product plan's rule, decouple's too; said).
    bunit : str, optional
        Units of the inputs, overriding their BUNIT.
    hdu : optional
        Science HDU of the FITS inputs.
    read_noise : float, optional
        [e-] per read; default: measured on the darks (or by the flat ramps'
        fit), else 0 (said in the report).
    dq_bits, refpix :
        Pixels left out (see :mod:`.inputs`).
    threshold : float
        Hot-pixel detection level in robust standard deviations.
    folds : int
        Folds of the held-out law choice (:func:`.lawfit.choose_law`).
    collection_steps : int, optional
        For SIMULATED flat ramps whose charge is collected in this many
        discrete steps per group (a charge arriving in a step does not steer
        that step: less brighter-fatter within a group than a detector's
        continuous collection, which is the default): see
        :mod:`.ramps`.
    overwrite : bool
    measure_map : bool
        Measure the IPC map across the detector (:mod:`.maps`); it is written
        only when held-out data prefer it to the uniform law.

    Returns
    -------
    dict
        ``model`` (CouplingModel), ``report`` (the report's content), ``output``.
    """
    darks, flats = list(darks or ()), list(flats or ())
    if not darks and not flats and reference is None:
        raise IPCInputError("calibrate needs darks, flats or a reference file")
    for path in (output, report_path):  # fail before measuring
        if path is not None:
            check_output_path(path, overwrite)
    _check_figures_folder(figures)
    options = {"hdu": hdu, "gain": gain, "dq_bits": dq_bits, "refpix": refpix, "bunit": bunit}
    dark_frames = [read_frames(p, role="dark", **options) for p in darks]
    sections = stream.flats_by_sections(flats, hdu)
    flat_frames = [read_frames(p, role="flat", sections=sections, **options) for p in flats]
    not_measured, notes = [], []
    hot = _HotPixels(dark_frames, threshold, not_measured)
    rn = read_noise if read_noise is not None else hot.read_noise
    flat = (_Flats(flat_frames, rn, not_measured, notes, collection_steps) if flat_frames
            else None)
    effects = _effects(flat, hot, _gain_used(dark_frames + flat_frames, gain))
    bf_likely = _frames_rise_like_bf(flat, hot)
    if bf_likely:
        effects["brighter_fatter"].update(likely=True, note=bf_likely)
    use_frames = bf_likely is None
    ref, ref_model = None, None
    if reference is not None:  # with its map, if any (reffiles)
        ref_model, info = reffiles.read_reference_model(reference)
        law_ref, geo_ref = ref_model.law, ref_model.geometry
        ref = {"file": reference, "law": law_ref.describe(), "geometry": geo_ref.describe(),
               "coupling_x": float(law_ref.alpha(1e4, 0.0) * geo_ref.weight(0, 1)),
               "pedigree": reffiles.pedigree_of(reference), **info}

    k = hot.folds(folds)

    def points_for(fold_list):
        return (hot.rows_for(fold_list, k),
                flat.rows_for(fold_list, k, use_frames) if flat else [])

    fit, transfer_check = None, None
    if any(points_for(None)):
        try:
            geometry, law, fit = lawfit.choose_law(points_for, folds=k)
        except ValueError as exc:
            not_measured.append(str(exc))
    if fit is None:
        if ref is None:
            raise IPCInputError("calibrate: nothing could be measured ("
                                + "; ".join(not_measured) + ")")
        law, geometry = law_ref, geo_ref
        fit = {"chosen": "reference file", "law": law.describe(), "assumed": [
            "the reference file's kernels at every signal" if "kept" not in info["kind"]
            else "the model kept in the reference file"]}
    elif hot.integrations:
        transfer_check = transfer.held_out_residuals(
            hot.integrations, hot.events, hot.bins, points_for(None)[1], fit["chosen"],
            min_signal=hot.floors["score"], bin_floor=hot.floors["bins"])
        law, geometry = verdicts.constant_unless_better(fit, transfer_check, points_for, law,
                                                        geometry)
    verdicts.say_why_empty(transfer_check, hot, darks, not_measured)
    bond_map, tested = _map_and_assumptions(dark_frames, flat_frames, hot, flat, law, geometry,
                                            rn, effects, measure_map)
    model = (ref_model if fit["chosen"] == "reference file"
             else CouplingModel.resolve(law, geometry, "zero",
                                        bonds=bond_map["bonds"] if bond_map else None))
    nl_ipc = verdicts.nonlinear_ipc(fit, effects.pop("flat_ramp_nonlinear_ipc"), transfer_check)
    inputs = records.Inputs(tuple(dark_frames), tuple(flat_frames), reference, read_noise,
                            hot.read_noise, rn)
    outcome = records.Outcome(hot, flat, effects, nl_ipc, fit, transfer_check, bond_map, tested,
                              ref, not_measured, notes)
    provenance = inputs.provenance(effects["gain"])
    document = records.assemble(inputs, outcome, model, provenance)
    if output is not None:
        model.save(output, provenance=provenance, fit=report.json_ready(outcome.summary()),
                   overwrite=overwrite, sections=report.json_ready(outcome.sections()))
    if report_path is not None:
        report.write_report(document, report_path, overwrite=overwrite)
    if figures is not None:
        document["figures"] = report.write_figures(figures, document, law, geometry)
    return {"model": model, "report": document, "output": output}


def _check_figures_folder(folder):
    """``--figures``: a folder, or a name for one; anything else refused
    before the work (not after it, with the model already written)."""
    if folder is None:
        return
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise IPCInputError(f"--figures {folder}: exists and is not a folder; name a folder "
                            "for the figures")
    parent = os.path.abspath(folder)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent) or not os.access(parent, os.W_OK | os.X_OK):
        raise IPCInputError(f"--figures {folder}: cannot be written ({parent} is not a "
                            "writable folder)")




def _map_and_assumptions(dark_frames, flat_frames, hot, flat, law, geometry, rn, effects,
                         measure_map):
    """The IPC map (:mod:`.maps`, None when not asked or nothing can measure
    it) and the two assumptions tested (:mod:`.assumptions`)."""
    bond_map = None
    if measure_map and (hot.events is not None or flat is not None):
        bond_map = maps.measure_map(dark_frames, flat_frames, hot, law, geometry, rn)
    levels = [r["level"] for r in flat.rows if r.get("terms")] if flat else []
    tested = [assumptions.read_noise_correlation(
                  bond_map.pop("read_cov", None) if bond_map else None, levels,
                  float(law.alpha(1e4, 1e4))),
              assumptions.hot_pixel_brighter_fatter(hot.slope(), effects["brighter_fatter"])]
    return bond_map, tested

"""``calibrate``: darks, flats and reference files in; a coupling-model file out.

The steps are those of a detector laboratory: hot pixels in the darks give
alpha(S, 0) per direction (:mod:`.hotpixels`), flats give alpha(S, S) per axis
(:mod:`.flats`), a law symmetric in its two arguments is fitted to both
(:mod:`.lawfit`), and the model (law, geometry, edge, provenance, fit quality)
is written with :meth:`ipc_taichi.model.CouplingModel.save`; the report
(:mod:`.report`) says what was measured, what was assumed and what could not
be measured. A reference file (:mod:`.reffiles`) alone gives a constant law;
with measurements it is reported beside them for comparison.
"""

import datetime

import numpy as np

from .. import __version__
from ..errors import IPCInputError
from ..fitsio import check_output_path
from ..model import CouplingModel
from . import flats as flatmod
from . import hotpixels, lawfit, reffiles, report
from .inputs import DEFAULT_DQ_BITS, read_frames

__all__ = ["calibrate"]


def _check_shapes(inputs):
    shapes = {f.path: f.shape2d for f in inputs}
    if len(set(shapes.values())) > 1:
        listing = ", ".join(f"{p} {s[0]}x{s[1]}" for p, s in shapes.items())
        raise IPCInputError(f"inputs of different frame shapes: {listing}")


def _measure_darks(darks, threshold, not_measured):
    events, read_noise, found = [], [], 0
    for f in darks:
        for i, integ in enumerate(f.data):
            last = integ[-1]
            positions = hotpixels.find_hot_pixels(last, f.mask[i, -1], threshold=threshold)
            found += len(positions)
            if len(positions):
                events.append(hotpixels.measure_events(integ, positions, f.mask[i]))
            rn = hotpixels.read_noise_from_darks(integ, f.mask[i])
            if rn is not None:
                read_noise.append(rn)
    rows = []
    if events:
        merged = {k: np.concatenate([e[k] for e in events]) for k in events[0]}
        rows = hotpixels.summarise_events(merged)
    if darks and not rows:
        not_measured.append("alpha(S,0): no isolated hot pixel in the darks "
                            f"(threshold {threshold:g} sigma; {found} candidates)")
    return rows, (float(np.median(read_noise)) if read_noise else None), found


def _measure_flats(flat_files, read_noise, not_measured):
    rows = []
    for f in flat_files:
        stack = f.data.reshape((-1,) + f.shape2d)
        mask = f.mask.reshape(stack.shape)
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
        if row.get("terms") is None:
            not_measured.append(f"{f.label}: level {row['level']:.4g} e-: {row['problem']}")
        rows.append(row)
    usable = [r for r in rows if r.get("terms")]
    if flat_files and len(usable) == 1:
        not_measured.append("alpha(S,S) at one level only: its change with signal is not "
                            "measured (held constant)")
    if flat_files and not usable:
        not_measured.append("alpha(S,S): no usable flat level")
    return rows


def calibrate(darks=(), flats=(), reference=None, output=None, *, report_path=None,
              figures=None, gain=None, hdu=None, read_noise=None, dq_bits=DEFAULT_DQ_BITS,
              refpix=None, threshold=30.0, overwrite=False):
    """Measure a detector's coupling and write its model file.

    Parameters
    ----------
    darks : sequence of str
        Dark products: 2-D frames, 3-D stacks or 4-D ramps (each ramp's hot
        pixels are followed group by group).
    flats : sequence of str
        Flat products, one file per illumination level (>= 2 frames each).
    reference : str, optional
        A JWST ``ipc`` (FITS) or Roman IPC (ASDF) reference file.
    output : str, optional
        The model file to write (JSON, see :mod:`ipc_taichi.model`).
    report_path, figures : str, optional
        The report (JSON) and a folder for figures.
    gain : float or str, optional
        e-/DN for inputs in DN (default: each file's GAIN keyword).
    hdu : optional
        Science HDU of the FITS inputs.
    read_noise : float, optional
        [e-] per read; default: measured on the darks, else 0 (said in the report).
    dq_bits, refpix :
        Pixels left out (see :mod:`.inputs`).
    threshold : float
        Hot-pixel detection level in robust standard deviations.
    overwrite : bool

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
    dark_frames = [read_frames(p, hdu, gain, dq_bits, refpix) for p in darks]
    flat_frames = [read_frames(p, hdu, gain, dq_bits, refpix) for p in flats]
    _check_shapes(dark_frames + flat_frames)
    not_measured = []
    hot_rows, rn_darks, found = _measure_darks(dark_frames, threshold, not_measured)
    rn = read_noise if read_noise is not None else rn_darks
    flat_rows = _measure_flats(flat_frames, rn, not_measured)
    growth = flatmod.growth_with_signal(flat_rows)
    ref = None
    if reference is not None:
        law_ref, geo_ref, info = reffiles.read_reference(reference)
        ref = {"file": reference, "law": law_ref.describe(), "geometry": geo_ref.describe(),
               **info}
    fit = None
    if hot_rows or any(r.get("terms") for r in flat_rows):
        try:
            geometry, law, fit = lawfit.fit_law(hot_rows, flat_rows)
        except ValueError as exc:
            not_measured.append(str(exc))
    if fit is None:
        if ref is None:
            raise IPCInputError("calibrate: nothing could be measured ("
                                + "; ".join(not_measured) + ")")
        law, geometry = law_ref, geo_ref
        fit = {"chosen": "reference file", "law": law.describe(), "assumed": [
            "the reference file's constant kernel (no signal dependence)"]}
    model = CouplingModel.resolve(law, geometry, "zero")
    provenance = {"software": f"ipc_taichi {__version__}", "command": "calibrate",
                  "date": datetime.datetime.now(datetime.UTC).isoformat(
                      timespec="seconds"),
                  "darks": [f.label for f in dark_frames], "flats": [f.label for f in flat_frames],
                  "reference": reference,
                  "units": sorted({f.units for f in dark_frames + flat_frames}),
                  "gain": gain, "read_noise_e": rn,
                  "read_noise_source": ("given" if read_noise is not None else
                                        "darks" if rn_darks is not None else "unknown (0)")}
    summary = {k: fit.get(k) for k in ("chosen", "law", "weights", "weight_errors", "assumed",
                                       "notes", "chi2_per_point", "n_points")}
    if "forms" in fit:
        summary["bic"] = {k: v.get("bic") for k, v in fit["forms"].items()}
    summary["not_measured"] = not_measured
    document = {"provenance": provenance, "model": model.describe(), "fit": fit,
                "hot_pixels": {"found": found, "bins": hot_rows},
                "flats": {"levels": [{k: v for k, v in r.items()} for r in flat_rows],
                          "growth_with_signal": growth},
                "reference": ref, "not_measured": not_measured}
    if output is not None:
        model.save(output, provenance=provenance, fit=report.json_ready(summary),
                   overwrite=overwrite)
    if report_path is not None:
        report.write_report(document, report_path, overwrite=overwrite)
    if figures is not None:
        document["figures"] = report.write_figures(figures, hot_rows, flat_rows, law, geometry)
    return {"model": model, "report": document, "output": output}

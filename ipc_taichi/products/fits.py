"""FITS products in, the same products out.

:func:`process_fits` couples or decouples the science arrays of a FITS
product and changes nothing else:

- every science read is corrected: each ``SCI`` HDU of a multi-read product
  (a WFC3/IR ``_ima``: one per read, each with its own ``SAMPTIME``), or the
  one ``--hdu`` names;
- every other HDU is copied byte for byte (ERR, DQ, VAR_*, SAMP, TIME, the
  ASDF extension, tables), so nothing is lost and nothing is rescaled;
- every header keyword is kept; each science HDU keeps its dtype (float32
  stays float32; integer data become float64 unless ``output_dtype`` says
  otherwise), its scaling keywords (BZERO/BSCALE/BLANK) are dropped since the
  result is stored unscaled, and CHECKSUM/DATASUM of the changed headers are
  dropped since they no longer hold; a tile-compressed science HDU is written
  uncompressed;
- the headers record what was done (:mod:`ipc_taichi.products.provenance`),
  ``S_IPC`` last, after the work;
- the output is written at a temporary path beside the target, allocated in
  full before any pixel is written, and renamed into place when complete; an
  error (a full disk included), SIGINT or SIGTERM removes it.

Which pixels take part and in which units follows
:mod:`ipc_taichi.products.conventions`; the observatory's conventions come
from :mod:`ipc_taichi.products.missions`. With ``tile`` the science array is
read and written tile by tile (:mod:`ipc_taichi.products.streams`).

The noise arrays beside each science HDU (``ERR``, ``VAR_POISSON``,
``VAR_RNOISE``, ``VAR_FLAT`` of the same ``EXTVER`` and shape) are, when
decoupling, replaced by their values after the decoupler
(:func:`ipc_taichi.noise.propagate_noise`, frame by frame, with the region,
model, mask, scale and pedestal of the correction), in their own dtype and
HDU; ``IPCNOISE`` and a HISTORY line say so. ``couple``, ``--keep-noise`` and
``--tile`` leave them as they came and say that instead
(:func:`ipc_taichi.products.noise_arrays.noise_of`).
"""

import os
import warnings

import numpy as np

from .. import runtime
from ..errors import IPCInputError
from ..fitsio import atomic_output, check_output_path, parse_hdu
from . import conventions as cv
from . import missions, streams
from .correction import RunSettings
from .fitsfile import (
    flag_hdus,
    hdu_label,
    is_compressed,
    keyword,
    noise_hdus,
    open_fits,
    read_array,
    science_header,
    science_indices,
    shape_of,
    write_skeleton,
)
from .noise_arrays import NOISE_ARRAYS, noise_of
from .options import ProductOptions, precision_for, resolve_model
from .pages import OutputPages
from .plan import ArrayFacts, Zeroth, plan_product, units_in
from .provenance import Provenance

__all__ = ["process_fits", "array_facts"]


def _check_paths(input_path, output_path, settings, options):
    if settings.tile and settings.operation != "decouple":
        raise IPCInputError("--tile is for decouple")
    check_output_path(output_path, options.overwrite)  # fail before computing
    if os.path.exists(output_path) and os.path.exists(input_path) and \
            os.path.samefile(input_path, output_path):
        raise IPCInputError(f"{output_path}: is the input; write to another file")
    if str(output_path).lower().endswith((".gz", ".fz", ".bz2", ".zip")):
        raise IPCInputError(f"{output_path}: the output is written uncompressed; name it .fits")


def _warn_if_corrected(hdul, index, label):
    """A science HDU whose IPC was already corrected would be corrected twice."""
    primary, own = hdul[0].header, hdul[index].header
    done = str(primary.get("S_IPC", "")).strip().upper() == "COMPLETE"
    if own.get("IPCOP") == "decouple" or (done and "IPCOP" in primary
                                           and "IPCNHDU" not in primary):
        by = "by ipc_taichi"
    elif done and "IPCOP" not in primary:
        by = "(S_IPC = 'COMPLETE', e.g. by the JWST ipc step)"
    else:
        return
    warnings.warn(f"{label}: IPC was already corrected {by}; correcting again",
                  cv.ProductWarning, stacklevel=3)


def _zeroth_read(hdul):
    """The index of a multi-read product's zeroth read (the ``SCI`` HDU with
    ``SAMPTIME = 0``), or None."""
    sci = [k for k, h in enumerate(hdul) if (h.name or "").upper() == "SCI"]
    if len(sci) < 2:
        return None
    zero = [k for k in sci if hdul[k].header.get("SAMPTIME") is not None
            and float(hdul[k].header["SAMPTIME"]) == 0.0]
    return zero[0] if len(zero) == 1 else None


def _facts(path, hdul, index, label, flags, zeroth):
    """What HDU ``index`` says about itself (:class:`~ipc_taichi.products.plan.ArrayFacts`);
    ``flags``: the indices of its bit-flag HDUs."""
    shape = shape_of(hdul[index].header)

    def own(key, h=hdul[index].header):
        return h[key] if key in h and h[key] not in (None, "") else None

    def product(key, h=hdul[0].header):
        return h[key] if key in h and h[key] not in (None, "") else None

    def reference():
        if not flags:
            return None
        source = min(flags, key=lambda k: hdul[k].header["NAXIS"])
        first = np.asarray(read_array(path, hdul, source)).reshape((-1,) + shape[-2:])[0]
        return (first.astype(np.int64) & cv.REFERENCE_PIXEL) != 0

    return ArrayFacts(index, hdu_label(hdul, index), label, shape, own, product, reference,
                      zeroth=index == zeroth)


def array_facts(path, hdul, index, label):
    """The :class:`~ipc_taichi.products.plan.ArrayFacts` of one science HDU
    (calibrate's reader asks the plan with it)."""
    shape = shape_of(hdul[index].header)
    return _facts(path, hdul, index, label, flag_hdus(hdul, index, shape, path), None)


def _output_dtype(bitpix, output_dtype):
    """The input's float dtype, float64 for integer data, or ``output_dtype``."""
    if output_dtype in (None, "same"):
        return {-32: np.dtype(np.float32)}.get(bitpix, np.dtype(np.float64))
    out = np.dtype(output_dtype)
    if out not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise IPCInputError(f"--output-dtype {output_dtype}: give float32 or float64")
    return out


def _plan(input_path, hdul, model, options, operation="decouple"):
    """Everything decided before the work (:func:`~ipc_taichi.products.plan.plan_product`),
    with what FITS adds: each science HDU's flag HDUs and output dtype, and its
    noise HDUs (``index -> {name: HDU index}``, empty when they are left as
    they came; those propagated get an output dtype too) and the record's text."""
    sciences = science_indices(input_path, hdul, parse_hdu(options.hdu))
    mission = missions.recognise(hdul[0].header, hdul[sciences[0][0]].header, hdul)
    zeroth = _zeroth_read(hdul)
    flags, dtypes, facts = {}, {}, []
    for index, label in sciences:
        header = hdul[index].header
        flags[index] = flag_hdus(hdul, index, shape_of(header), input_path)
        dtypes[index] = _output_dtype(header["BITPIX"], options.output_dtype)
        facts.append(_facts(input_path, hdul, index, label, flags[index], zeroth))
    first = None
    if zeroth is not None:
        first = Zeroth(f"zeroth read, HDU {zeroth} {hdu_label(hdul, zeroth)}",
                       shape_of(hdul[zeroth].header)[-2:],
                       lambda gain: _zeroth_charge(input_path, hdul, zeroth, gain, options))
    all_sci = [k for k, hh in enumerate(hdul) if (hh.name or "").upper() == "SCI"]
    dq_where = next((f"{input_path}[{hdu_label(hdul, k)}]" for k, h in enumerate(hdul)
                     if (h.name or "").upper() == "DQ_DEF"), None)
    plan = plan_product(facts, mission, model, options, dq_where=dq_where, zeroth=first,
                        complete=set(all_sci) <= {i for i, _ in sciences})
    for index, label in sciences:
        _warn_if_corrected(hdul, index, label)
    noise = {index: noise_hdus(hdul, index, shape_of(hdul[index].header), NOISE_ARRAYS)
             for index, _ in sciences}
    found = [n for n in NOISE_ARRAYS if any(n in v for v in noise.values())]
    where = next((f"{input_path}[{hdu_label(hdul, k)}]" for v in noise.values()
                  for k in v.values()), input_path)
    propagate, noise_text = noise_of(operation, options, found, where)
    noise = {index: (v if propagate else {}) for index, v in noise.items()}
    for v in noise.values():
        dtypes.update({k: np.dtype(np.float32 if hdul[k].header["BITPIX"] == -32
                                   else np.float64) for k in v.values()})
    return plan, flags, dtypes, noise, noise_text


def _zeroth_charge(path, hdul, zeroth, gain, options):
    """The zeroth read in electrons (its data times the gain, when in DN)."""
    label = f"{path}[{hdu_label(hdul, zeroth)}]"
    units = units_in(options.bunit if options.bunit is not None
                     else keyword(hdul, zeroth, "BUNIT"), gain is not None, label)
    units = cv.Units(units.kind.replace("_rate", ""), units.text)
    scale, _ = cv.charge_scale(units, gain, None, label)
    charge = np.asarray(read_array(path, hdul, zeroth), dtype=np.float64) * scale
    return np.where(np.isfinite(charge), charge, 0.0)


def process_fits(input_path, output_path, operation="decouple", *, model=None, options=None,
                 **kwargs):
    """Couple or decouple the science arrays of a FITS product into ``output_path``.

    Parameters
    ----------
    input_path, output_path : str
    operation : {"couple", "decouple"}
    model : CouplingModel, str or path, optional
        The coupling model. None: the paper's law, refused on a JWST, HST or
        Roman product (:func:`ipc_taichi.products.missions.check_model_chosen`).
    options : ProductOptions or dict, optional
        How the product is read and written; ``kwargs`` override its fields.

    Returns
    -------
    dict
        ``output``, ``label``, ``frames``, ``iterations`` (max over frames),
        ``converged`` (all frames; ``None`` for couple or ``tol = 0``), ``infos``,
    ``hdus`` (labels of the science HDUs changed), ``law`` and ``edge`` (the
    law's name and the edge rule of the first), ``masked_unphysical``
    (unflagged pixels masked as unphysical, all HDUs: ``IPCNBAD``).
    """
    options = ProductOptions.from_kwargs(options, **kwargs)
    model, options = resolve_model(model, options)
    settings = RunSettings.of(options, operation)
    _check_paths(input_path, output_path, settings, options)
    hdul = open_fits(input_path, memmap=True)
    with hdul:
        plan, flags, dtypes, noise, noise_text = _plan(input_path, hdul, model, options,
                                                       operation)
        if options.precision == "auto":  # the science arrays' own precision
            options = options.replace(precision=precision_for("auto", [
                np.float32 if hdul[p.index].header["BITPIX"] == -32 else np.float64
                for p in plan.arrays]))
            settings = RunSettings.of(options, operation)
        if settings.tile:
            for k in [p.index for p in plan.arrays] + [f for p in plan.arrays
                                                        for f in flags[p.index]]:
                if is_compressed(hdul[k]):
                    raise IPCInputError(
                        f"{input_path}[{hdu_label(hdul, k)}]: tile-compressed; --tile reads "
                        "pixels through memory maps: run without --tile, or decompress the "
                        "file first (funpack)")
        prov = Provenance(plan, settings, runtime.init(options.arch, options.precision),
                          noise_text)

        def headers():
            out = {}
            for p in plan.arrays:
                out[p.index] = prov.science(p.index, science_header(
                    hdul[p.index].header, dtypes[p.index]))
                for k in noise[p.index].values():
                    out[k] = science_header(hdul[k].header, dtypes[k])
            out[0] = prov.primary(out[0] if 0 in out else hdul[0].header.copy())
            return out

        with atomic_output(output_path, options.overwrite) as tmp:
            places = _write(output_path, lambda: write_skeleton(
                tmp, input_path, hdul, headers(), dtypes))
            for p in plan.arrays:  # the per-HDU work of the plan
                out = OutputPages(tmp, dtypes[p.index], places[p.index][2], p.shape)
                record = cv.Unphysical(settings.unphysical)
                done = False
                try:
                    prov.infos[p.index] = _correct(
                        input_path, hdul, p, streams.Flags(
                            input_path, hdul, flags[p.index], plan.bits, p, options.saturation,
                            settings.tile), out, settings, record,
                        _Noise(input_path, hdul, tmp, places, dtypes, noise[p.index], p))
                    prov.unphysical[p.index] = record.masked
                    done = True
                finally:
                    out.close(sync=done)
            _write(output_path, lambda: _rewrite_headers(tmp, places, headers(), output_path))
    return prov.summary(output_path)


def _correct(input_path, hdul, plan, flags, out, settings, record, noise):
    """Correct one science HDU of the plan (its :class:`~ipc_taichi.products.plan.ArrayPlan`;
    ``flags``: its :class:`~ipc_taichi.products.streams.Flags`) and its noise HDUs
    (a :class:`_Noise`), whole or tile by tile, into ``out`` (its
    :class:`~ipc_taichi.products.pages.OutputPages`)."""
    if settings.tile:
        return streams.tiled(input_path, hdul, plan, out.array, flags, settings, record,
                             written=out.written)
    arrays = noise.read()
    infos = streams.whole(input_path, hdul, plan, out.array, flags, settings, record, arrays,
                          written=out.written)
    noise.write(arrays)
    return infos


class _Noise:
    """The noise HDUs of one science HDU: read (float64, in the contiguous
    image) before its correction, written into the output after."""

    def __init__(self, path, hdul, tmp, places, dtypes, indices, plan):
        self.path, self.hdul, self.tmp = path, hdul, tmp
        self.places, self.dtypes, self.indices, self.plan = places, dtypes, indices, plan

    def read(self):
        science = self.plan.arrangement.to_science
        return {name: np.array(science(read_array(self.path, self.hdul, k)), dtype=np.float64)
                for name, k in self.indices.items()}

    def write(self, arrays):
        for name, k in self.indices.items():
            dtype = self.dtypes[k]
            out = np.memmap(self.tmp, dtype=dtype.newbyteorder(">"), mode="r+",
                            offset=self.places[k][2], shape=self.plan.shape)
            try:
                out[...] = self.plan.arrangement.from_science(
                    arrays[name].astype(dtype), np.asarray(read_array(self.path, self.hdul, k)))
                out.flush()
            finally:
                del out


def _rewrite_headers(tmp, places, headers, output_path):
    """The final headers, in place (the same cards, so the same size)."""
    with open(tmp, "r+b") as f:
        for index, header in headers.items():
            start, length, _ = places[index]
            with warnings.catch_warnings():  # its cards were verified (and reported) above
                warnings.simplefilter("ignore")
                text = header.tostring().encode("ascii")
            if len(text) != length:  # the same cards: cannot happen
                raise RuntimeError(f"{output_path}: provenance header changed size")
            f.seek(start)
            f.write(text)


def _write(output_path, action):
    """Run a write; a full disk or another OS error becomes one line naming the
    user's output (the temporary file is removed by ``atomic_output``)."""
    try:
        return action()
    except OSError as exc:
        raise IPCInputError(f"{output_path}: cannot be written "
                            f"({exc.strerror or type(exc).__name__})") from None

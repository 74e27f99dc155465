"""One entry point for any product file: FITS or Roman ASDF, by its content."""

import time
import warnings

from ..model import CouplingModel
from .checks import check_input_file
from .fits import process_fits
from .missions import is_asdf
from .options import ProductOptions
from .roman import process_asdf

__all__ = ["process_product", "decouple_file", "couple_file", "written_by_ipc_taichi",
           "SUMMARY_KEYS"]

SUMMARY_KEYS = ("iterations", "converged", "frames", "hdus", "law", "edge", "masked_unphysical",
                "seconds")
"""What :func:`decouple_file` returns (small, picklable: it comes back from Dask workers)."""


def process_product(input_path, output_path, operation="decouple", model=None, options=None,
                    **kwargs):
    """Couple or decouple a product file: Roman ASDF
    (:func:`~ipc_taichi.products.roman.process_asdf`) or FITS
    (:func:`~ipc_taichi.products.fits.process_fits`); same options
    (:class:`~ipc_taichi.products.options.ProductOptions`), same summary, with
    ``seconds`` (wall-clock time of the whole call, reading and writing included)."""
    check_input_file(input_path)  # before its first bytes are read
    run = process_asdf if is_asdf(input_path) else process_fits
    start = time.perf_counter()
    summary = run(input_path, output_path, operation, model=model,
                  options=ProductOptions.from_kwargs(options, **kwargs))
    summary["seconds"] = time.perf_counter() - start
    return summary


def decouple_file(input_path, output_path, law=None, geometry=None, edge=None, model=None,
                  options=None, **kwargs):
    """Decouple one product file; the per-file task of
    :func:`ipc_taichi.cluster.decouple_files`. The model is ``model`` (a
    CouplingModel or a model file) or ``law``/``geometry``/``edge``; giving
    both is refused, as :func:`ipc_taichi.decouple` does; giving neither means
    the paper's law (refused on instrument products). Returns a small
    picklable summary: ``iterations``, ``converged``, ``frames``, ``hdus``
    (the science HDUs changed), ``law``, ``edge`` (the law's name and the edge
    rule applied), ``masked_unphysical`` (unflagged pixels masked as
    unphysical) and ``seconds``."""
    if model is not None:  # a model or its file; law/geometry/edge beside it are refused
        model = CouplingModel.resolve(law, geometry, edge, model=model)
    elif law is not None:
        model = CouplingModel.resolve(law, geometry, edge or "zero")
        if edge is not None:  # asked for: the frame decides what it gets (plan.edge_of)
            options = ProductOptions.from_kwargs(options, edge=edge)
    elif (geometry, edge) != (None, None):
        raise ValueError("decouple_file: geometry= and edge= need law= (or give model=)")
    res = process_product(input_path, output_path, "decouple", model=model, options=options,
                          **kwargs)
    return {key: res[key] for key in SUMMARY_KEYS}


def couple_file(input_path, output_path, model=None, options=None, **kwargs):
    """Couple one product file (:func:`process_product` with ``operation="couple"``)."""
    return process_product(input_path, output_path, "couple", model=model, options=options,
                           **kwargs)


def written_by_ipc_taichi(path, operation=None):
    """Whether ``path`` is a product this tool wrote: a FITS file whose primary
    header has ``IPCOP``, or an ASDF file with ``meta.ipc_taichi`` (and, given
    ``operation``, whether that operation is ``"couple"``/``"decouple"``)."""
    from astropy.io import fits

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if is_asdf(path):
                import asdf

                with asdf.open(path, lazy_load=True, memmap=False) as af:
                    meta = af.tree.get("roman", {}).get("meta", {})
                    record = meta.get("ipc_taichi")
                    return record is not None and (
                        operation is None or record.get("operation") == operation)
            header = fits.getheader(path, 0)
            return "IPCOP" in header and operation in (None, header["IPCOP"])
    except Exception:
        return False

"""One entry point for any product file: FITS or Roman ASDF, by its content."""

from ..model import CouplingModel
from .fits import process_fits
from .roman import is_asdf, process_asdf

__all__ = ["process_product", "decouple_file", "couple_file"]


def process_product(input_path, output_path, operation="decouple", **options):
    """Couple or decouple a product file: Roman ASDF
    (:func:`~ipc_taichi.products.roman.process_asdf`) or FITS
    (:func:`~ipc_taichi.products.fits.process_fits`); same options, same summary."""
    run = process_asdf if is_asdf(input_path) else process_fits
    return run(input_path, output_path, operation, **options)


def decouple_file(input_path, output_path, law="donlon2018", geometry=None, edge="zero",
                  model=None, **options):
    """Decouple one product file; the per-file task of
    :func:`ipc_taichi.cluster.decouple_files`. The model is ``model`` or
    ``law``/``geometry``/``edge``. Returns a small picklable summary
    ``{"iterations", "converged", "frames"}``."""
    model = CouplingModel.resolve(model) if model is not None else \
        CouplingModel.resolve(law, geometry, edge)
    res = process_product(input_path, output_path, "decouple", model=model, **options)
    return {"iterations": res["iterations"], "converged": res["converged"],
            "frames": res["frames"]}


def couple_file(input_path, output_path, model=None, **options):
    """Couple one product file (:func:`process_product` with ``operation="couple"``)."""
    return process_product(input_path, output_path, "couple", model=model, **options)

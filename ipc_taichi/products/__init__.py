"""The product pipeline: detector products in, the same products out.

The layer between the command line and the arrays (like the JWST pipeline's
split between a Step that does I/O and a pure correction function):

- :mod:`ipc_taichi.products.options`: :class:`ProductOptions`, the options
  of a run as one value;
- :mod:`ipc_taichi.products.missions`: what kind of product a file is, and
  its observatory's conventions (reference borders, DQ names, time keywords);
- :mod:`ipc_taichi.products.plan`: everything decided about a product
  before any pixel changes (units, gain, DQ bits, reference pixels, edge,
  pedestal, coadds), once, for FITS, ASDF, the Step and calibrate;
- :mod:`ipc_taichi.products.provenance`: what a product records (IPC
  keywords, HISTORY, ``S_IPC``);
- :mod:`ipc_taichi.products.conventions`: which pixels take part (DQ,
  reference pixels, NaN) and in which units (BUNIT, gain, integration time);
- :mod:`ipc_taichi.products.correction`:
  :func:`~ipc_taichi.products.correction.correct_frames`, the pure
  correction applied to the science array of every product, given the
  array's plan and the run's settings
  (:class:`~ipc_taichi.products.correction.RunSettings`);
- :mod:`ipc_taichi.products.noise_arrays`: the ``ERR``/``VAR_*`` arrays
  beside a science array, and whether a run propagates them;
- :mod:`ipc_taichi.products.fits`: FITS products (JWST rate, rateints, ramp,
  HST MULTIACCUM, plain images and cubes), orchestrated over
  :mod:`~ipc_taichi.products.fitsfile` (bytes, checks, the output skeleton)
  and :mod:`~ipc_taichi.products.streams` (whole or tiled);
- :mod:`ipc_taichi.products.gain`: the gain of a product;
- :mod:`ipc_taichi.products.roman`: Roman ASDF products (``ipc_taichi[roman]``);
- :mod:`ipc_taichi.products.files`: one entry point for either, by content;
- :mod:`ipc_taichi.products.jwst_step`: an ``stpipe`` Step for
  ``calwebb_detector1`` (``ipc_taichi[jwst]``).

Used by the command line (:mod:`ipc_taichi.cli`) and the Dask cluster
(:mod:`ipc_taichi.cluster`); it imports neither.
"""

from .conventions import parse_dq_bits, parse_units
from .correction import FramePlan, RunSettings, correct_frames
from .files import couple_file, decouple_file, process_product, written_by_ipc_taichi
from .fits import process_fits
from .options import ProductOptions
from .roman import process_asdf

__all__ = ["process_product", "process_fits", "process_asdf", "decouple_file", "couple_file",
           "written_by_ipc_taichi", "correct_frames", "FramePlan", "RunSettings",
           "parse_dq_bits", "parse_units", "ProductOptions"]

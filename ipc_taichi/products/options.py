"""The options of a product run, as one value.

:class:`ProductOptions` is what the command line, the Dask workers
(:mod:`ipc_taichi.cluster`) and the library hand to
:func:`ipc_taichi.products.process_product`: frozen and picklable, checked
once when it is built (:meth:`ProductOptions.from_kwargs` refuses an unknown
name in one line).
"""

import dataclasses
import os
from dataclasses import dataclass

from .. import iteration
from ..errors import IPCInputError
from ..model import EDGES, CouplingModel
from ..runtime import PRECISION_ENV
from .checks import check_numbers
from .missions import DEFAULT_DQ

__all__ = ["ProductOptions", "resolve_model", "precision_for", "product_precision",
           "NOISE_CHOICES"]

NOISE_CHOICES = ("propagate", "keep")
"""What is done with the noise arrays beside the science one."""


@dataclass(frozen=True)
class ProductOptions:
    """How a product is read, corrected and written.

    Attributes
    ----------
    hdu : int, str or (str, int), optional
        The science HDU (FITS); default: every ``SCI`` HDU (every read of a
        multi-read product), else the first image HDU with data.
    overwrite : bool
        Replace an existing output.
    max_iter, tol, arch :
        As for :func:`ipc_taichi.decouple`.
    precision : {None, "auto", "f64", "f32"}
        As for :func:`ipc_taichi.decouple` (None: the runtime's), or
        ``"auto"``: each science array in its own precision
        (:func:`precision_for`: f32 for float32 data, else f64), the command
        line's default.
    tile : int, optional
        Decouple tile by tile through memory maps (FITS, decouple only).
    progress : bool or callable
        A progress bar on a terminal: True, a bar of tiles (tiled runs); a
        reporter (:class:`ipc_taichi.progress.TerminalProgress`), that bar and
        each frame of a stack or iteration of a lone frame.
    dq_bits : str or int
        Flags of pixels left out (names of the product's mission, its
        ``DQ_DEF`` first, or integers; default ``DO_NOT_USE,SATURATED``).
    refpix : int, optional
        Width of the reference border; default: the flags, else the
        observatory's convention (:mod:`ipc_taichi.products.missions`).
    gain : float, str or ndarray, optional
        e-/DN: a number or a gain image file (default: the GAIN keyword).
    exptime : float, optional
        Integration time of a rate, seconds (default: the keywords, see
        :data:`ipc_taichi.products.missions.TIME_KEYWORDS`).
    bunit : str, optional
        Override the file's units.
    output_dtype : {None, "float32", "float64"}
    pedestal : str or float, optional
        Charge on the node before the first read, electrons: ``"auto"`` (the
        zeroth read of a multi-read product), ``"none"``, a number or an
        image file.
    coadds : int, optional
        Exposures summed in each frame (default: ``NCOADDS``/``NDIT``, else 1).
    saturation : float, optional
        Pixels at or above this value (data units) are left out like flagged ones.
    unphysical : {"mask", "keep"}
        Unflagged pixels no detector can hold (infinite, or a charge outside
        :data:`ipc_taichi.products.conventions.PHYSICAL_RANGE`): masked (the
        default; counted in ``IPCNBAD``) or kept in the correction (the
        finite ones; ``--keep-unphysical``).
    model_chosen : bool
        The caller chose the law (``--law``/``--model``, or a model passed to
        the library); False: the paper's law by default, refused on instrument
        products.
    edge : {None, "zero", "isolated"}
        The edge rule the caller asks for (``--edge``, the Step's ``edge=``);
        None: none asked. The product's frame decides what it gets
        (:func:`ipc_taichi.products.plan.edge_of`): ``zero`` beside reference
        pixels whatever was asked; else the rule asked for; else
        ``isolated`` for a detector product, the model's rule for a plain
        image.
    noise : {"propagate", "keep"}
        The noise arrays beside the science one (``ERR``, ``VAR_POISSON``,
        ``VAR_RNOISE``, ``VAR_FLAT``; Roman's and the Step's ``err`` and
        ``var_*``): propagated through the linearised decoupler (the default,
        decouple only; :func:`ipc_taichi.products.noise_arrays.noise_of`) or left as
        they came (``--keep-noise``).
    warm_start : bool
        Decouple the groups of a ramp with warm starts (each from the
        previous group's answer plus the new charge; the same stopping rule).
        The groups are streamed one at a time, the warm start carried from
        one to the next (:class:`ipc_taichi.decoupling.WarmCarry`). Off by
        default: on the CPU its passes over each group cost about what the
        iteration it saves costs (``docs/products.md``, Ramps and stacks).
    """

    hdu: object = None
    overwrite: bool = False
    max_iter: int = iteration.MAX_ITER
    tol: float = iteration.TOL
    arch: str = None
    precision: str = None
    tile: int = None
    progress: bool = False
    dq_bits: object = DEFAULT_DQ
    refpix: int = None
    gain: object = None
    exptime: float = None
    bunit: str = None
    output_dtype: str = None
    pedestal: object = "auto"
    coadds: int = None
    saturation: float = None
    unphysical: str = "mask"
    model_chosen: bool = True
    edge: str = None
    noise: str = "propagate"
    warm_start: bool = False

    @classmethod
    def from_kwargs(cls, options=None, **kwargs):
        """``options`` (a ProductOptions, a dict or None) updated by ``kwargs``;
        an unknown name is refused in one line."""
        if isinstance(options, cls):
            base = dataclasses.asdict(options)
        else:
            base = dict(options or {})
        base.update(kwargs)
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(base) - names)
        if unknown:
            raise IPCInputError(f"unknown product option(s): {', '.join(unknown)}")
        if base.get("dq_bits") is None:
            base["dq_bits"] = DEFAULT_DQ
        if base.get("output_dtype") == "same":
            base["output_dtype"] = None
        if base.get("edge") is not None:
            if base["edge"] not in EDGES:
                raise IPCInputError(f"edge must be one of {', '.join(EDGES)}, got "
                                    f"{base['edge']!r}")
        check_numbers(base)
        if base.get("noise", "propagate") not in NOISE_CHOICES:
            raise IPCInputError(f"noise must be one of {', '.join(NOISE_CHOICES)}, got "
                                f"{base['noise']!r}")
        return cls(**base)

    def replace(self, **changes):
        """A copy with ``changes``."""
        return dataclasses.replace(self, **changes)


def precision_for(precision, dtypes):
    """The runtime precision of a run asked for with ``precision`` on data of
    ``dtypes`` (the science arrays' dtypes): ``"auto"`` gives ``"f32"`` when
    every one is float32 (the f32 answer is then exact to the data's own
    precision: ``docs/products.md``, Precision), else ``"f64"``; any other
    value is returned as it is."""
    if precision != "auto":
        return precision
    import numpy as np

    dtypes = [np.dtype(d) for d in dtypes]  # either byte order
    return "f32" if all(d.kind == "f" and d.itemsize == 4 for d in dtypes) else "f64"


def product_precision(asked):
    """The precision a product command (``ipc-taichi couple|decouple``) runs
    with: ``asked`` (``--precision``), else ``$IPC_TAICHI_PRECISION`` (None:
    the runtime reads it), else ``"auto"``."""
    if asked is not None or os.environ.get(PRECISION_ENV):
        return asked
    return "auto"


def resolve_model(model, options):
    """The coupling model of a run and the options saying whether the caller
    chose it: with no model, the paper's law, not counted as chosen (an
    instrument product then refuses it)."""
    if model is None:
        return CouplingModel.resolve(), options.replace(model_chosen=False)
    return CouplingModel.resolve(model=model), options

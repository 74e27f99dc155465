"""Signal-dependent IPC in romanisim's L1 ramps (``pip install 'ipc_taichi[romanisim]'``).

How romanisim (0.15) makes an L1 ramp (``romanisim.l1.make_l1``):

1. ``apportion_counts_to_resultants`` draws, read after read, the charge that arrived
   since the last read; each read is the **reset level** (``pedestal`` plus a
   per-pixel ``pedestal_extra_noise``, electrons) plus the charge accumulated since reset
   (photons and dark current, cosmic rays, persistence), passed through
   ``inv_linearity.apply(read, electrons=True)``; the reads of a resultant are averaged.
2. ``ipc_model.apply(resultants)`` (or, with ``ipc_model=None``, ``add_ipc``): one
   constant 3x3 kernel convolved with the resultants, reset level included.
3. Electrons to DN (``gain``), dark decay, read noise (DN), rounding, saturation.

The coupling law needs the charge of each read, not the resultant (the law is
non-linear, so the coupled mean of the reads is not the mean of the coupled reads) and
not the raw level (the reset level is no charge). The one per-read entry point of
``make_l1`` is its ``inv_linearity`` slot, so :class:`ReadCoupling` sits there: it takes
the reset level off each read, couples the charge with :func:`ipc_taichi.couple` (the
law in electrons, of ``law=`` or a coupling-model file ``model=``), puts the reset level
back and hands the read to romanisim's own inverse linearity if there is one (so the
coupling acts on the collected charge, the node's non-linearity on what it measures).
romanisim's constant kernel is then not applied. The reset level is drawn here as
romanisim draws it (the same generator and seed), and given to romanisim as its
``pedestal`` with no extra noise: the ramp's random numbers are romanisim's own, read
charges included, so a run with the coupling differs from one without only by it.

- :func:`make_l1` and :func:`apportion_counts_to_resultants`: romanisim's functions of
  those names with the coupling (same arguments, plus ``law``/``geometry``/``edge`` or
  ``model``).
- :func:`coupled`: a context in which ``romanisim.l1.make_l1`` is :func:`make_l1`, so
  that ``romanisim.image.simulate`` (and scripts built on it) make coupled ramps.
- ``python -m ipc_taichi.romanisim --model FILE romanisim-make-image ARGS...``: one of
  romanisim's commands (or any script) run inside :func:`coupled` (:func:`main`).

The counts romanisim ramps are the science pixels (its ``make_asdf`` puts them inside
the 4-pixel reference border): the ``zero`` edge (the default) makes the reference
pixels zero-signal neighbours, as romanisim's own ``add_ipc`` does (``cval=0``).
docs/romanisim.md has a worked command.
"""

import argparse
import contextlib
import functools
import importlib.util
import os
import runpy
import shutil
import sys

import numpy as np

from .coupling import couple
from .errors import IPCInputError
from .model import CouplingModel

__all__ = ["ReadCoupling", "reset_level", "apportion_counts_to_resultants", "make_l1",
           "coupled", "main"]

# apportion_counts_to_resultants seeds its pedestal-noise generator with rng.raw() + 3
# (romanisim 0.15); tests/test_romanisim.py checks the reset level against romanisim's
PEDESTAL_STREAM = 3
# its seed when given neither rng nor seed
APPORTION_SEED = 46


def reset_level(shape, pedestal=None, pedestal_extra_noise=None, rng=None, seed=None):
    """The reset level (electrons, float32) that romanisim's
    ``apportion_counts_to_resultants`` adds to every read with these arguments.

    ``pedestal`` (a number or an array, ``None``: 0) plus, unless
    ``pedestal_extra_noise`` is ``None``, the Gaussian noise of that sigma drawn as
    romanisim draws it. ``rng`` (a galsim deviate) is not advanced: a duplicate is read.
    """
    import galsim

    source = rng.duplicate() if rng is not None else galsim.GaussianDeviate(
        APPORTION_SEED if seed is None else seed)
    level = np.zeros(shape, dtype="f4")
    level += 0 if pedestal is None else pedestal
    if pedestal_extra_noise is not None:
        noise = np.random.default_rng(source.raw() + PEDESTAL_STREAM)
        level += noise.normal(0, pedestal_extra_noise, shape)
    return level


class ReadCoupling:
    """The coupling of each read, in romanisim's ``inv_linearity`` slot.

    Parameters
    ----------
    coupling : CouplingModel
        The law (electrons), geometry and edge.
    reset : array_like
        The reset level (electrons) in every read: what is not charge.
    inv_linearity : romanisim.nonlinearity.NL, optional
        romanisim's own inverse linearity, applied after the coupling.

    Attributes
    ----------
    reads : int
        How many reads have been coupled (a reference read counts).
    """

    def __init__(self, coupling, reset, inv_linearity=None):
        self.coupling = coupling
        self.reset = np.asarray(reset, dtype=np.float64)
        self.inv_linearity = inv_linearity
        self.reads = 0

    @property
    def dq(self):
        """romanisim ORs this into its DQ: the inverse linearity's flags, if any."""
        dq = getattr(self.inv_linearity, "dq", None)
        return 0 if dq is None else dq

    def apply(self, img, electrons=False, reversed=False):
        """A read (reset level + charge, electrons) with its charge coupled."""
        if not electrons:
            raise IPCInputError("ReadCoupling.apply: the read must be in electrons "
                                "(romanisim passes electrons=True)")
        charge = np.asarray(img, dtype=np.float64) - self.reset
        read = self.reset + np.asarray(couple(charge, model=self.coupling), dtype=np.float64)
        self.reads += 1
        if self.inv_linearity is None:
            return read
        return self.inv_linearity.apply(read, electrons=True, reversed=reversed)


class _Resultants:
    """An ``ipc_model`` that leaves the resultants alone: the reads are coupled already
    (``ipc_model=None`` would convolve romanisim's constant kernel on top)."""

    def apply(self, img, **kwargs):
        return None


def _hook(shape, coupling, pedestal, pedestal_extra_noise, inv_linearity, rng, seed):
    """romanisim's arguments that couple each read: the reset level drawn here as its
    pedestal (no extra noise left to draw) and the coupling in the inv_linearity slot."""
    reset = reset_level(shape, pedestal, pedestal_extra_noise, rng=rng, seed=seed)
    return dict(pedestal=reset, pedestal_extra_noise=0.0,
                inv_linearity=ReadCoupling(coupling, reset, inv_linearity))


def apportion_counts_to_resultants(counts, tij, law=None, geometry=None, edge=None, *,
                                   model=None, pedestal=None, pedestal_extra_noise=None,
                                   inv_linearity=None, rng=None, seed=None, **kwargs):
    """``romanisim.l1.apportion_counts_to_resultants`` with each read's charge coupled.

    Returns its ``(resultants, dq)``: resultants in electrons, the reset level included.
    ``law``/``geometry``/``edge`` or ``model`` as in :func:`ipc_taichi.couple`; the other
    arguments are romanisim's (``pedestal`` ``None``: 0, as there).
    """
    from romanisim import l1

    coupling = CouplingModel.resolve(law, geometry, edge, model=model)
    hooked = _hook(np.shape(counts), coupling, pedestal, pedestal_extra_noise,
                   inv_linearity, rng, seed)
    return l1.apportion_counts_to_resultants(counts, tij, rng=rng, seed=seed, **hooked,
                                             **kwargs)


def make_l1(counts, read_pattern, law=None, geometry=None, edge=None, *, model=None,
            pedestal=None, pedestal_extra_noise=None, inv_linearity=None, rng=None,
            seed=None, ipc_model=None, **kwargs):
    """``romanisim.l1.make_l1`` with each read's charge coupled (the module docstring).

    Parameters
    ----------
    counts : galsim.Image
        Total electrons per pixel by the last read (romanisim's ``counts``).
    read_pattern : int or list of lists
        romanisim's MA table number or read pattern.
    law, geometry, edge, model
        The coupling, as in :func:`ipc_taichi.couple` (default the paper's law).
    pedestal, pedestal_extra_noise : float or array, optional
        The reset level and its noise (electrons); ``None``: romanisim's defaults.
    inv_linearity, rng, seed, **kwargs
        romanisim's, unchanged (``gain``, ``read_noise``, ``crparam``, ``persistence``,
        ``reference_read``, ...).
    ipc_model : None
        Refused: the coupling replaces romanisim's constant kernel.

    Returns
    -------
    What ``romanisim.l1.make_l1`` returns: resultants in DN, DQ (and the reference read).
    """
    from romanisim.models import parameters

    if ipc_model is not None:
        raise IPCInputError("make_l1: ipc_model= is romanisim's constant kernel; the "
                            "coupling replaces it (give law=/model=, not ipc_model=)")
    coupling = CouplingModel.resolve(law, geometry, edge, model=model)
    if pedestal is None:
        pedestal = parameters.pedestal
    if pedestal_extra_noise is None:
        pedestal_extra_noise = parameters.pedestal_extra_noise
    array = counts.array if hasattr(counts, "array") else counts
    hooked = _hook(np.shape(array), coupling, pedestal, pedestal_extra_noise,
                   inv_linearity, rng, seed)
    return _stock_make_l1()(counts, read_pattern, rng=rng, seed=seed, ipc_model=_Resultants(),
                            **hooked, **kwargs)


def _stock_make_l1():
    """romanisim's own make_l1, also inside :func:`coupled`."""
    from romanisim import l1

    return getattr(l1.make_l1, "stock", l1.make_l1)


@contextlib.contextmanager
def coupled(law=None, geometry=None, edge=None, *, model=None):
    """Within this context ``romanisim.l1.make_l1`` couples each read's charge.

    ``romanisim.image.simulate`` calls it with the ``ipc_model`` of its reference data:
    that constant kernel is dropped, the coupling replaces it. The coupling is resolved
    (a model file read) on entry; on exit romanisim's function is back.

    Examples
    --------
    >>> with ipc_taichi.romanisim.coupled(model="sca01_ipc.json"):   # doctest: +SKIP
    ...     im, extras = romanisim.image.simulate(metadata, catalog, level=1, ...)
    """
    from romanisim import l1

    coupling = CouplingModel.resolve(law, geometry, edge, model=model)
    stock = _stock_make_l1()

    @functools.wraps(stock)
    def patched(counts, read_pattern, *args, ipc_model=None, **kwargs):
        if args:
            raise IPCInputError("romanisim.l1.make_l1 in ipc_taichi.romanisim.coupled: "
                                "give its arguments after read_pattern by keyword")
        return make_l1(counts, read_pattern, model=coupling, **kwargs)

    patched.stock = stock
    previous, l1.make_l1 = l1.make_l1, patched
    try:
        yield coupling
    finally:
        l1.make_l1 = previous  # an enclosing coupled() keeps its own


def main(argv=None):
    """``python -m ipc_taichi.romanisim [--model FILE | --law LAW] [--edge E] COMMAND
    ARGS...``: romanisim's ``COMMAND`` (``romanisim-make-image``, on the PATH, or a script's
    path) run with ``ARGS`` inside :func:`coupled`. Returns the exit code (2: bad input)."""
    parser = argparse.ArgumentParser(
        prog="python -m ipc_taichi.romanisim",
        description="Run a romanisim command with signal-dependent IPC: each read's charge "
                    "coupled by the law (electrons) of --model or --law.")
    parser.add_argument("--model", metavar="FILE", help="a coupling-model file (JSON)")
    parser.add_argument("--law", help="the coupling law (default the paper's, donlon2018)")
    parser.add_argument("--edge", choices=("zero", "isolated"), help="beyond the pixels")
    parser.add_argument("command", help="romanisim-make-image, or a script's path")
    parser.add_argument("args", nargs=argparse.REMAINDER, help="the command's arguments")
    args = parser.parse_args(argv)
    if importlib.util.find_spec("romanisim") is None:
        print(f"{parser.prog}: error: romanisim is not installed "
              "(pip install 'ipc_taichi[romanisim]')", file=sys.stderr)
        return 2
    # romanisim's commands are scripts beside the interpreter (an unactivated venv too)
    path = args.command if os.path.isfile(args.command) else (
        shutil.which(args.command) or
        shutil.which(args.command, path=os.path.dirname(sys.executable)))
    if path is None:
        print(f"{parser.prog}: error: command {args.command!r}: not on the PATH and no "
              "such file", file=sys.stderr)
        return 2
    try:
        coupling = CouplingModel.resolve(args.law, None, args.edge, model=args.model)
    except (ValueError, OSError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    saved, sys.argv = sys.argv, [path, *args.args]
    try:
        with coupled(model=coupling):
            runpy.run_path(path, run_name="__main__")
    except SystemExit as exc:  # the command's own exit, with its code
        if exc.code is None or isinstance(exc.code, int):
            return exc.code or 0
        print(exc.code, file=sys.stderr)
        return 1
    finally:
        sys.argv = saved
    return 0


if __name__ == "__main__":
    sys.exit(main())

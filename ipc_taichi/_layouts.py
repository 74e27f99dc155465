"""The engine's kernel layouts, one object each, and the step plan they make.

A layout is how a step kernel walks the frame (the loops are described in
:mod:`ipc_taichi._kernels`): ``sweep`` (CPU: strips of rows, pairs carried
along a row and through a ring of rows), ``pixel`` (CUDA: column runs, pairs
carried down a column) and ``lanes`` (the CPU's default: the sweep on vectors
of ``L`` pixels, :mod:`ipc_taichi._lanes`). The engine names one per call
(``layout=`` of :func:`ipc_taichi.couple` and :func:`ipc_taichi.decouple`, or
:func:`default_layout`); :func:`kernel_layout` turns the name into its object
once, and every choice that depends on the layout is a method or an
attribute of that object, here and nowhere else:

- its step kernel's plan (:class:`StepPlan`: where each offset's second alpha
  comes from, :meth:`Layout.sources`; the registers it carries, worked out
  once from :meth:`Layout.carried`) and its kernel (:func:`get_step_kernel`);
- its workspace's shape (:class:`~ipc_taichi._workspace.Workspace`): padded
  rows, rows per task, rows of partials, the ring, how host arrays are
  allocated, whether the measured frame is kept padded and ``ok`` as reals;
- the arrays of a launch as its kernel reads them (:meth:`Layout.arguments`)
  and the bond map's copy (:meth:`Layout.bond_array`).

The buffers' swap is the workspace's (:meth:`~ipc_taichi._workspace.Workspace.holding`):
the same for every layout once the load has said where ``S_0`` is.
"""

import functools
from dataclasses import dataclass

import numpy as np

from . import _kernels, runtime
from ._kernels import SPREAD, pixel_kernel, sweep_kernel, tree_rows
from ._lanes import (
    aligned_zeros,
    cell_table,
    forget_vector_unit,
    host_vector_unit,
    lane_count,
    lanes_kernel,
    padded_width,
    reads_cells,
)
from .errors import IPCInputError

__all__ = ["Layout", "kernel_layout", "default_layout", "LAYOUTS", "StepPlan", "get_step_kernel",
           "clear_kernels", "STRIP_ROWS", "PIXEL_THREADS", "MIN_RUN_ROWS"]

# rows per task of the CPU sweep: a strip re-evaluates the dy-row pairs above
# it (1/STRIP_ROWS extra work for nearest neighbours) and 2 cores need a few
# dozen tasks to balance when other processes share them
STRIP_ROWS = 32
# threads the ``pixel`` layout aims for: an H100 keeps 132 x 2048 = 270 k
# threads resident, twice that hides the tail of the last wave
PIXEL_THREADS = 1 << 19
MIN_RUN_ROWS = 8


def _flat(array):
    """A C-contiguous array as 1-D, without a copy (an error if one were needed)."""
    return np.reshape(array, -1, copy=False)


class Layout:
    """What every layout shares; the strip layouts' (``sweep``, ``lanes``)
    answers where the ``pixel`` layout differs."""

    name = None
    fast_exp = False  # alpha's exponentials by the inlined polynomial (make_exp)
    padded_base = False  # the step reads the measured frame padded (Workspace.measured)
    real_ok = False  # ``ok`` held as reals, made when first needed (Workspace.ok_array)

    def check(self, device_buffers):
        """Refuse a layout that cannot run on the engine's path."""

    # --- the plan ------------------------------------------------------------------

    def sources(self, config):
        """Where each half-stencil offset's second alpha (``a_minus``, the pair
        with the neighbour at ``p - u``) comes from, per offset (static):

        - ``"row"``: registers carried along the row (``dy == 0``);
        - ``"ring"``: the ring buffer, written ``dy`` rows earlier;
        - ``"column"``: registers carried down the column (``dx == 0``);
        - ``"fresh"``: evaluated again (the pixel layout's other offsets, and
          every offset of a constant law, whose alpha is one number).
        """
        if config.law_kind == "constant":
            return ("fresh",) * len(config.offsets)
        return tuple("row" if dy == 0 else "ring" for dy, _ in config.offsets)

    def carried(self, config, dy, dx):
        """Registers the offset ``(dy, dx)`` carries (the sweep: one per column
        of a pair along the row)."""
        return dx if dy == 0 else 0

    # --- the workspace -------------------------------------------------------------

    def padded_shape(self, shape, reach, precision):
        """The padded working arrays' shape for an unpadded ``shape`` frame."""
        return shape[0] + 2 * reach, shape[1] + 2 * reach

    def rows_per_task(self, height, width):
        """Rows one task (a strip) walks."""
        return min(STRIP_ROWS, height)

    def partials(self, height, width, strip):
        """Rows of the ``partials`` array a step writes: one per task."""
        return -(-height // strip)

    def maxima_rows(self, n_partials):
        """Rows of ``partials`` holding the maxima after a step."""
        return n_partials

    def ring_shape(self, config, height, padded_width):
        """The shape of the ring of pair alphas (strips, slots, depth, row)."""
        return (-(-height // STRIP_ROWS), max(1, len(config.vertical)), config.ring_depth,
                padded_width)

    def host_zeros(self, shape, dtype, fill=0):
        """A host working array filled with ``fill``."""
        return np.full(shape, fill, dtype=dtype)

    # --- the launch ----------------------------------------------------------------

    def arguments(self, ws, config, src, base, dst, table, bonds):
        """``(src, base, dst, ok, bonds, table, ring)`` as the step kernel reads them."""
        ok, ring = ws.ok, ws.ring
        if config.flat:
            src, base, dst, ok, table, ring = (_flat(a) for a in (src, base, dst, ok, table,
                                                                  ring))
        return src, base, dst, ok, bonds, table, ring

    def bond_array(self, padded, reach, precision):
        """A padded bond map ``[k, y, x]`` as the host path's kernel reads it."""
        return padded.reshape(-1)

    def kernel(self, plan):
        return sweep_kernel(plan)


class Sweep(Layout):
    """The CPU sweep in scalar code."""

    name = "sweep"
    fast_exp = True


class Pixel(Layout):
    """One thread per column run; maxima reduced by a tree in the same launch."""

    name = "pixel"

    def sources(self, config):
        if config.law_kind == "constant":
            return ("fresh",) * len(config.offsets)
        return tuple("column" if dx == 0 else "fresh" for _, dx in config.offsets)

    def carried(self, config, dy, dx):
        return dy if dx == 0 else 0

    def rows_per_task(self, height, width):
        rows = max(MIN_RUN_ROWS, -(-height * width // PIXEL_THREADS))
        # fewer partials than the tree reduces to one row, unless the frame is
        # wider than that (then maxima() reads the rows the tree leaves)
        rows = max(rows, -(-height * width // _kernels.FAN_IN ** _kernels.TREE_LEVELS))
        return min(rows, height)

    def partials(self, height, width, strip):
        return -(-height // strip) * width

    def maxima_rows(self, n_partials):
        return tree_rows(n_partials)

    def ring_shape(self, config, height, padded_width):
        return (1, 1, 1, 1)

    def kernel(self, plan):
        return pixel_kernel(plan)


class Lanes(Layout):
    """The sweep on vectors of ``L`` pixels (:mod:`ipc_taichi._lanes`): rows
    rounded up to whole vectors, arrays 64-byte aligned, the measured frame
    padded, ``ok`` as reals; the CPU's own arrays only."""

    name = "lanes"
    padded_base = True
    real_ok = True

    def check(self, device_buffers):
        if device_buffers:
            raise IPCInputError("layout 'lanes' runs on the CPU's own arrays only; use "
                                "'sweep' or 'pixel'")

    def carried(self, config, dy, dx):
        return lane_count(config.precision) if dy == 0 else 0  # one vector per pair along the row

    def padded_shape(self, shape, reach, precision):
        return shape[0] + 2 * reach, padded_width(shape[1], reach, precision)

    def host_zeros(self, shape, dtype, fill=0):
        return aligned_zeros(shape, dtype, fill)

    def arguments(self, ws, config, src, base, dst, table, bonds):
        lanes = lane_count(config.precision)
        # the width changed since the workspace was made, without engine.clear_kernels()
        if ws.measured.shape[-1] != padded_width(ws.shape[1], ws.reach, config.precision):
            raise RuntimeError(f"a workspace built for another lane width than {lanes}: "
                               "call ipc_taichi.engine.clear_kernels() after changing it")
        ok = ws.ok_array() if config.uses_ok else ws.no_ok
        src, base, dst, ok, ring = (_flat(a).reshape(-1, lanes)
                                    for a in (src, ws.measured, dst, ok, ws.ring))
        if not config.mapped:  # unused: any vectors
            bonds = ok
        table = cell_table(table) if reads_cells(config.precision) else _flat(table)
        return src, base, dst, ok, bonds, table, ring

    def bond_array(self, padded, reach, precision):
        n, py, px = padded.shape
        wide = aligned_zeros((n, py, padded_width(px - 2 * reach, reach, precision)),
                             padded.dtype)
        wide[:, :, :px] = padded
        return wide.reshape(-1, lane_count(precision))

    def kernel(self, plan):
        return lanes_kernel(plan, SPREAD)


LAYOUTS = {layout.name: layout for layout in (Sweep(), Pixel(), Lanes())}


def kernel_layout(name):
    """The layout object of a layout's name."""
    layout = LAYOUTS.get(name)
    if layout is None:
        raise ValueError(f"unknown kernel layout {name!r}")
    return layout


def default_layout(arch, device_buffers=False):
    """The name of the layout that suits ``arch``: ``lanes`` on the CPU (host
    arrays) where it has a vector unit the ``lanes`` step is built for
    (:func:`~ipc_taichi._lanes.host_vector_unit`), else ``sweep``; ``sweep``
    for host arrays handled as device buffers (the test path), ``pixel`` on
    CUDA."""
    if arch == "cuda":
        return Pixel.name
    return Sweep.name if device_buffers or host_vector_unit() is None else Lanes.name


# --------------------------------------------------------------------------- the plan

@dataclass(frozen=True)
class StepPlan:
    """The compile-time plan of one step kernel: its
    :class:`~ipc_taichi._kernels.KernelConfig`, its layout and the static
    bookkeeping of the carried alphas, worked out once in plain Python
    (:meth:`of`); every field is a ``ti.static`` value in the kernels."""

    config: object  # the KernelConfig
    layout: Layout
    sources: tuple  # per offset: where its a_minus comes from (Layout.sources)
    carry_at: tuple  # per offset: its first carried register (Layout.carried)
    ring_index: tuple  # per offset: its ring slot (dy > 0), else -1
    left_extra: tuple  # per ring slot: columns left of 0 that later rows read back
    right_extra: tuple  # per ring slot: columns right of the last that later rows read
    prologue_lo: tuple  # per ring slot: the first column of the prologue rows
    carry_size: int  # registers carried along a row or down a column

    @classmethod
    def of(cls, config):
        layout = kernel_layout(config.layout)
        offsets, vertical = config.offsets, config.vertical
        carried = [layout.carried(config, dy, dx) for dy, dx in offsets]
        return cls(
            config=config, layout=layout, sources=layout.sources(config),
            carry_at=tuple(sum(carried[:k]) for k in range(len(offsets))),
            ring_index=tuple(vertical.index(k) if k in vertical else -1
                             for k in range(len(offsets))),
            left_extra=tuple(tuple(range(-offsets[k][1], 0)) for k in vertical),
            right_extra=tuple(max(0, -offsets[k][1]) for k in vertical),
            prologue_lo=tuple(min(0, -offsets[k][1]) for k in vertical),
            carry_size=max(1, sum(carried)))

    @property
    def law_at(self):
        """Where the law's 5 kernel parameters start among the coefficients."""
        return 2 * len(self.config.offsets)

    @property
    def combined(self):
        """Whether the flow is taken with pre-combined coefficients: a
        constant law with no ``ok`` gating, where every pair's alpha is the
        same number ``a``, so ``flow = sum_k (a w[k, 1] S(p+u) + a w[k, 0]
        S(p-u)) - (a sum_k (w[k, 0] + w[k, 1])) S(p)``: 2 multiply-adds per
        offset and one product, instead of 10 operations per offset."""
        return (self.config.law_kind == "constant" and not self.config.uses_ok
                and not self.config.mapped)

    @property
    def combined_at(self):
        """Where the pre-combined coefficients start (:attr:`combined`): per
        offset ``a w[k, 1]`` and ``a w[k, 0]``, then ``a sum_k (w[k, 0] + w[k, 1])``."""
        return self.law_at + 5

    @property
    def total_at(self):
        """Where ``a sum_k (w[k, 0] + w[k, 1])`` is, after the per-offset
        pre-combined coefficients (:attr:`combined`)."""
        return self.combined_at + 2 * len(self.config.offsets)

    @property
    def n_coef(self):
        """Registers of ``coefficients``: two weights per offset, then the law's
        5 parameters (a constant law's alpha last), then the pre-combined
        coefficients when :attr:`combined`."""
        return self.total_at + 1 if self.combined else self.combined_at

    @property
    def rings(self):
        return "ring" in self.sources

    @property
    def carries_row(self):
        return "row" in self.sources


@functools.cache
def get_step_kernel(config):
    """Build (once per config) the Taichi kernel for one coupling step: its
    layout's, from the :class:`StepPlan` of ``config``. Every layout is built
    from the device functions of :mod:`ipc_taichi._stepparts` (``lanes``: on
    vectors, :mod:`ipc_taichi._lanes`); the layouts differ only in their
    loops and in what they carry."""
    plan = StepPlan.of(config)
    return plan.layout.kernel(plan)


def clear_kernels():
    """Forget every compiled kernel (the step kernels and the frame kernels)
    and the vector unit chosen (``$IPC_TAICHI_LANES`` is read again)."""
    get_step_kernel.cache_clear()
    _kernels._clear_caches()
    forget_vector_unit()


runtime.on_reset(get_step_kernel.cache_clear)
runtime.on_reset(forget_vector_unit)

"""Signal-dependent IPC as Pyxel models (ESA's detector simulator, ``pip install
ipc_taichi[pyxel]``).

Pyxel's own IPC model, ``pyxel.models.charge_measurement.simple_ipc``, convolves the
charge with a fixed 3x3 kernel; esa/pyxel #65 asks for the signal-level dependent
coupling of Donlon et al. A Pyxel model is any importable function named by its dotted
path in the YAML, so this module provides two:

- :func:`nonlinear_ipc` (group ``charge_measurement``, Pixel -> Signal): the detector's
  charge (``detector.pixel``, electrons; in non-destructive mode the charge accumulated
  at each read, exactly what the law needs) coupled by :func:`ipc_taichi.couple`
  (the coupling law, in electrons, of ``law=`` or of a coupling-model file ``model=``),
  times the detector's ``charge_to_volt_conversion`` (V/e-). It replaces
  ``simple_measurement``/``simple_ipc`` in the pipeline.
- :func:`decouple_ipc` (group ``data_processing``): the charge of the signal
  (``detector.signal`` / ``charge_to_volt_conversion``) decoupled by
  :func:`ipc_taichi.decouple`, stored per read under ``detector.data["/decouple_ipc"]``
  (variable ``charge``, electrons, dims ``time, y, x``).

Reference pixels (``reference_pixels=``: ``"detector"``, the default, takes the
detector geometry's reference rows/columns; an integer ``N`` a border of N pixels; ``0``
none) are left alone, as :mod:`ipc_taichi.products` leaves them: their signal is their
charge times the conversion, and the science region inside them is coupled with the
model's edge rule (``zero``: the reference pixels are zero-signal neighbours).

The edge differs from ``simple_ipc``'s: Pyxel fills beyond the frame with the frame's
*mean* charge (``convolve_fft(boundary="fill", fill_value=mean)``); ours is ``zero``
(zero-signal pixels that take charge, the paper's) or ``isolated`` (no coupling across the
edge). Away from the outermost pixel ring a constant law (``law="constant:0.01"``) gives
``simple_ipc(coupling=0.01)`` to rounding. docs/examples/pyxel_nonlinear_ipc.yaml runs it.
"""

import numpy as np

from . import iteration
from .coupling import couple
from .decoupling import decouple
from .model import CouplingModel

__all__ = ["nonlinear_ipc", "decouple_ipc", "science_region"]


def science_region(shape, reference_pixels):
    """``(rows slice, cols slice)`` of the pixels inside the reference border:
    ``reference_pixels`` an integer border, or a Pyxel ``Mask`` (whole reference
    rows and columns) that must form a border; ``None``/``0``: the whole frame."""
    ny, nx = shape
    if reference_pixels is None or isinstance(reference_pixels, (bool, int, np.integer)):
        n = int(reference_pixels or 0)
        if n < 0 or 2 * n >= min(ny, nx):
            raise ValueError(f"reference_pixels={reference_pixels}: needs 0 <= N < "
                             f"{min(ny, nx) // 2 + (min(ny, nx) % 2)} for a {ny}x{nx} frame")
        return slice(n, ny - n), slice(n, nx - n)
    rows = sorted(set(int(r) % ny for r in (reference_pixels.row or [])))
    cols = sorted(set(int(c) % nx for c in (reference_pixels.col or [])))
    keep_rows = [r for r in range(ny) if r not in rows]
    keep_cols = [c for c in range(nx) if c not in cols]
    if not keep_rows or not keep_cols:
        raise ValueError("reference_pixels: every pixel is a reference pixel")
    region = slice(keep_rows[0], keep_rows[-1] + 1), slice(keep_cols[0], keep_cols[-1] + 1)
    if len(keep_rows) != region[0].stop - region[0].start or \
            len(keep_cols) != region[1].stop - region[1].start:
        raise ValueError(f"reference_pixels: rows {rows}, columns {cols} do not form a "
                         "border; give reference rows and columns at the frame's edges")
    return region


def _region(detector, reference_pixels):
    shape = (detector.geometry.row, detector.geometry.col)
    if isinstance(reference_pixels, str):
        if reference_pixels != "detector":
            raise ValueError(f"reference_pixels={reference_pixels!r}: 'detector', an "
                             "integer border or 0")
        reference_pixels = getattr(detector.geometry, "reference_pixels", None)
    return science_region(shape, reference_pixels)


def _volts_per_electron(detector):
    value = float(detector.characteristics.charge_to_volt_conversion)
    if not value > 0:
        raise ValueError(f"charge_to_volt_conversion={value}: needs a positive V/e-")
    return value


def nonlinear_ipc(detector, law=None, model=None, geometry=None, edge=None,
                  reference_pixels="detector"):
    """Pyxel ``charge_measurement`` model: signal-dependent IPC, Pixel -> Signal.

    Parameters
    ----------
    detector : pyxel.detectors.Detector
        Its ``pixel`` (charge, electrons) is read; its ``signal`` (V) written.
    law : str, optional
        The coupling law, in electrons (:func:`ipc_taichi.laws.get_law`: ``donlon2018``,
        ``constant:0.0125``, ``parametric:...``, ``table:FILE.npz``); default the paper's.
    model : str, optional
        A coupling-model file (JSON, from ``ipc-taichi calibrate``) instead of
        ``law``/``geometry``/``edge``.
    geometry : str or dict, optional
        Neighbour weights (default the 4 nearest, weight 1).
    edge : {"zero", "isolated"}, optional
        Beyond the science region (default ``zero``).
    reference_pixels : "detector", int or None
        See the module docstring.
    """
    coupling = CouplingModel.resolve(law, geometry, edge, model=model)
    charge = np.asarray(detector.pixel.array, dtype=np.float64)
    region = _region(detector, reference_pixels)
    coupled = charge.copy()
    coupled[region] = couple(np.ascontiguousarray(charge[region]), model=coupling)
    detector.signal.array = coupled * _volts_per_electron(detector)


def decouple_ipc(detector, law=None, model=None, geometry=None, edge=None,
                 reference_pixels="detector", max_iter=iteration.MAX_ITER, tol=iteration.TOL):
    """Pyxel ``data_processing`` model: the IPC-free charge of each read.

    The charge of the signal (``signal / charge_to_volt_conversion``, electrons) is
    decoupled (the paper's stopping rule: ``max_iter``, ``tol``) inside the reference
    border and stored, read after read, as ``detector.data["/decouple_ipc"]``: variables
    ``charge`` (electrons, dims ``time, y, x``), ``iterations`` and ``converged``
    (dim ``time``). The detector's buckets are not changed.
    """
    import xarray as xr

    coupling = CouplingModel.resolve(law, geometry, edge, model=model)
    charge = np.asarray(detector.signal.array, dtype=np.float64) / _volts_per_electron(detector)
    region = _region(detector, reference_pixels)
    out = charge.copy()
    out[region], info = decouple(np.ascontiguousarray(charge[region]), model=coupling,
                                 max_iter=max_iter, tol=tol, full_output=True)
    ny, nx = out.shape
    step = xr.Dataset(
        {"charge": (("time", "y", "x"), out[np.newaxis], {"units": "electron"}),
         "iterations": (("time",), [int(info.iterations)]),
         "converged": (("time",), [bool(info.converged)])},
        coords={"time": [float(detector.absolute_time)], "y": np.arange(ny),
                "x": np.arange(nx)})
    key = "/decouple_ipc"
    if key in detector.data.groups:
        step = xr.concat([detector.data[key].to_dataset(), step], dim="time")
    detector.data[key] = xr.DataTree(step)

"""Helpers more than one test file uses (fixtures are in conftest.py).

- :data:`CPU_ENV`, :func:`run_cli`: ``ipc-taichi`` in a new process, on the CPU in f64;
- :data:`LAW`: the paper's law on the command line;
- :func:`same`: bit-identical arrays (NaN equal to NaN), of any array kind;
- :func:`next_to`: pixels beside masked ones;
- :func:`write_sci`: a FITS file with a SCI extension (and more);
- :func:`optional`: why a test of an optional dependency is skipped, and what to install;
- :func:`one_array_plan`: the product plan of one plain science array (a record's input).
"""

import os
import subprocess
import sys

import numpy as np
from astropy.io import fits

CPU_ENV = dict(os.environ, IPC_TAICHI_ARCH="cpu", IPC_TAICHI_PRECISION="f64")
LAW = ("--law", "donlon2018")

# what to install for each optional dependency the tests use (pyproject's extras)
_EXTRA = {"torch": "torch", "roman_datamodels": "ipc_taichi[roman]", "asdf": "ipc_taichi[roman]",
          "jwst": "ipc_taichi[jwst]", "stdatamodels": "ipc_taichi[jwst]",
          "stpipe": "ipc_taichi[jwst]", "solid_waffle": "solid-waffle",
          "galsim": "galsim", "hypothesis": "hypothesis",
          "dask_jobqueue": "ipc_taichi[hpc]", "pyxel": "ipc_taichi[pyxel]",
          "romancal": "ipc_taichi[roman-pipeline]", "romanisim": "ipc_taichi[romanisim]"}


def optional(module):
    """The reason a test needing ``module`` is skipped where it is not installed
    (``pytest.importorskip(module, reason=optional(module))``): an optional
    dependency, and what to install."""
    top = module.split(".")[0]
    return f"{top} is not installed (optional: pip install '{_EXTRA.get(top, top)}')"


def run_cli(*args, env=CPU_ENV, timeout=300):
    """``ipc-taichi ARGS`` as a user runs it (a new process)."""
    return subprocess.run([sys.executable, "-m", "ipc_taichi.cli", *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=timeout)


def same(a, b):
    """Whether two arrays (NumPy, or anything :func:`numpy.asarray` reads) are
    bit-identical, NaN equal to NaN."""
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def next_to(mask):
    """Pixels with a masked nearest neighbour, and the masked pixels."""
    near = mask.copy()
    near[1:] |= mask[:-1]
    near[:-1] |= mask[1:]
    near[:, 1:] |= mask[:, :-1]
    near[:, :-1] |= mask[:, 1:]
    return near


def write_sci(path, sci, bunit="electron", extra=()):
    """A FITS file: an empty PRIMARY, ``sci`` as SCI (float32, ``BUNIT``), then
    the ``(name, data)`` pairs of ``extra`` as image extensions. Returns the path."""
    hdus = [fits.PrimaryHDU(), fits.ImageHDU(np.asarray(sci, np.float32), name="SCI")]
    hdus[1].header["BUNIT"] = bunit
    hdus += [fits.ImageHDU(data, name=name) for name, data in extra]
    fits.HDUList(hdus).writeto(path)
    return str(path)


def loop_couple(s, alpha, weights):
    """Coupling by a plain loop over pixels and offsets (zero charge beyond the
    frame): ``weights`` ``{(dy, dx): w}``, ``alpha(S, N)`` a fraction. The
    reference the independent generators' vectorised coupling is checked against."""
    ny, nx = s.shape
    out = s.copy()
    for y in range(ny):
        for x in range(nx):
            for (dy, dx), w in weights.items():
                qy, qx = y + dy, x + dx
                inside = 0 <= qy < ny and 0 <= qx < nx
                flow = w * alpha(s[y, x], s[qy, qx] if inside else 0.0) * s[y, x]
                out[y, x] -= flow
                if inside:
                    out[qy, qx] += flow
    return out


def one_array_plan(model, shape=(4, 4), label="x[SCI]", edge_reason=None, pedestal_text=None):
    """The :class:`~ipc_taichi.products.plan.ProductPlan` of one plain science
    array in electrons (HDU 1, ``SCI``), its edge reason and pedestal text as
    given (else as planned)."""
    import dataclasses

    from ipc_taichi.products import ProductOptions, missions
    from ipc_taichi.products.plan import ArrayFacts, plan_product

    plan = plan_product([ArrayFacts(1, "SCI", label, tuple(shape))], missions.recognise({}),
                        model, ProductOptions())
    first = plan.arrays[0]
    if edge_reason is not None:
        first = dataclasses.replace(first, edge_reason=edge_reason)
    return dataclasses.replace(plan, arrays=(first,),
                               pedestal_text=pedestal_text or plan.pedestal_text)

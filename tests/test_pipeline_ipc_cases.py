"""The JWST pipeline's own ``ipc`` test cases (``jwst/ipc/tests/test_ipc_corr.py``,
jwst 3.0), ported where the physics agrees (docs/products.md, "The JWST pipeline's
ipc step and this one").

The fixtures are the pipeline's: ramps holding the plane ``1000 + 2 y + 3 x`` DN
with the subarray keywords of a MIRI and a NIRCam full frame and subarray, and no
``pixeldq``/``groupdq`` (all good). What agrees:

- the reference pixels of each frame (``get_num_ref_pixels``: bottom, top, left,
  right) are the plan's science region, and they are never changed;
- the pipeline convolves the science region, zero-padded, with a deconvolution
  kernel; for a constant symmetric coupling ``a`` that kernel is, to first order,
  ``1 + 4a`` at the centre and ``-a`` on the four neighbours, and this Step's
  iterative inversion with the ``zero`` edge (the frames have reference sides)
  agrees with it to ``O(a^2)`` of the signal on every science pixel.

What does not: the pipeline's test kernel is antisymmetric (it shifts a plane by
0.2 DN); a coupling law here is symmetric by construction, so a plane stays a plane.
IRS2 frames are another module's.
"""

from collections import namedtuple

import numpy as np
import pytest
from jwst.ipc import ipc_corr
from stdatamodels.jwst.datamodels import RampModel

from ipc_taichi.model import CouplingModel
from ipc_taichi.products.jwst_step import IPCTaichiStep, plan_model
from ipc_taichi.products.options import ProductOptions

Nref = namedtuple("Nref", ["bottom_rows", "top_rows", "left_columns", "right_columns"])
A = 0.005  # the constant coupling, per neighbour
CASES = {  # the pipeline's fixtures (fewer groups): instrument, (ysize, xsize), (xstart, ystart)
    "miri_full": ("MIRI", (1024, 1032), (1, 1), Nref(0, 0, 4, 4)),
    "nir_full": ("NIRCAM", (2048, 2048), (1, 1), Nref(4, 4, 4, 4)),
    "miri_subarray": ("MIRI", (100, 100), (933, 925), Nref(0, 0, 0, 4)),
    "nir_subarray": ("NIRCAM", (200, 200), (1849, 1849), Nref(0, 4, 0, 4)),
}


def _model(name, ngroups=2):
    instrument, (ysize, xsize), (xstart, ystart), _ = CASES[name]
    y, x = np.mgrid[0:ysize, 0:xsize]
    model = RampModel()
    model.data = np.broadcast_to(1000.0 + 2.0 * y + 3.0 * x,
                                 (1, ngroups, ysize, xsize)).astype(np.float32)
    model.meta.subarray.xstart, model.meta.subarray.ystart = xstart, ystart
    model.meta.subarray.xsize, model.meta.subarray.ysize = xsize, ysize
    model.meta.instrument.name = instrument
    model.meta.exposure.nints, model.meta.exposure.ngroups = 1, ngroups
    model.meta.exposure.groupgap, model.meta.exposure.nframes = 0, 1
    model.meta.cal_step.superbias = "COMPLETE"
    return model


@pytest.mark.parametrize("name", list(CASES))
def test_get_num_ref_pixels(name):
    """The pipeline's ``test_get_num_ref_pixels``: the same counts, from the
    plan's science region (the pipeline's own function agrees on the same model)."""
    model = _model(name, ngroups=1)
    expected = CASES[name][3]
    assert ipc_corr.get_num_ref_pixels(model) == expected
    plan, flags = plan_model(model, CouplingModel.resolve("constant:0.005"),
                             ProductOptions(gain=1.0))
    assert flags == []  # no pixeldq, groupdq: all good (before: a bare TypeError)
    region = plan.arrays[0].science_region
    assert region.widths == tuple(expected)
    assert region.beyond == "reference" and plan.arrays[0].model.edge == "zero"


def _kernel():
    k = np.zeros((3, 3), dtype=np.float32)
    k[1, 1] = 1 + 4 * A
    k[0, 1] = k[2, 1] = k[1, 0] = k[1, 2] = -A
    return k


@pytest.mark.parametrize("name", ["miri_full", "miri_subarray", "nir_full", "nir_subarray"])
def test_correction_agrees_with_the_pipeline_kernel(name):
    """The pipeline's ``test_do_correction`` with a symmetric first-order kernel:
    the Step and ``ipc_corr.do_correction`` agree to O(a^2) of the signal, and
    both leave the reference pixels exactly as they were."""
    model = _model(name)
    before = np.array(model.data)
    expected = ipc_corr.do_correction(model.copy(), _kernel_model()).data
    result = IPCTaichiStep.call(model, gain=1.0, law=f"constant:{A}")
    got = np.asarray(result.data, dtype=np.float64)
    nref = CASES[name][3]
    ny, nx = before.shape[-2:]
    science = np.zeros((ny, nx), dtype=bool)
    science[nref.bottom_rows:ny - nref.top_rows, nref.left_columns:nx - nref.right_columns] = True
    for frame in range(before.shape[1]):
        g, e, b = got[0, frame], expected[0, frame], before[0, frame]
        assert np.array_equal(g[~science], b[~science])  # reference pixels untouched
        assert np.array_equal(e[~science], b[~science])
        bound = 20 * A ** 2 * float(np.abs(b).max())  # the first-order kernel's error
        assert np.abs(g - e)[science].max() <= bound
        # the edge rows gain back what leaked into the zero-signal reference pixels:
        # about a x signal, far above the bound
        assert np.abs(g - b)[science].max() > 0.5 * A * float(b[science].min())
    assert result.meta.cal_step.ipc == "COMPLETE"


def _kernel_model():
    from stdatamodels.jwst.datamodels import IPCModel

    return IPCModel(data=_kernel())


def test_plane_interior_unchanged():
    """A symmetric coupling moves no charge across a plane (each pixel gives
    and takes the same): far from the edges the decoupled plane is the plane,
    where the pipeline's antisymmetric test kernel shifts it by 0.2 DN."""
    model = _model("nir_subarray")
    before = np.array(model.data, dtype=np.float64)
    got = np.asarray(IPCTaichiStep.call(model, gain=1.0, law=f"constant:{A}").data,
                     dtype=np.float64)
    inner = (Ellipsis, slice(10, 150), slice(10, 150))
    assert np.abs(got[inner] - before[inner]).max() <= 1e-6 * before[inner].max()

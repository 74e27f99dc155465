"""The bench row beside the JWST pipeline's own ``ipc`` step.

On one NIRCam-like full-frame ramp (``nints x ngroups`` groups of
``size x size`` pixels, coupled with a constant alpha), in one process:

- ``jwst ipc step``: :func:`jwst.ipc.ipc_corr.ipc_correction`, the compute of
  the pipeline's step: one pass of a 3x3 deconvolution kernel (here the exact
  inverse of the coupling kernel, cropped to 3x3 and normalised, as the IPC
  reference files hold) over every group, reference pixels left alone;
- ``decouple (constant law)``: :func:`ipc_taichi.decouple` of the same groups,
  law ``constant:<alpha>``, nearest neighbours, the paper's stopping rule,
  which runs the constant-law kernel (no alpha evaluation), in f64 and in f32
  (both converge to the stopping rule; f32 moves half the bytes).

Both read the ramp's float32 groups and are timed on the compute alone (the
step's data copied in before each run, outside the timing); both results are
compared with the true signal. Needs the
``jwst`` package (the ``jwst`` extra).
"""

import statistics
import time

import numpy as np

import ipc_taichi

from ..datasets import star_field

__all__ = ["measure_pipeline_ipc", "jwst_ipc_kernel", "PIPELINE_SIZE"]

NIRCAM_BORDER = 4  # reference pixels on each side of a NIRCam full frame
PIPELINE_SIZE = 2048  # a NIRCam full frame


def jwst_ipc_kernel(alpha):
    """The 3x3 deconvolution kernel a JWST IPC reference file would hold for a
    constant nearest-neighbour coupling ``alpha``: the exact inverse of the
    coupling kernel (computed on a 64x64 periodic grid), cropped to 3x3 and
    normalised to a sum of 1."""
    n = 64
    k = np.zeros((n, n))
    k[0, 0] = 1 - 4 * alpha
    k[0, 1] = k[1, 0] = k[0, -1] = k[-1, 0] = alpha
    inverse = np.real(np.fft.ifft2(1.0 / np.fft.fft2(k)))
    crop = np.roll(np.roll(inverse, 1, 0), 1, 1)[:3, :3]
    return crop / crop.sum()


def _ramp(size, nints, ngroups, alpha, seed):
    """``(truth, measured)`` in electrons, shape ``(nints * ngroups, size, size)``:
    a star field on a sky, accumulating group by group; the reference border
    holds no signal and is not coupled."""
    b = NIRCAM_BORDER
    rate = np.zeros((size, size))
    rate[b:-b, b:-b] = star_field(size - 2 * b, seed=seed) / ngroups
    truth = np.stack([rate * (g + 1) for _ in range(nints) for g in range(ngroups)])
    measured = truth.copy()
    inner = ipc_taichi.couple(truth[:, b:-b, b:-b], law=f"constant:{alpha}")
    measured[:, b:-b, b:-b] = inner
    return truth, measured


def _ramp_model(measured, nints, ngroups):
    from stdatamodels.jwst.datamodels import RampModel

    size = measured.shape[-1]
    model = RampModel((nints, ngroups, size, size))
    model.meta.instrument.name = "NIRCAM"
    model.meta.instrument.detector = "NRCA1"
    model.meta.exposure.nints = nints
    model.meta.exposure.ngroups = ngroups
    model.meta.exposure.nframes = 1
    model.meta.exposure.groupgap = 0
    model.meta.exposure.readpatt = "RAPID"
    model.meta.subarray.name = "FULL"
    model.meta.subarray.xstart = model.meta.subarray.ystart = 1
    model.meta.subarray.xsize = model.meta.subarray.ysize = size
    return model


def _median(fn, repeats, before=None):
    times = []
    for _ in range(repeats):
        if before is not None:
            before()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def measure_pipeline_ipc(size=PIPELINE_SIZE, nints=2, ngroups=4, alpha=0.0125, repeats=3, seed=3,
                         precisions=("f64", "f32")):
    """Time the JWST ``ipc`` step's compute and :func:`ipc_taichi.decouple`
    with the constant law on the same ramp, in this process.

    Returns
    -------
    dict
        ``rows``: one dict per method (``row``, ``median_s``, ``times_s``,
        ``max_error`` in electrons over the science pixels; for the decoupler,
        one row per precision in ``precisions``, each with its ``iterations``
        and ``vs_jwst``, its median over the step's); ``ratio``: that of the
        first precision; the ramp's description. Taichi is left in the last
        precision.
    """
    import logging

    from jwst.ipc import ipc_corr
    from stdatamodels.jwst.datamodels import IPCModel

    truth, measured = _ramp(size, nints, ngroups, alpha, seed)
    b = NIRCAM_BORDER
    science = (slice(None), slice(b, -b), slice(b, -b))
    model = _ramp_model(measured, nints, ngroups)
    ipc_model = IPCModel(data=jwst_ipc_kernel(alpha).astype(np.float32))
    ramp32 = measured.reshape(nints, ngroups, size, size).astype(np.float32)

    def reload():
        model.data = ramp32.copy()

    logging.getLogger("jwst").setLevel(logging.WARNING)
    jwst_s, jwst_times = _median(lambda: ipc_corr.ipc_correction(model, ipc_model), repeats,
                                 reload)
    jwst_out = np.asarray(model.data, dtype=np.float64).reshape(measured.shape)
    jwst_err = float(np.abs(jwst_out - truth)[science].max())

    # the decoupler reads the same float32 groups the step reads
    groups = ramp32.reshape(measured.shape)
    law = f"constant:{alpha}"
    rows = [{"row": "jwst ipc step (3x3 pre-inverted kernel, float32)", "median_s": jwst_s,
             "times_s": jwst_times, "max_error": jwst_err}]
    for precision in precisions:
        info = ipc_taichi.init(precision=precision)
        run = dict(law=law, arch=info.arch, precision=precision)
        out = np.empty(measured.shape, dtype=info.dtype)
        ipc_taichi.decouple(groups[:1, :64, :64], **run)  # JIT outside the timing
        infos = []

        def ours():  # timed by _median at once, within this iteration
            infos[:] = ipc_taichi.decouple(groups, out=out, full_output=True,  # noqa: B023
                                           **run)[1]  # noqa: B023

        ours_s, ours_times = _median(ours, repeats)
        rows.append({"row": f"decouple, constant law ({info.arch} {info.precision})",
                     "median_s": ours_s, "times_s": ours_times,
                     "max_error": float(np.abs(out - truth)[science].max()),
                     "iterations": sorted({i.iterations for i in infos}),
                     "vs_jwst": ours_s / jwst_s})
    return {"size": size, "nints": nints, "ngroups": ngroups, "alpha": alpha,
            "arch": info.arch, "ratio": rows[1]["vs_jwst"], "rows": rows}

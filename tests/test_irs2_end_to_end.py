"""JWST readout arrangements and reference pixels through the public product
paths: the command line's ``process_product`` on FITS files and the stpipe Step on RampModels.

- A NIRSpec IRS2 ramp (reference samples interleaved with the rows): every
  science pixel within 1 DN of the truth, every reference sample and the
  reference border bit for bit, the Step COMPLETE, and both paths identical.
- An IRS2 frame whose arrangement cannot be placed: refused in one line naming the
  file, by both paths.
- A RampModel without ``pixeldq``/``groupdq`` (as the JWST pipeline's own test
  fixtures make them): corrected as all good.
- MIRI's 4 + 4 reference columns, with no DQ flag: left as they are.

These run the product plan (``ipc_taichi.products``) together with
``ipc_taichi.products.arrangement``.
"""

import numpy as np
import pytest
from astropy.io import fits
from jwst.ipc import x_irs2
from stdatamodels.jwst.datamodels import RampModel

import ipc_taichi
from ipc_taichi.datasets import star_field
from ipc_taichi.errors import IPCInputError
from ipc_taichi.model import CouplingModel
from ipc_taichi.products import irs2, process_product
from ipc_taichi.products.jwst_step import IPCTaichiStep

GAIN = 2.0  # e-/DN
LAW = "donlon2018"
BORDER = 4  # the near-infrared reference border of the science image
LEVELS = (0.5, 1.0)  # two groups of a ramp, fractions of the final charge


def _keywords(model, **meta):
    for path, value in meta.items():
        node = model.meta
        *parents, leaf = path.split(".")
        for name in parents:
            node = getattr(node, name)
        setattr(node, leaf, value)
    model.meta.cal_step.superbias = "COMPLETE"  # groups hold collected charge only
    model.meta.bunit_data = "DN"
    return model


def _irs2_ramp(detector="NRS1", filename="jw01_nrs1_irs2_ramp.fits"):
    """An IRS2 RampModel in DN, bias-free, its interleaved reference samples
    unflagged, and the truth (groups, 2048, 2048) in DN."""
    rng = np.random.default_rng(5)
    geometry = irs2.IRS2Geometry(16, 4, detector)
    inner = star_field(2048 - 2 * BORDER, seed=9, n_per_mpix=4000, background=200.0)
    truth = np.zeros((len(LEVELS), 2048, 2048))
    measured = np.zeros_like(truth)
    cut = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    for g, level in enumerate(LEVELS):
        truth[g][cut] = inner * level / GAIN
        measured[g][cut] = ipc_taichi.couple(inner * level, law=LAW, edge="zero") / GAIN
    reference = rng.normal(0.0, 20.0, (1, len(LEVELS)) + geometry.shape)
    data = irs2.interleave(measured[None], reference, geometry).astype(np.float32)
    pixeldq = np.zeros(geometry.shape, np.uint32)
    border = np.zeros((2048, 2048), np.uint32)
    border[:BORDER] = border[-BORDER:] = border[:, :BORDER] = border[:, -BORDER:] = 2 ** 31
    pixeldq[irs2.science_rows(geometry)] = border
    model = RampModel(data=data, pixeldq=pixeldq,
                      groupdq=np.zeros(data.shape, np.uint8))
    _keywords(model, **{"filename": filename, "telescope": "JWST",
                        "instrument.name": "NIRSPEC", "instrument.detector": detector,
                        "exposure.readpatt": "NRSIRS2", "exposure.nrs_normal": 16,
                        "exposure.nrs_reference": 4, "subarray.name": "FULL",
                        "subarray.xstart": 1, "subarray.ystart": 1, "subarray.xsize": 2048,
                        "subarray.ysize": 2048})
    return model, truth, geometry


def _science(data, detector):
    """The science rows, through the JWST pipeline's own ``x_irs2``."""
    return x_irs2.from_irs2(np.asarray(data, dtype=np.float64), x_irs2.make_mask(data),
                            detector)


def _bits(array):
    """The bits of a float32 array, whatever its byte order (FITS is big-endian)."""
    assert array.dtype.kind == "f" and array.dtype.itemsize == 4  # the product's float32
    return np.asarray(array).astype("<f4").view("<u4")


def _check_irs2(out, model, truth, geometry, detector):
    before = np.asarray(model.data)
    reference = ~irs2.science_rows(geometry)
    np.testing.assert_array_equal(_bits(out[..., reference, :]),
                                  _bits(before[..., reference, :]))
    got, came = _science(out, detector)[0], _science(before, detector)[0]
    cut = (slice(None), slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    assert np.abs(got - truth)[cut].max() < 1.0  # DN, every science pixel
    assert np.abs(came - truth)[cut].max() > 100.0  # the coupling removed was large
    ring = np.ones((2048, 2048), bool)
    ring[BORDER:-BORDER, BORDER:-BORDER] = False
    np.testing.assert_array_equal(got[:, ring], came[:, ring])  # the reference border


@pytest.mark.parametrize("detector", ["NRS1", "NRS2"])
def test_irs2_ramp_file_and_step(cpu, tmp_path, detector):
    model, truth, geometry = _irs2_ramp(detector)
    src, dst = tmp_path / "jw01_irs2_ramp.fits", tmp_path / "jw01_irs2_ipc.fits"
    model.save(src)
    process_product(src, dst, "decouple", model=CouplingModel.resolve(LAW), gain=GAIN)
    with fits.open(dst) as hdul:
        from_file = np.array(hdul["SCI"].data)
    _check_irs2(from_file, model, truth, geometry, detector)

    result = IPCTaichiStep(gain=GAIN, law=LAW).run(model)
    assert result.meta.cal_step.ipc == "COMPLETE"
    from_step = np.asarray(result.data)
    _check_irs2(from_step, model, truth, geometry, detector)
    np.testing.assert_array_equal(from_step, from_file)  # the same plan for both paths


def _irs2_subarray(tmp_path):
    data = np.zeros((1, 1, 3200, 64), np.float32)
    model = RampModel(data=data, pixeldq=np.zeros(data.shape[-2:], np.uint32),
                      groupdq=np.zeros(data.shape, np.uint8))
    _keywords(model, **{"filename": "jw02_irs2_sub_ramp.fits", "telescope": "JWST",
                        "instrument.name": "NIRSPEC", "instrument.detector": "NRS1",
                        "exposure.readpatt": "NRSIRS2", "exposure.nrs_normal": 16,
                        "exposure.nrs_reference": 4, "subarray.name": "SUBS200A1",
                        "subarray.xstart": 1, "subarray.ystart": 1, "subarray.xsize": 64,
                        "subarray.ysize": 2048})
    src = tmp_path / "jw02_irs2_sub_ramp.fits"
    model.save(src)
    return model, src


WHY = ("an IRS2 frame (NRSIRS2) of 3200x64 pixels, not the full frame of 3200x2048 that "
       "NRS_NORM = 16 and NRS_REF = 4 give (rows x columns, DMS orientation): its reference "
       "samples cannot be placed; refused")


def test_irs2_arrangement_that_cannot_be_placed_is_refused(cpu, tmp_path):
    model, src = _irs2_subarray(tmp_path)
    dst = tmp_path / "out.fits"
    with pytest.raises(IPCInputError) as err:
        process_product(src, dst, "decouple", model=CouplingModel.resolve(LAW), gain=GAIN)
    message = str(err.value)
    assert "\n" not in message and "jw02_irs2_sub_ramp.fits" in message
    assert message.endswith(WHY)
    assert not dst.exists()
    with pytest.raises(IPCInputError) as err:
        IPCTaichiStep(gain=GAIN, law=LAW).run(model)
    assert str(err.value) == f"jw02_irs2_sub_ramp.fits[SCI]: {WHY}"


def _fixture_ramp(instrument, shape, xstart=1):
    """A RampModel as the JWST pipeline's own ``ipc`` test fixtures build it:
    ``RampModel()``, then ``data`` and a few keywords; no ``pixeldq``/``groupdq``."""
    model = RampModel()
    ny, nx = shape
    ramp = np.zeros((1, 2, ny, nx))
    rng = np.random.default_rng(8)
    ramp[0, 1] = rng.uniform(0.0, 20000.0, shape) / GAIN
    ramp[0, 0] = ramp[0, 1] / 2
    model.data = ramp.astype(np.float32)
    _keywords(model, **{"filename": f"jw03_{instrument.lower()}_ramp.fits",
                        "telescope": "JWST", "instrument.name": instrument,
                        "subarray.xstart": xstart, "subarray.ystart": 1,
                        "subarray.xsize": nx, "subarray.ysize": ny})
    return model


def test_ramp_model_without_dq_arrays(cpu):
    model = _fixture_ramp("NIRCAM", (40, 44), xstart=1849)
    assert model.pixeldq is None and model.groupdq is None
    with_dq = model.copy()
    with_dq.pixeldq = np.zeros((40, 44), np.uint32)
    with_dq.groupdq = np.zeros((1, 2, 40, 44), np.uint8)
    result = IPCTaichiStep(gain=GAIN, law=LAW).run(model)
    expected = IPCTaichiStep(gain=GAIN, law=LAW).run(with_dq)
    assert result.meta.cal_step.ipc == "COMPLETE"
    np.testing.assert_array_equal(result.data, expected.data)  # missing = all good
    assert np.abs(np.asarray(result.data) - np.asarray(model.data)).max() > 1.0  # corrected


def test_miri_reference_columns_untouched(cpu, tmp_path):
    """No DQ flag marks them: the science region does (columns 1-4 and 1029-1032)."""
    model = _fixture_ramp("MIRI", (1024, 1032))
    model.meta.instrument.detector = "MIRIMAGE"
    model.pixeldq = np.zeros((1024, 1032), np.uint32)
    model.groupdq = np.zeros((1, 2, 1024, 1032), np.uint8)
    src, dst = tmp_path / "jw03_miri_ramp.fits", tmp_path / "jw03_miri_ipc.fits"
    model.save(src)
    process_product(src, dst, "decouple", model=CouplingModel.resolve(LAW), gain=GAIN)
    with fits.open(dst) as hdul:
        from_file = np.array(hdul["SCI"].data)
    result = IPCTaichiStep(gain=GAIN, law=LAW).run(model)
    before = np.asarray(model.data)
    columns = [0, 1, 2, 3, 1028, 1029, 1030, 1031]
    for out in (from_file, np.asarray(result.data)):
        np.testing.assert_array_equal(_bits(out[..., columns]), _bits(before[..., columns]))
        assert np.abs(out[..., 4:-4] - before[..., 4:-4]).max() > 1.0  # the rest corrected
    np.testing.assert_array_equal(np.asarray(result.data), from_file)


def test_irs2_pedestal_image_in_the_product_frame(cpu, tmp_path):
    """A pedestal image is given in the product's frame (3200x2048 for IRS2)
    and taken to the science image with the frames: 500 e- on every science
    row (1e6 on the reference samples) is the number 500."""
    model, _, geometry = _irs2_ramp("NRS1")
    src = tmp_path / "jw01_irs2_ramp.fits"
    model.save(src)
    image = np.full(geometry.shape, 1e6, np.float32)
    image[irs2.science_rows(geometry)] = 500.0
    pedestal = tmp_path / "pedestal.fits"
    fits.PrimaryHDU(image).writeto(pedestal)
    out = {}
    for name, option in (("image", str(pedestal)), ("number", 500.0)):
        dst = tmp_path / f"{name}.fits"
        process_product(src, dst, "decouple", model=CouplingModel.resolve(LAW), gain=GAIN,
                        pedestal=option)
        with fits.open(dst) as hdul:
            out[name] = np.array(hdul["SCI"].data)
    np.testing.assert_array_equal(out["image"], out["number"])

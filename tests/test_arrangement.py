"""Readout arrangements (ipc_taichi.products.arrangement) and the reference pixels the
product plan places in their image (ipc_taichi.products.plan.science_region_of): contiguous,
IRS2, MIRI's reference columns (against the JWST pipeline's
``ipc_corr.get_num_ref_pixels`` on its own test fixtures), and the flag arrays of a
RampModel that has none."""

import numpy as np
import pytest
from jwst import datamodels
from jwst.ipc.ipc_corr import get_num_ref_pixels

from ipc_taichi.errors import IPCInputError
from ipc_taichi.products import irs2, missions, plan
from ipc_taichi.products.arrangement import arrangement_of
from ipc_taichi.products.jwst_step import _flags, _keywords
from ipc_taichi.products.options import ProductOptions

LABEL = "jw_mirimage_rate.fits[SCI]"
MIRI = {"TELESCOP": "JWST", "INSTRUME": "MIRI", "DETECTOR": "MIRIMAGE"}


def _facts(primary, science, shape, label=LABEL):
    def lookup(header):
        return lambda key: header.get(key) if header.get(key) not in (None, "") else None

    return plan.ArrayFacts(1, "SCI", label, tuple(shape), lookup(science), lookup(primary))


def _region(primary, science, shape, label=LABEL):
    mission = missions.recognise(primary, science)
    return plan.science_region_of(tuple(shape)[-2:], mission,
                                  _facts(primary, science, shape, label))


def test_contiguous_is_the_identity():
    arrangement = arrangement_of({"TELESCOP": "JWST", "INSTRUME": "NIRCAM"}, {},
                                         (3, 64, 80), "x.fits[SCI]")
    assert (arrangement.kind, arrangement.shape, arrangement.science_shape) == (
        "contiguous", (64, 80), (64, 80))
    assert arrangement.identity and arrangement.irs2 is None and arrangement.border == 0
    frames = np.ones((3, 64, 80))
    corrected = frames * 2
    assert arrangement.to_science(frames) is frames
    assert arrangement.from_science(corrected, frames) is corrected
    assert arrangement.describe() == "contiguous 64x80"
    assert arrangement_of({}, {}, (5, 7), "x.fits[SCI]").kind == "contiguous"


def test_irs2_rate_file_is_contiguous():
    header = {"INSTRUME": "NIRSPEC", "DETECTOR": "NRS1", "READPATT": "NRSIRS2"}
    arrangement = arrangement_of(header, {}, (2048, 2048), "jw_nrs1_rate.fits[SCI]")
    assert arrangement.kind == "contiguous" and arrangement.identity
    assert arrangement.describe() == ("IRS2 read pattern, its interleaved reference samples "
                                      "already removed")


def test_irs2_arrangement_and_the_plans_science_region():
    header = {"TELESCOP": "JWST", "INSTRUME": "NIRSPEC", "DETECTOR": "NRS2",
              "READPATT": "NRSIRS2RAPID", "NRS_NORM": 16, "NRS_REF": 4}
    arrangement = arrangement_of(header, {}, (1, 4, 3200, 2048),
                                         "jw_nrs2_uncal.fits[SCI]")
    assert (arrangement.kind, arrangement.shape, arrangement.science_shape) == (
        "irs2", (3200, 2048), (2048, 2048))
    assert not arrangement.identity and arrangement.border == 4
    assert arrangement.describe() == ("IRS2 NRS2, NRS_NORM = 16, NRS_REF = 4 (3200 rows, 2048 "
                                      "of them science)")
    ramp = np.arange(2 * 3200 * 2048, dtype=np.float32).reshape(1, 2, 3200, 2048)
    science = arrangement.to_science(ramp)
    assert science.shape == (1, 2, 2048, 2048)
    np.testing.assert_array_equal(arrangement.from_science(science, ramp), ramp)
    # the plan asks once: the arrangement, then the border of its image
    region = _region(header, {}, (1, 4, 3200, 2048), "jw_nrs2_uncal.fits[SCI]")
    assert region.arrangement == arrangement and region.shape == (2048, 2048)
    assert region.slices == (slice(4, 2044), slice(4, 2044)) and region.beyond == "reference"


def test_irs2_refused_with_tile():
    header = {"TELESCOP": "JWST", "INSTRUME": "NIRSPEC", "DETECTOR": "NRS1",
              "READPATT": "NRSIRS2", "BUNIT": "DN"}
    facts = _facts(header, {}, (1, 2, 3200, 2048), "jw_nrs1_uncal.fits[SCI]")
    options = ProductOptions.from_kwargs(tile=256, gain=2.0)
    with pytest.raises(IPCInputError) as err:
        plan.plan_array(facts, missions.recognise(header), None, options)
    assert str(err.value) == ("jw_nrs1_uncal.fits[SCI]: an IRS2 frame (reference samples "
                              "interleaved) is corrected whole: run without --tile")


def test_miri_full_frame():
    region = _region(MIRI, {}, (2, 1024, 1032))
    assert region.arrangement.identity and region.beyond == "reference"
    assert region.slices == (slice(0, 1024), slice(4, 1028))  # no reference rows
    assert region.source == "MIRI full frame"


def _miri_model(xstart, xsize, ysize=64):
    """A RampModel as the JWST pipeline's own ``ipc`` test fixtures make it (no DQ)."""
    model = datamodels.RampModel()
    model.data = np.zeros((1, 2, ysize, xsize), dtype=np.float32)
    model.meta.instrument.name = "MIRI"
    model.meta.subarray.xstart, model.meta.subarray.ystart = xstart, 1
    model.meta.subarray.xsize, model.meta.subarray.ysize = xsize, ysize
    return model


@pytest.mark.parametrize("xstart,xsize", [(1, 1032), (933, 100), (1, 288), (413, 256),
                                          (3, 72)])
def test_miri_columns_are_the_pipelines(xstart, xsize):
    """One rule for MIRI's 4 + 4 reference columns: the plan's
    (``missions.reference_border``), read from the model as the Step reads it."""
    model = _miri_model(xstart, xsize)
    nref = get_num_ref_pixels(model)
    get = _keywords(model)
    assert get("SUBSTRT1") == xstart and get("INSTRUME") == "MIRI"
    facts = plan.ArrayFacts(1, "SCI", LABEL, model.data.shape, get, get)
    miri = missions.recognise({"TELESCOP": "JWST", "INSTRUME": "MIRI"})
    region = plan.science_region_of((64, xsize), miri, facts)
    columns = np.ones(xsize, bool)
    columns[region.slices[1]] = False
    assert columns[:nref.left_columns].all() and columns[xsize - nref.right_columns:].all()
    assert columns.sum() == nref.left_columns + nref.right_columns
    assert (nref.bottom_rows, nref.top_rows) == (0, 0)
    assert region.slices[0] == slice(0, 64)


def test_miri_frame_of_reference_columns_only_refused():
    """The pipeline counts 4 right columns for a 3-column frame at the edge: every
    pixel is a reference pixel, nothing to correct."""
    with pytest.raises(IPCInputError) as err:
        _region(dict(MIRI, SUBSTRT1=1030, SUBSTRT2=1), {}, (64, 3))
    assert str(err.value) == "jw_mirimage_rate.fits[SCI]: every pixel is a reference pixel"


def test_miri_cut_out_is_not_placed():
    """A slit cut out of a subarray keeps the exposure's SUBSTRT1 and SUBSIZE1."""
    primary = dict(MIRI, SUBSTRT1=1, SUBSTRT2=1, SUBSIZE1=72, SUBSIZE2=64)
    assert _region(primary, {}, (64, 72)).slices == (slice(0, 64), slice(4, 72))
    assert _region(primary, {}, (40, 20)).source == "no reference pixels"


@pytest.mark.parametrize("start,width,message", [
    (0, 72, "jw_mirimage_rate.fits[SCI]: SUBSTRT1 = 0 is not a pixel of the detector (a whole "
            "number from 1); its reference pixels cannot be placed; refused"),
    ("left", 72, "jw_mirimage_rate.fits[SCI]: SUBSTRT1 = 'left' is not a pixel of the "
                 "detector (a whole number from 1); its reference pixels cannot be placed; "
                 "refused"),
    (1000, 72, "jw_mirimage_rate.fits[SCI]: a MIRI frame of 64x72 pixels from SUBSTRT1/2 = "
               "1000, 1 runs past the detector's 1024x1032; refused"),
])
def test_geometry_refused_in_one_line(start, width, message):
    with pytest.raises(IPCInputError) as err:
        _region(dict(MIRI, SUBSTRT1=start, SUBSTRT2=1), {}, (64, width))
    assert str(err.value) == message


def test_flags_of_a_model_without_them_all_good():
    model = datamodels.RampModel()  # as the pipeline's test fixtures make it
    model.data = np.ones((2, 3, 8, 10), dtype=np.float32)
    assert model.pixeldq is None and model.groupdq is None
    assert _flags(model, model.data.shape, "ramp") == []
    assert model.pixeldq is None  # the model is left as it is


def test_flags_of_the_wrong_shape_refused():
    model = datamodels.RampModel()
    model.data = np.ones((1, 2, 8, 10), dtype=np.float32)
    model.pixeldq = np.zeros((8, 11), np.uint32)
    with pytest.raises(IPCInputError) as err:
        _flags(model, model.data.shape, "jw_bad_ramp.fits")
    assert str(err.value) == ("jw_bad_ramp.fits[PIXELDQ]: shape (8, 11) does not match the "
                              "science data's (1, 2, 8, 10); refused")


def test_irs2_fixture_without_readpatt():
    """The pipeline's own IRS2 ``ipc`` fixture (no READPATT), read as the Step reads it."""
    model = datamodels.RampModel()
    model.data = np.zeros((1, 2, 3200, 2048), dtype=np.float32)
    model.meta.instrument.name, model.meta.instrument.detector = "NIRSPEC", "NRS1"
    model.meta.exposure.nrs_normal, model.meta.exposure.nrs_reference = 16, 4
    get = _keywords(model)
    facts = plan.ArrayFacts(1, "SCI", "ramp[SCI]", model.data.shape, get, get)
    assert plan.arrangement_of(facts, (3200, 2048)).irs2 == irs2.IRS2Geometry(16, 4, "NRS1")


def test_calibrate_refuses_an_irs2_ramp(tmp_path):
    """calibrate reads contiguous frames: an IRS2 ramp is refused in one line."""
    from astropy.io import fits

    from ipc_taichi.calibrate.inputs import read_frames

    primary = fits.PrimaryHDU()
    primary.header.update({"TELESCOP": "JWST", "INSTRUME": "NIRSPEC", "DETECTOR": "NRS1",
                           "READPATT": "NRSIRS2", "NRS_NORM": 16, "NRS_REF": 4})
    sci = fits.ImageHDU(np.zeros((1, 2, 3200, 2048), np.float32), name="SCI")
    sci.header["BUNIT"] = "DN"
    path = tmp_path / "jw_nrs1_irs2_dark.fits"
    fits.HDUList([primary, sci]).writeto(path)
    with pytest.raises(IPCInputError) as err:
        read_frames(str(path), gain=2.0)
    assert str(err.value) == (
        f"{path}[SCI]: IRS2 NRS1, NRS_NORM = 16, NRS_REF = 4 (3200 rows, 2048 of them science): "
        "calibrate reads contiguous frames; give the products after the refpix step (its "
        "reference samples removed)")

"""Product layouts (ipc_taichi.products.layouts): contiguous, IRS2, MIRI reference
columns (against the JWST pipeline's ``ipc_corr.get_num_ref_pixels`` on its own test
fixtures), and the DQ arrays of a RampModel that has none."""

import numpy as np
import pytest
from jwst import datamodels
from jwst.ipc.ipc_corr import get_num_ref_pixels

from ipc_taichi.errors import IPCInputError
from ipc_taichi.products import irs2, layouts

LABEL = "jw_mirimage_rate.fits[SCI]"
MIRI = {"TELESCOP": "JWST", "INSTRUME": "MIRI", "DETECTOR": "MIRIMAGE"}


def test_contiguous_is_the_identity():
    layout = layouts.layout_of({"TELESCOP": "JWST", "INSTRUME": "NIRCAM"}, {}, (3, 64, 80),
                               "x.fits[SCI]")
    assert (layout.kind, layout.shape, layout.science_shape) == ("contiguous", (64, 80),
                                                                 (64, 80))
    assert layout.identity and layout.reference is None and layout.irs2 is None
    frames = np.ones((3, 64, 80))
    corrected = frames * 2
    assert layout.to_science(frames) is frames
    assert layout.from_science(corrected, frames) is corrected
    assert layout.describe() == "contiguous 64x80"
    assert layouts.layout_of({}, {}, (5, 7), "x.fits[SCI]").kind == "contiguous"


def test_irs2_rate_file_is_contiguous():
    header = {"INSTRUME": "NIRSPEC", "DETECTOR": "NRS1", "READPATT": "NRSIRS2"}
    layout = layouts.layout_of(header, {}, (2048, 2048), "jw_nrs1_rate.fits[SCI]")
    assert layout.kind == "contiguous" and layout.identity
    assert layout.describe() == ("IRS2 read pattern, its interleaved reference samples "
                                 "already removed")


def test_irs2_layout():
    header = {"INSTRUME": "NIRSPEC", "DETECTOR": "NRS2", "READPATT": "NRSIRS2RAPID",
              "NRS_NORM": 16, "NRS_REF": 4}
    layout = layouts.layout_of(header, {}, (1, 4, 3200, 2048), "jw_nrs2_uncal.fits[SCI]")
    assert (layout.kind, layout.shape, layout.science_shape) == ("irs2", (3200, 2048),
                                                                 (2048, 2048))
    assert not layout.identity
    assert layout.describe() == ("IRS2 NRS2, NRS_NORM = 16, NRS_REF = 4 (3200 rows, 2048 of "
                                 "them science)")
    ref = layout.reference  # the near-infrared 4-pixel border of the science image
    assert ref.shape == (2048, 2048) and ref.sum() == 2048 * 2048 - 2040 * 2040
    assert ref[:4].all() and ref[:, -4:].all() and not ref[4:-4, 4:-4].any()
    ramp = np.arange(2 * 3200 * 2048, dtype=np.float32).reshape(1, 2, 3200, 2048)
    science = layout.to_science(ramp)
    assert science.shape == (1, 2, 2048, 2048)
    back = layout.from_science(science, ramp)
    np.testing.assert_array_equal(back, ramp)


def test_miri_full_frame():
    layout = layouts.layout_of(MIRI, {}, (2, 1024, 1032), LABEL)
    assert layout.kind == "miri" and layout.identity
    assert layout.describe() == "MIRI, 8 reference columns kept as they are"
    ref = layout.reference
    assert np.flatnonzero(ref.any(axis=0)).tolist() == [0, 1, 2, 3, 1028, 1029, 1030, 1031]
    assert ref[:, [0, 3, 1028, 1031]].all()  # every row: MIRI has no reference rows
    frames = np.ones((2, 1024, 1032))
    assert layout.to_science(frames) is frames


def _miri_model(xstart, xsize, ysize=64):
    """A RampModel as the JWST pipeline's own ``ipc`` test fixtures make it (no DQ)."""
    model = datamodels.RampModel()
    model.data = np.zeros((1, 2, ysize, xsize), dtype=np.float32)
    model.meta.instrument.name = "MIRI"
    model.meta.subarray.xstart, model.meta.subarray.ystart = xstart, 1
    model.meta.subarray.xsize, model.meta.subarray.ysize = xsize, ysize
    return model


@pytest.mark.parametrize("xstart,xsize", [(1, 1032), (933, 100), (1, 288), (413, 256),
                                          (3, 72), (1030, 3)])
def test_miri_columns_are_the_pipelines(xstart, xsize):
    model = _miri_model(xstart, xsize)
    nref = get_num_ref_pixels(model)
    keywords = layouts.ramp_keywords(model)
    assert keywords["SUBSTRT1"] == xstart and keywords["INSTRUME"] == "MIRI"
    mask = layouts.miri_reference_columns(keywords, None, model.data.shape[-2:], LABEL)
    columns = np.zeros(xsize, bool) if mask is None else mask.all(axis=0)
    assert columns[:nref.left_columns].all() and columns[xsize - nref.right_columns:].all()
    # the pipeline's counts are not clipped to the frame's width (4 for 3 columns)
    assert columns.sum() == min(xsize, nref.left_columns + nref.right_columns)
    assert (nref.bottom_rows, nref.top_rows) == (0, 0)
    if mask is not None:
        assert (mask == columns[None, :]).all()


def test_miri_keywords_of_the_science_header_come_first():
    mask = layouts.miri_reference_columns(dict(MIRI, SUBSTRT1=1), {"SUBSTRT1": 413},
                                          (64, 256), LABEL)
    assert mask is None


def test_miri_cut_out_is_not_placed():
    """A slit cut out of a subarray keeps the exposure's SUBSTRT1 and SUBSIZE1."""
    primary = dict(MIRI, SUBSTRT1=1, SUBSIZE1=72)
    assert layouts.miri_reference_columns(primary, {}, (64, 72), LABEL).sum() == 4 * 64
    assert layouts.miri_reference_columns(primary, {}, (40, 20), LABEL) is None


def test_miri_without_substrt():
    assert layouts.miri_reference_columns(MIRI, {}, (1024, 1032), LABEL).sum() == 8 * 1024
    assert layouts.miri_reference_columns(MIRI, {}, (64, 72), LABEL) is None
    assert layouts.miri_reference_columns({"INSTRUME": "NIRCAM"}, {}, (1024, 1032),
                                          LABEL) is None


@pytest.mark.parametrize("start,width,message", [
    (0, 72, "jw_mirimage_rate.fits[SCI]: SUBSTRT1 = 0 is not a column of the MIRI detector "
            "(a whole number from 1); its reference columns cannot be placed; refused"),
    ("left", 72, "jw_mirimage_rate.fits[SCI]: SUBSTRT1 = 'left' is not a column of the MIRI "
                 "detector (a whole number from 1); its reference columns cannot be placed; "
                 "refused"),
    (1000, 72, "jw_mirimage_rate.fits[SCI]: a MIRI frame of 72 columns from SUBSTRT1 = 1000 "
               "runs past the detector's 1032 columns; refused"),
])
def test_miri_refused_in_one_line(start, width, message):
    with pytest.raises(IPCInputError) as err:
        layouts.layout_of(dict(MIRI, SUBSTRT1=start), {}, (64, width), LABEL)
    assert str(err.value) == message


def test_border_mask():
    mask = layouts.border_mask((6, 7), 1, 2, 0, 3)
    assert mask[:, 0].all() and mask[:, 5:].all() and mask[3:].all()
    assert mask.sum() == 6 * 7 - 3 * 4
    assert layouts.border_mask((3, 3), 9, 0, 0, 0).all()


def test_ramp_dq_all_good_when_missing():
    model = datamodels.RampModel()  # as the pipeline's test fixtures make it
    model.data = np.ones((2, 3, 8, 10), dtype=np.float32)
    assert model.pixeldq is None and model.groupdq is None
    pixeldq, groupdq = layouts.ramp_dq(model)
    assert pixeldq.shape == (8, 10) and pixeldq.dtype == np.uint32 and not pixeldq.any()
    assert groupdq.shape == (2, 3, 8, 10) and groupdq.dtype == np.uint8 and not groupdq.any()
    assert model.pixeldq is None  # the model is left as it is


def test_ramp_dq_the_models_own():
    model = datamodels.RampModel((1, 2, 8, 10))
    model.pixeldq[2, 3] = 1
    model.groupdq[0, 1, 4, 5] = 4
    pixeldq, groupdq = layouts.ramp_dq(model)
    assert pixeldq[2, 3] == 1 and pixeldq.sum() == 1
    assert groupdq[0, 1, 4, 5] == 4 and groupdq.sum() == 4


def test_ramp_dq_wrong_shape_refused():
    model = datamodels.RampModel()
    model.data = np.ones((1, 2, 8, 10), dtype=np.float32)
    model.meta.filename = "jw_bad_ramp.fits"
    model.pixeldq = np.zeros((8, 11), np.uint32)
    with pytest.raises(IPCInputError) as err:
        layouts.ramp_dq(model)
    assert str(err.value) == ("jw_bad_ramp.fits[PIXELDQ]: shape (8, 11) does not match the "
                              "science data's (8, 10); refused")


def test_ramp_keywords_irs2_fixture():
    """The pipeline's own IRS2 ``ipc`` fixture (no READPATT) is an IRS2 layout."""
    model = datamodels.RampModel()
    model.data = np.zeros((1, 2, 3200, 2048), dtype=np.float32)
    model.meta.instrument.name, model.meta.instrument.detector = "NIRSPEC", "NRS1"
    model.meta.exposure.nrs_normal, model.meta.exposure.nrs_reference = 16, 4
    layout = layouts.layout_of(layouts.ramp_keywords(model), None, model.data.shape,
                               "ramp[SCI]")
    assert layout.irs2 == irs2.IRS2Geometry(16, 4, "NRS1")

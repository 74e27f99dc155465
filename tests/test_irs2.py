"""NIRSpec IRS2 frames (ipc_taichi.products.irs2), against the JWST pipeline's own
``jwst.ipc.x_irs2`` and ``jwst.refpix.irs2_subtract_reference``, and the
decoupling of an IRS2 ramp: within 1 DN of the truth on every science pixel."""

import numpy as np
import pytest
from jwst.ipc import x_irs2
from jwst.refpix.irs2_subtract_reference import make_irs2_mask

import ipc_taichi
from ipc_taichi.datasets import star_field
from ipc_taichi.errors import IPCInputError
from ipc_taichi.products import irs2
from ipc_taichi.products.arrangement import arrangement_of

LABEL = "jw_irs2_uncal.fits[SCI]"
GAIN = 2.0  # e-/DN
LAW = "donlon2018"
HEADER = {"TELESCOP": "JWST", "INSTRUME": "NIRSPEC", "DETECTOR": "NRS1", "READPATT": "NRSIRS2",
          "NRS_NORM": 16, "NRS_REF": 4, "SUBARRAY": "FULL"}

# (NRS_NORM, NRS_REF): flight, the ground-test patterns NRSN8R2/NRSN32R8, and others
PATTERNS = [(16, 4), (8, 2), (32, 8), (4, 1), (16, 8), (2, 2)]


def header(**changes):
    h = dict(HEADER, **changes)
    return {k: v for k, v in h.items() if v is not None}


def test_full_frame_is_3200_by_2048():
    g = irs2.IRS2Geometry()
    assert (g.normal, g.reference, g.output_length, g.shape) == (16, 4, 640, (3200, 2048))
    rows = irs2.science_rows(g)
    assert rows.sum() == 2048
    assert not rows[:640].any() and rows[640:648].all() and not rows[648:652].any()
    assert rows[3192:].all()  # each output ends with n/2 science pixels
    rows2 = irs2.science_rows(irs2.IRS2Geometry(detector="NRS2"))
    assert not rows2[2560:].any() and rows2[:8].all()


@pytest.mark.parametrize("n,r", PATTERNS)
def test_science_rows_are_the_pipelines(n, r):
    g = irs2.IRS2Geometry(n, r, "NRS1")
    frame = np.zeros(g.shape, np.float32)
    expected = x_irs2.make_mask(frame, n=n, r=r)
    np.testing.assert_array_equal(irs2.science_rows(g), expected)
    np.testing.assert_array_equal(irs2.science_rows(irs2.IRS2Geometry(n, r, "NRS2")),
                                  expected[::-1])
    # refpix's own mask (detector orientation: the long axis is x)
    np.testing.assert_array_equal(irs2.science_rows(g), make_irs2_mask(g.length, 2048, n, r))
    # each output's pattern reads the same in both directions
    one = irs2.science_rows(g)[g.output_length:2 * g.output_length]
    np.testing.assert_array_equal(one, one[::-1])


@pytest.mark.parametrize("detector", ["NRS1", "NRS2"])
def test_science_image_and_interleave_match_x_irs2(detector):
    g = irs2.IRS2Geometry(16, 4, detector)
    rng = np.random.default_rng(3)
    ramp = rng.normal(1000.0, 50.0, (1, 2) + g.shape).astype(np.float32)
    mask = x_irs2.make_mask(ramp)
    science = irs2.science_image(ramp, g)
    np.testing.assert_array_equal(science, x_irs2.from_irs2(ramp, mask, detector))
    corrected = science * 1.5 + 7.0
    expected = ramp.copy()
    x_irs2.to_irs2(expected, corrected, mask, detector)
    out = irs2.interleave(corrected, ramp, g)
    assert out.dtype == ramp.dtype and out is not ramp
    np.testing.assert_array_equal(out.view(np.uint32), expected.view(np.uint32))


def test_reference_samples_kept_bit_for_bit():
    g = irs2.IRS2Geometry()
    rng = np.random.default_rng(4)
    bits = rng.integers(0, 2 ** 32, g.shape, dtype=np.uint64).astype(np.uint32)
    frame = bits.view(np.float32)  # NaN payloads, denormals, negative zero among them
    before = frame.copy()
    out = irs2.interleave(np.zeros((2048, 2048)), frame, g)
    reference = ~irs2.science_rows(g)
    np.testing.assert_array_equal(out[reference].view(np.uint32), bits[reference])
    assert (out[~reference] == 0).all()
    np.testing.assert_array_equal(frame.view(np.uint32), before.view(np.uint32))


def test_pixeldq_de_interleaved_like_the_data():
    g = irs2.IRS2Geometry()
    pixeldq = np.zeros(g.shape, np.uint32)
    pixeldq[irs2.science_rows(g)] = 7
    assert (irs2.science_image(pixeldq, g) == 7).all()


def test_recognised_from_the_headers():
    assert irs2.irs2_geometry(header(), {}, (2, 5, 3200, 2048), LABEL) == irs2.IRS2Geometry()
    g = irs2.irs2_geometry(header(READPATT="NRSIRS2RAPID", DETECTOR="NRS2", NRS_NORM="8",
                                  NRS_REF=2.0), {}, (3200, 2048), LABEL)
    assert g == irs2.IRS2Geometry(8, 2, "NRS2")
    # missing NRS_NORM / NRS_REF: the flight values, as the pipeline assumes
    assert irs2.irs2_geometry(header(NRS_NORM=None, NRS_REF=None), {}, (3200, 2048),
                              LABEL) == irs2.IRS2Geometry()
    # no READPATT (the pipeline's test fixtures): the NIRSpec shape says IRS2
    assert irs2.irs2_geometry(header(READPATT=None), {}, (3200, 2048), LABEL) is not None
    # the science header comes first
    assert irs2.irs2_geometry(header(), {"DETECTOR": "NRS2"}, (3200, 2048),
                              LABEL).detector == "NRS2"


def test_not_interleaved():
    # a rate file of an IRS2 exposure: the pipeline removed the reference samples
    assert irs2.irs2_geometry(header(), {}, (2048, 2048), LABEL) is None
    assert irs2.irs2_geometry(header(READPATT="NRS"), {}, (2048, 2048), LABEL) is None
    assert irs2.irs2_geometry({"INSTRUME": "NIRCAM"}, {}, (4096, 4096), LABEL) is None
    assert irs2.irs2_geometry({}, {}, (3200, 2048), LABEL) is None
    assert irs2.irs2_geometry(header(), {}, (2048,), LABEL) is None


REFUSALS = [
    (header(), (3200, 512),
     "jw_irs2_uncal.fits[SCI]: an IRS2 frame (NRSIRS2) of 3200x512 pixels, not the full frame "
     "of 3200x2048 that NRS_NORM = 16 and NRS_REF = 4 give (rows x columns, DMS orientation): "
     "its reference samples cannot be placed; refused"),
    (header(), (2048, 3200),
     "jw_irs2_uncal.fits[SCI]: an IRS2 frame (NRSIRS2) of 2048x3200 pixels, not the full frame "
     "of 3200x2048 that NRS_NORM = 16 and NRS_REF = 4 give (rows x columns, DMS orientation): "
     "its reference samples cannot be placed; refused"),
    (header(NRS_REF=8), (3200, 2048),
     "jw_irs2_uncal.fits[SCI]: an IRS2 frame (NRSIRS2) of 3200x2048 pixels, not the full frame "
     "of 3840x2048 that NRS_NORM = 16 and NRS_REF = 8 give (rows x columns, DMS orientation): "
     "its reference samples cannot be placed; refused"),
    (header(READPATT=None, NRS_NORM=None, NRS_REF=None), (2600, 2048),
     "jw_irs2_uncal.fits[SCI]: an IRS2 frame (no READPATT) of 2600x2048 pixels, not the full "
     "frame of 3200x2048 that NRS_NORM = 16 and NRS_REF = 4 give (rows x columns, DMS "
     "orientation): its reference samples cannot be placed; refused"),
    (header(NRS_NORM=13), (3200, 2048),
     "jw_irs2_uncal.fits[SCI]: IRS2 with NRS_NORM = 13: only an even NRS_NORM that divides 512 "
     "gives interleaving that does not depend on each output's readout direction; refused"),
    (header(NRS_NORM=24), (3200, 2048),
     "jw_irs2_uncal.fits[SCI]: IRS2 with NRS_NORM = 24: only an even NRS_NORM that divides 512 "
     "gives interleaving that does not depend on each output's readout direction; refused"),
    (header(NRS_REF="four"), (3200, 2048),
     "jw_irs2_uncal.fits[SCI]: NRS_REF = 'four' is not a positive whole number; the IRS2 "
     "interleaving cannot be placed; refused"),
    (header(NRS_NORM=0), (3200, 2048),
     "jw_irs2_uncal.fits[SCI]: NRS_NORM = 0 is not a positive whole number; the IRS2 "
     "interleaving cannot be placed; refused"),
    (header(DETECTOR="NRCA1"), (3200, 2048),
     "jw_irs2_uncal.fits[SCI]: an IRS2 frame with DETECTOR = NRCA1: the interleaving order is "
     "known for NRS1 and NRS2 only; refused"),
    (header(DETECTOR=None), (3200, 2048),
     "jw_irs2_uncal.fits[SCI]: an IRS2 frame with DETECTOR = (none): the interleaving order is "
     "known for NRS1 and NRS2 only; refused"),
    (header(READPATT="NRSRAPID"), (3200, 2048),
     "jw_irs2_uncal.fits[SCI]: a NIRSpec frame of 3200x2048 pixels, longer than the detector's "
     "2048, with READPATT = NRSRAPID, not an IRS2 pattern: where its reference samples lie is "
     "unknown; refused"),
]


@pytest.mark.parametrize("primary,shape,message", REFUSALS)
def test_refused_in_one_line(primary, shape, message):
    with pytest.raises(IPCInputError) as err:
        irs2.irs2_geometry(primary, {}, shape, LABEL)
    assert str(err.value) == message
    with pytest.raises(IPCInputError, match="refused$"):
        arrangement_of(primary, {}, shape, LABEL)


def test_wrong_shapes_refused():
    g = irs2.IRS2Geometry()
    with pytest.raises(IPCInputError, match=r"^frames of shape \(2048, 2048\) are not an IRS2"):
        irs2.science_image(np.zeros((2048, 2048)), g)
    with pytest.raises(IPCInputError, match=r"^IRS2 science image of shape \(2048, 2047\)"):
        irs2.interleave(np.zeros((2048, 2047)), np.zeros(g.shape), g)


def _irs2_ramp(truth_e, geometry, rng):
    """A bias-free IRS2 ramp in DN: ``truth_e`` (groups, 2048, 2048) coupled in
    the contiguous science image, reference samples around 0 DN."""
    science = ipc_taichi.couple(truth_e, law=LAW) / GAIN
    reference = rng.normal(0.0, 20.0, (1,) + truth_e.shape[:1] + geometry.shape)
    return irs2.interleave(science[None].astype(np.float32), reference.astype(np.float32),
                           geometry)


@pytest.mark.parametrize("detector", ["NRS1", "NRS2"])
def test_irs2_ramp_decoupled_within_1_dn(cpu, detector):
    """Truth -> couple (contiguous) -> interleave -> arrangement -> decouple ->
    re-interleave: every science pixel within 1 DN of the truth, every reference
    sample bit for bit; decoupling the interleaved frame as if contiguous (the
    old behaviour) is far off."""
    rng = np.random.default_rng(11)
    truth = star_field(2048, seed=7, n_per_mpix=4000, background=200.0)
    b = 4  # the reference border collects no charge
    truth[:b] = truth[-b:] = 0.0
    truth[:, :b] = truth[:, -b:] = 0.0
    truth_e = truth[None] * np.array([0.5, 1.0])[:, None, None]  # two groups of a ramp
    arrangement = arrangement_of(header(DETECTOR=detector), {}, (1, 2, 3200, 2048), LABEL)
    assert arrangement.kind == "irs2" and arrangement.science_shape == (2048, 2048)
    ramp = _irs2_ramp(truth_e, arrangement.irs2, rng)

    science_e = arrangement.to_science(ramp)[0].astype(np.float64) * GAIN
    decoupled = ipc_taichi.decouple(science_e, law=LAW) / GAIN
    out = arrangement.from_science(decoupled[None].astype(np.float32), ramp)

    truth_dn = truth_e / GAIN
    error = np.abs(x_irs2.from_irs2(out, x_irs2.make_mask(out), detector)[0] - truth_dn)
    assert error.max() < 1.0
    reference = ~irs2.science_rows(arrangement.irs2)
    np.testing.assert_array_equal(out[..., reference, :].view(np.uint32),
                                  ramp[..., reference, :].view(np.uint32))

    naive = ipc_taichi.decouple(ramp[0].astype(np.float64) * GAIN, law=LAW) / GAIN
    naive_error = np.abs(arrangement.to_science(naive) - truth_dn)
    uncorrected = np.abs(arrangement.to_science(ramp)[0] - truth_dn)
    assert naive_error.max() > 100.0  # DN, on the science rows beside the reference samples
    assert (naive_error > 1.0).mean() > 0.03
    assert (uncorrected > 1.0).mean() > 0.05  # the coupling itself is well above 1 DN

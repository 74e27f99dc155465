"""One product plan for every path (issue 27 items 1 and 5, issue 29 item 3).

The command line (``ipc-taichi decouple``) and the ``stpipe`` Step give bit-identical
science and the same IPC keywords and HISTORY on a real FGS flight ramp (a subarray
inside the detector), a full-frame NIRCam ramp and a rate file at the detector's
corner; a DQ name the file's own DQ_DEF lacks is said, never taken from JWST's
table; a slit cut-out's geometry is its own header's; the keyword of the science
region says so; Roman's conventions live in ``missions``.
"""

import ast
import os
import re

import numpy as np
import pytest
from astropy.io import fits
from stdatamodels.jwst.datamodels import ImageModel, RampModel

from ipc_taichi.model import CouplingModel
from ipc_taichi.products import missions, plan
from ipc_taichi.products.jwst_step import IPCTaichiStep
from ipc_taichi.reference import couple_reference

DATA = os.path.join(os.path.dirname(__file__), "data")
FGS = os.path.join(DATA, "jwst_fgs_guider2_acq1.fits")
DARK = os.path.join(DATA, "jwst_nirspec_nrs1_dark_sub512.fits")
FGS_GAIN = 1.57  # e-/DN, GUIDER2 (tests/data/PROVENANCE.md)
STAMP = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ ")


def _model_file(tmp_path, law="donlon2018"):
    path = tmp_path / "det.json"
    CouplingModel.resolve(law).save(path)  # the file's edge is 'zero'
    return path


def _ipc_cards(header):
    return {k: header[k] for k in header if k.startswith("IPC") or k == "S_IPC"}


def _history(header):
    lines = [str(c) for c in header.get("HISTORY", [])]
    start = next(k for k, line in enumerate(lines) if " ipc_taichi " in line)
    return [STAMP.sub("", line) for line in lines[start:]]


def _same(cli, tmp_path, src, gain, model, **step_args):
    """Decouple ``src`` by the command line and by the Step; both outputs."""
    out_cli, out_step = tmp_path / "cli.fits", tmp_path / "step.fits"
    r = cli("decouple", src, out_cli, "--model", model, "--gain", gain)
    assert r.returncode == 0, r.stderr
    result = IPCTaichiStep.call(str(src), gain=gain, model=str(model), **step_args)
    result.save(out_step)
    with fits.open(out_cli) as a, fits.open(out_step) as b:
        sci_a, sci_b = a["SCI"].data, b["SCI"].data
        assert sci_a.dtype == sci_b.dtype
        assert np.array_equal(sci_a, sci_b, equal_nan=True)  # bit-identical science
        assert _ipc_cards(b[0].header) == _ipc_cards(a[0].header)
        assert _ipc_cards(b["SCI"].header) == _ipc_cards(a["SCI"].header)
        assert _history(b[0].header) == _history(a[0].header)
        return dict(a[0].header), dict(a["SCI"].header), np.asarray(sci_a), \
            np.asarray(fits.getdata(src, "SCI"))


def test_fgs_flight_ramp_same_by_cli_and_step(cli, tmp_path):
    """The real FGS ramp, a 128x128 subarray inside the detector (SUBSTRT 887,
    1022): no reference border, so both give it the ``isolated`` edge. Before,
    the Step kept the model file's ``zero`` and differed by up to 0.74 DN within
    3 pixels of the edge, and its output carried no IPC keyword or HISTORY."""
    ramp = RampModel(FGS)
    data = np.asarray(ramp.data, dtype=np.float32)
    ramp.data = data - data.min(axis=(0, 1))  # as if bias-subtracted (no superbias known)
    ramp.meta.cal_step.superbias = "COMPLETE"
    src = tmp_path / "jw01019_fgs_ramp.fits"
    ramp.save(src)
    primary, sci, got, before = _same(cli, tmp_path, src, FGS_GAIN, _model_file(tmp_path))
    assert primary["IPCEDGE"] == "isolated" and "subarray" in primary["IPCEDGER"]
    assert primary["S_IPC"] == "COMPLETE"
    assert sci["IPCSCIRG"] == "[1:128,1:128]" and sci["IPCNREF"] == "0 0 0 0"
    assert "IPCREFPX" not in sci
    assert got.shape == (6, 2, 128, 128)
    assert np.abs(got - before).max() > 1.0  # corrected (hot pixels lose their ring)


def _nircam_full(tmp_path, rng):
    shape = (2048, 2048)
    truth = np.zeros(shape)
    truth[4:-4, 4:-4] = rng.uniform(0, 20000, (2040, 2040))
    ramp = RampModel((1, 2) + shape)
    ramp.data = np.stack([couple_reference(truth * (g + 1) / 2, law="constant:0.006")
                          / 2.0 for g in range(2)])[np.newaxis].astype(np.float32)
    ramp.meta.instrument.name, ramp.meta.instrument.detector = "NIRCAM", "NRCA1"
    ramp.meta.subarray.name = "FULL"
    ramp.meta.subarray.xstart = ramp.meta.subarray.ystart = 1
    ramp.meta.subarray.xsize = ramp.meta.subarray.ysize = 2048
    ramp.meta.bunit_data = "DN"
    ramp.meta.cal_step.superbias = "COMPLETE"
    src = tmp_path / "jw_nrca1_ramp.fits"
    ramp.save(src)
    return src


def test_full_frame_ramp_same_by_cli_and_step(cli, tmp_path, rng):
    """A 2048x2048 NIRCam ramp without REFERENCE_PIXEL flags: the 4-pixel
    border from the convention, ``zero`` edge, on both paths."""
    src = _nircam_full(tmp_path, rng)
    model = _model_file(tmp_path, "constant:0.006")
    primary, sci, got, before = _same(cli, tmp_path, src, 2.0, model)
    assert primary["IPCEDGE"] == "zero" and "reference pixels" in primary["IPCEDGER"]
    assert sci["IPCSCIRG"] == "[5:2044,5:2044]" and sci["IPCNREF"] == "4 4 4 4"
    assert np.array_equal(got[..., :4, :], before[..., :4, :])  # reference rows untouched


def test_rate_file_same_by_cli_and_step(cli, tmp_path, rng):
    """A rate (DN/s, EFFINTTM) of a subarray at the detector's corner, with
    DQ, ERR and variances: two reference sides, ``zero`` edge."""
    shape = (64, 64)
    truth = rng.uniform(0, 30000, shape)
    rate = ImageModel(shape)
    rate.data = (couple_reference(truth) / (2.0 * 100.0)).astype(np.float32)
    dq = np.zeros(shape, dtype=np.uint32)
    dq[30, 32] = 1  # DO_NOT_USE
    rate.dq = dq
    rate.err = np.full(shape, 0.5, dtype=np.float32)
    rate.meta.instrument.name, rate.meta.instrument.detector = "NIRCAM", "NRCA1"
    rate.meta.subarray.name = "SUB64P"
    rate.meta.subarray.xstart = rate.meta.subarray.ystart = 1
    rate.meta.subarray.xsize = rate.meta.subarray.ysize = 64
    rate.meta.exposure.integration_time = 100.0
    rate.meta.bunit_data = "DN/s"
    src = tmp_path / "jw_nrca1_rate.fits"
    rate.save(src)
    primary, sci, got, before = _same(cli, tmp_path, src, 2.0, _model_file(tmp_path))
    assert sci["IPCSCIRG"] == "[5:64,5:64]" and sci["IPCNREF"] == "4 0 4 0"
    assert sci["IPCTIME"] == 100.0 and primary["IPCEDGE"] == "zero"
    assert got[30, 32] == before[30, 32]


def test_step_records_what_the_cli_records(tmp_path, rng):
    """The Step's output carries the run (before: no IPC keyword, no HISTORY),
    each HISTORY card whole."""
    ramp = RampModel((1, 2, 24, 28))
    ramp.data = rng.uniform(0, 5000, (1, 2, 24, 28)).astype(np.float32)
    ramp.meta.instrument.name = "NIRCAM"
    ramp.meta.cal_step.superbias = "COMPLETE"
    result = IPCTaichiStep.call(ramp, gain=2.0, law="constant:0.006")
    result.save(tmp_path / "out.fits")
    h = fits.getheader(tmp_path / "out.fits")
    assert h["S_IPC"] == "COMPLETE" and h["IPCOP"] == "decouple" and h["IPCCONV"]
    assert h["IPCLAW"].startswith("constant") and h["IPCEDGE"] == "isolated"
    cards = [str(c) for c in h["HISTORY"]]
    assert any("ipc_taichi" in c and "decouple" in c for c in cards)
    assert any("DN -> electrons (gain 2 e-/DN)" in c for c in cards)
    assert all(len(c) <= 70 for c in cards)
    assert fits.getheader(tmp_path / "out.fits", "SCI")["IPCSCIRG"] == "[1:28,1:24]"


# --- DQ names by the file's own DQ_DEF


def test_dq_def_lacking_a_name_is_said(cli, tmp_path):
    """The real NIRSpec dark's DQ_DEF defines WARM = 2 and no SATURATED: the
    default ``DO_NOT_USE,SATURATED`` leaves out bit 1 only and says so in one
    line (before: SATURATED became JWST's bit 2 and 376 warm pixels were left
    out silently)."""
    out = tmp_path / "out.fits"
    r = cli("decouple", DARK, out, "--law", "constant:0.006", "--gain", 1.0)
    assert r.returncode == 0, r.stderr
    line = (f"ipc-taichi: warning: {DARK}[DQ_DEF]: defines no SATURATED: not left out (this "
            "file's flags: DO_NOT_USE = 1, WARM = 2, HOT = 4, UNRELIABLE_SLOPE = 8, "
            "UNRELIABLE_DARK = 16, BAD_REF_PIXEL = 32); give --dq-bits with its names or "
            "bit values")
    assert line in r.stderr.splitlines()
    assert fits.getheader(out)["IPCDQBIT"] == 1
    dq = fits.getdata(DARK, "DQ")
    warm = (dq & 2) != 0
    assert warm.sum() == 376
    got, before = fits.getdata(out, "SCI"), fits.getdata(DARK, "SCI")
    assert (got[-1][warm] != before[-1][warm]).any()  # the warm pixels are corrected


def test_dq_bits_of_reads_the_files_table_alone():
    mission = missions.Mission("JWST", "NIRSPEC", True, dict(missions.JWST_DQ_FLAGS),
                               {"DO_NOT_USE": 1, "WARM": 2, "HOT": 4})
    assert plan.dq_bits_of("DO_NOT_USE,SATURATED,HOT", mission) == (5, ["SATURATED"])
    assert plan.dq_bits_of("3", mission) == (3, [])
    with pytest.raises(ValueError, match="unknown flag 'SATURATD'"):
        plan.dq_bits_of("SATURATD", mission)
    jwst = missions.Mission("JWST", "NIRCAM", True, dict(missions.JWST_DQ_FLAGS))
    assert plan.dq_bits_of("DO_NOT_USE,SATURATED", jwst) == (3, [])


# --- geometry from the science header's own keywords


def test_slit_cutout_gets_no_border_from_the_exposure(cli, tmp_path, rng):
    """An MSA slit cut-out inside the detector (its own SLTSTRT1/2) in a file
    whose primary header describes the whole full-frame exposure (SUBSTRT 1):
    no reference border (before: 4 pixels on two sides, from the primary)."""
    primary = fits.Header({"TELESCOP": "JWST", "INSTRUME": "NIRSPEC", "SUBARRAY": "FULL",
                           "SUBSTRT1": 1, "SUBSTRT2": 1, "SUBSIZE1": 2048, "SUBSIZE2": 2048})
    truth = rng.uniform(0, 20000, (20, 40))
    sci = fits.ImageHDU(couple_reference(truth, law="constant:0.006", edge="isolated"),
                        name="SCI")
    sci.header["BUNIT"] = "electrons"
    sci.header["SLTSTRT1"], sci.header["SLTSTRT2"] = 1200, 600
    src, out = tmp_path / "slit.fits", tmp_path / "out.fits"
    fits.HDUList([fits.PrimaryHDU(header=primary), sci]).writeto(src)
    r = cli("decouple", src, out, "--law", "constant:0.006")
    assert r.returncode == 0, r.stderr
    h = fits.getheader(out, "SCI")
    assert h["IPCSCIRG"] == "[1:40,1:20]" and fits.getheader(out)["IPCEDGE"] == "isolated"
    assert np.abs(fits.getdata(out, "SCI") - truth).max() <= 2e-5 * truth.max()


def test_primary_geometry_applies_when_it_describes_the_array():
    jwst = missions.recognise(fits.Header({"TELESCOP": "JWST", "INSTRUME": "NIRCAM"}))
    product = {"SUBSTRT1": 1, "SUBSTRT2": 1, "SUBSIZE1": 64, "SUBSIZE2": 32}.get
    facts = plan.ArrayFacts(1, "SCI", "f[SCI]", (32, 64), lambda k: None, product)
    region = plan.science_region_of((32, 64), jwst, facts)
    assert region.widths == (4, 0, 4, 0) and region.beyond == "reference"
    other = plan.ArrayFacts(1, "SCI", "f[SCI]", (20, 40), lambda k: None, product)
    assert plan.science_region_of((20, 40), jwst, other).widths == (0, 0, 0, 0)


# --- the edge, decided once


def test_edge_of_the_frame():
    model = CouplingModel.resolve("constant:0.006")  # asks for 'zero' (the default)
    jwst = missions.recognise(fits.Header({"TELESCOP": "JWST", "INSTRUME": "NIRCAM"}))
    plain = missions.recognise(fits.Header())
    whole = plan.science_region_of((16, 16), jwst)
    assert whole.beyond == "pixels"
    assert plan.edge_of(model, None, whole)[0].edge == "isolated"
    assert plan.edge_of(model, "zero", whole)[0].edge == "zero"  # asked for
    assert plan.edge_of(model, None, plan.science_region_of((16, 16), plain))[0].edge == "zero"
    border = plan.science_region_of((16, 16), jwst, refpix=2)
    assert plan.edge_of(model, "isolated", border) == (
        CouplingModel(model.law, model.geometry, "zero"),
        "reference pixels (--refpix 2): zero-signal neighbours")


# --- Roman's conventions in missions


def test_roman_conventions_live_in_missions():
    roman = missions.roman_mission()
    science = plan.science_region_of(missions.ROMAN["science_area"], roman,
                                     plan.ArrayFacts(0, "data", "r[data]", (4088, 4088)))
    assert science.beyond == "reference" and science.widths == (0, 0, 0, 0)
    model = CouplingModel.resolve("constant:0.006", edge="isolated")
    assert plan.edge_of(model, None, science)[0].edge == "zero"
    full = plan.science_region_of(missions.ROMAN["full_frame"], roman,
                                  plan.ArrayFacts(0, "data", "r[data]", (2, 4096, 4096)))
    assert full.widths == (4, 4, 4, 4)
    keys = missions.roman_keywords("ImageModel", {"exposure": {
        "effective_exposure_time": -999999.0, "exposure_time": 139.8}})
    assert keys("BUNIT") == "DN/s" and keys("effective_exposure_time") is None
    assert keys("exposure_time") == 139.8
    here = os.path.dirname(missions.__file__)
    for name in ("roman.py", "plan.py", "fits.py", "jwst_step.py"):  # no Roman number in code
        with open(os.path.join(here, name)) as f:
            tree = ast.parse(f.read())
        constants = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)}
        assert not constants & {4096, 4088, "effective_exposure_time"}, name

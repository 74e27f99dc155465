"""Every :class:`ProductOptions` field, through every reader, changes the output or is refused.

The readers are the three that apply the product plan: FITS
(:func:`~ipc_taichi.products.process_fits`), Roman ASDF
(:func:`~ipc_taichi.products.process_asdf`) and the JWST Step's
(:func:`~ipc_taichi.products.jwst_step.correct_model`). Each field is turned
from its base value to another one on a small synthetic product where it
applies (a rate; a ramp for ``warm_start``), and the run either changes
what it should (the science data, the noise arrays, the output dtype, the
progress reported, the existing output replaced) or refuses the option in
one :class:`~ipc_taichi.errors.IPCInputError`. A reader that drops a field
silently (as Roman and the Step dropped ``pedestal`` at a53f084) fails here;
a field added to :class:`ProductOptions` without an entry in :data:`SPECS`
fails :func:`test_every_field_has_a_spec`.
"""

import dataclasses

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.errors import ArchUnavailableError, IPCInputError
from ipc_taichi.gpus import cuda_present
from ipc_taichi.model import CouplingModel
from ipc_taichi.products import ProductOptions, process_asdf, process_fits
from ipc_taichi.reference import couple_reference
from tests.helpers import optional

SHAPE = (24, 20)
GAIN, EXPTIME = 2.0, 10.0
DO_NOT_USE = 1
FLAGGED, WILD = (5, 6), (12, 9)  # a flagged junk pixel; an unflagged unphysical one
BASE = dict(gain=GAIN)
MODEL = CouplingModel.resolve("donlon2018")
# the inputs hold what the rules warn about (an unphysical pixel; max_iter=2)
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _truth(rng):
    return rng.uniform(2000, 60000, SHAPE)


def _rate_arrays(seed=7):
    """DN/s, a flagged junk pixel, an unphysical one (5e6 e-), err."""
    rng = np.random.default_rng(seed)
    rate = couple_reference(_truth(rng)) / (GAIN * EXPTIME)
    rate[FLAGGED] = 1e4
    rate[WILD] = 5e6 / (GAIN * EXPTIME)
    dq = np.zeros(SHAPE, np.uint32)
    dq[FLAGGED] = DO_NOT_USE
    err = rng.uniform(0.5, 1.0, SHAPE)
    return rate.astype(np.float32), dq, err.astype(np.float32)


def _ramp_arrays(seed=8):
    """(1, 3) groups in DN, charge growing."""
    rng = np.random.default_rng(seed)
    truth = _truth(rng) / 3
    data = np.stack([couple_reference(truth * (g + 1)) / GAIN for g in range(3)])[np.newaxis]
    return data.astype(np.float32)


# --- the JWST datamodel (the Step's input, and the FITS file saved from it) ------------------


def _jwst(kind):
    dm = pytest.importorskip("stdatamodels.jwst.datamodels", reason=optional("stdatamodels"))
    if kind == "rate":
        rate, dq, err = _rate_arrays()
        m = dm.ImageModel(SHAPE)
        m.data, m.dq, m.err = rate, dq, err
        m.meta.exposure.integration_time = EXPTIME
        m.meta.bunit_data = "DN/s"
    else:
        data = _ramp_arrays()
        m = dm.RampModel(data.shape)
        m.data = data
        m.pixeldq = np.zeros(SHAPE, np.uint32)
        m.groupdq = np.zeros(data.shape, np.uint8)
        m.meta.bunit_data = "DN"
        m.meta.cal_step.superbias = "COMPLETE"
    m.meta.telescope = "JWST"
    m.meta.instrument.name = "NIRCAM"
    m.meta.filename = f"jw_{kind}.fits"
    return m


def _fits_input(tmp_path, kind):
    path = tmp_path / f"jw_{kind}.fits"
    _jwst(kind).save(str(path))
    if kind == "rate":  # a second science array: what --hdu chooses among
        with fits.open(path, mode="append") as hdul:
            sci2 = fits.ImageHDU(hdul["SCI"].data * np.float32(0.5), hdul["SCI"].header,
                                 name="SCI")
            sci2.header["EXTVER"] = 2
            hdul.append(sci2)
    return path


def _roman_input(tmp_path, kind):
    rdm = pytest.importorskip("roman_datamodels.datamodels", reason=optional("roman_datamodels"))
    if kind == "rate":
        rate, dq, err = _rate_arrays()
        m = rdm.ImageModel.create_fake_data(shape=SHAPE)
        m.data, m.dq = rate, dq
        m.err = err.astype(m.err.dtype)
        m.meta.exposure.effective_exposure_time = EXPTIME
    else:
        data = _ramp_arrays()[0]
        m = rdm.RampModel.create_fake_data(shape=data.shape)
        m.data = data
        m.pixeldq = np.zeros(SHAPE, np.uint32)
        m.groupdq = np.zeros(data.shape, np.uint8)
    path = tmp_path / f"r_{kind}.asdf"
    m.save(path)
    return path


# --- one run of a reader: what it changed ---------------------------------------------------


@dataclasses.dataclass
class Result:
    data: list  # the science arrays written
    err: np.ndarray = None
    reported: int = 0


def _run_fits(tmp_path, kind, options, out_name="out"):
    src, out = tmp_path / f"jw_{kind}.fits", tmp_path / f"{out_name}.fits"
    if not src.exists():
        _fits_input(tmp_path, kind)
    process_fits(src, out, model=MODEL, options=options)
    with fits.open(out) as hdul:
        data = [np.array(h.data) for h in hdul if h.name == "SCI"]
        err = np.array(hdul["ERR"].data) if "ERR" in hdul else None
    return Result(data, err)


def _run_roman(tmp_path, kind, options, out_name="out"):
    rdm = pytest.importorskip("roman_datamodels.datamodels", reason=optional("roman_datamodels"))
    src, out = tmp_path / f"r_{kind}.asdf", tmp_path / f"{out_name}.asdf"
    if not src.exists():
        _roman_input(tmp_path, kind)
    process_asdf(src, out, model=MODEL, options=options)
    with rdm.open(out) as m:
        err = np.array(m.err) if kind == "rate" else None
        return Result([np.array(m.data)], err)


def _run_step(tmp_path, kind, options, out_name=None):
    pytest.importorskip("jwst", reason=optional("jwst"))
    from ipc_taichi.products.jwst_step import correct_model

    m = _jwst(kind)
    correct_model(m, MODEL, options)
    err = np.array(m.err) if kind == "rate" else None
    return Result([np.array(m.data)], err)


READERS = {"fits": _run_fits, "roman": _run_roman, "step": _run_step}

# field -> (input kind, the value changed to, what it changes: one effect, or reader -> effect)
# effects: data (the science arrays), err (the noise arrays), dtype (of the output),
# reported (a progress reporter told), overwrite (an existing output replaced; refused
# without), refused (one IPCInputError)
SPECS = {
    "hdu": ("rate", ("SCI", 1), {"fits": "data", "roman": "refused", "step": "refused"}),
    "overwrite": ("rate", True, {"fits": "overwrite", "roman": "overwrite", "step": "refused"}),
    "max_iter": ("rate", 2, "data"),
    "tol": ("rate", 1e-3, "data"),
    "arch": ("rate", "cuda", "arch"),
    "precision": ("rate", "f32", "data"),
    "tile": ("rate", 8, {"fits": "err", "roman": "refused", "step": "refused"}),
    "progress": ("rate", "reporter", "reported"),
    "dq_bits": ("rate", "none", "data"),
    "refpix": ("rate", 2, "data"),
    "gain": ("rate", 3.0, "data"),
    "exptime": ("rate", 20.0, "data"),
    "bunit": ("rate", "DN", "data"),
    "output_dtype": ("rate", "float64", {"fits": "dtype", "roman": "refused",
                                         "step": "refused"}),
    "pedestal": ("rate", 20000.0, "data"),
    "coadds": ("rate", 2, "data"),
    "saturation": ("rate", 1000.0, "data"),
    "unphysical": ("rate", "keep", "data"),
    "model_chosen": ("rate", False, "refused"),
    "edge": ("rate", "zero", "data"),
    "noise": ("rate", "keep", "err"),
    "warm_start": ("ramp", True, "data"),
}


_BASE = {}
"""(reader, input kind) -> the :class:`Result` of the base options."""


def test_every_field_has_a_spec():
    assert set(SPECS) == {f.name for f in dataclasses.fields(ProductOptions)}


def _differs(a, b):
    return any(x.shape != y.shape or not np.array_equal(x, y, equal_nan=True)
               for x, y in zip(a, b))


RESTARTS = ("arch", "precision")
"""Fields whose change restarts the runtime (every kernel compiled again, twice):
marked slow."""


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("field", [pytest.param(f, marks=pytest.mark.slow) if f in RESTARTS
                                   else f for f in sorted(SPECS)])
def test_every_option_changes_the_output_or_is_refused(tmp_path, reader, field, cpu):
    kind, value, effect = SPECS[field]
    effect = effect[reader] if isinstance(effect, dict) else effect
    run = READERS[reader]
    told = []
    if value == "reporter":
        value = lambda *a: told.append(a)  # noqa: E731
    base = ProductOptions.from_kwargs(**BASE)
    changed = base.replace(**{field: value})
    if effect == "arch":  # no GPU here: asked for explicitly, refused; else it runs there
        effect = "data" if cuda_present() else "refused"
    if effect == "refused":
        with pytest.raises((IPCInputError, ArchUnavailableError)):
            run(tmp_path, kind, changed, out_name="changed")
        return
    if effect == "overwrite":  # the base output exists: refused without, replaced with
        before = run(tmp_path, kind, base, out_name="base")
        with pytest.raises(IPCInputError, match="exists"):
            run(tmp_path, kind, base, out_name="base")
        after = run(tmp_path, kind, changed, out_name="base")
        assert not _differs(before.data, after.data)
        return
    if (reader, kind) not in _BASE:  # the same run for every field: made once
        _BASE[reader, kind] = run(tmp_path, kind, base, out_name="base")
    before = _BASE[reader, kind]
    after = run(tmp_path, kind, changed, out_name="changed")
    if effect == "data":
        assert _differs(before.data, after.data), f"{field} changed nothing ({reader})"
    elif effect == "err":
        assert not np.array_equal(before.err, after.err), f"{field}: err unchanged ({reader})"
    elif effect == "dtype":
        assert before.data[0].dtype != after.data[0].dtype
    elif effect == "reported":
        assert told, f"{field}: nothing reported ({reader})"
    else:
        raise AssertionError(effect)


# --- issue 37's faults: a bad option or header value is refused in one line naming it -------


def _plain(tmp_path, bunit="electron", gain=None, shape=(16, 16)):
    rng = np.random.default_rng(3)
    hdus = [fits.PrimaryHDU(), fits.ImageHDU(rng.uniform(1000, 30000, shape).astype(np.float32),
                                             name="SCI")]
    hdus[1].header["BUNIT"] = bunit
    if gain is not None:
        hdus[1].header["GAIN"] = gain
    path = tmp_path / "in.fits"
    fits.HDUList(hdus).writeto(path)
    return path


def _refused(r, tmp_path, *words):
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and "Traceback" not in line, line
    for w in words:
        assert w in line, line
    assert not (tmp_path / "out.fits").exists()
    return line


@pytest.mark.parametrize("args, named", [
    (("--pedestal", "nan"), "--pedestal nan"),
    (("--pedestal", "inf"), "--pedestal inf"),
    (("--pedestal", "1e9"), "--pedestal 1e9"),
    (("--coadds", "0"), "--coadds 0"),
    (("--coadds", "-2"), "--coadds -2"),
    (("--dq-bits", str(2 ** 32)), f"--dq-bits {2 ** 32}"),
    (("--dq-bits", f"DO_NOT_USE,{2 ** 40}"), f"--dq-bits {2 ** 40}"),
    (("--saturation=-5",), "--saturation -5"),
    (("--saturation", "nan"), "--saturation nan"),
])
def test_a_meaningless_option_is_refused_naming_it(cli, tmp_path, args, named):
    src = _plain(tmp_path)
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits", *args)
    _refused(r, tmp_path, named)


def test_a_header_gain_that_is_not_a_number_is_blamed_on_the_keyword(cli, tmp_path):
    src = _plain(tmp_path, bunit="DN", gain="abc")
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits")
    line = _refused(r, tmp_path, "header GAIN = 'abc'", "in.fits[SCI]")
    assert "--gain abc" not in line


def test_a_gain_image_with_no_usable_pixel_is_refused_naming_the_option(cli, tmp_path):
    src = _plain(tmp_path, bunit="DN")
    gain = tmp_path / "gain.fits"
    fits.PrimaryHDU(np.zeros((16, 16), np.float32)).writeto(gain)
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits", "--gain", gain)
    _refused(r, tmp_path, "--gain", "no usable pixel")


@pytest.mark.parametrize("lost", ["nan", "flagged"])
def test_one_lost_frame_of_a_stack_is_left_and_said_the_others_corrected(cli, tmp_path, lost):
    """An all-NaN frame of a stack, or an all-flagged integration of a rateints:
    the good frames are decoupled (as one frame alone would be), the lost one
    left as it came, said on the console and in the record."""
    rng = np.random.default_rng(4)
    cube = rng.uniform(1000, 30000, (3, 16, 16)).astype(np.float32)
    dq = np.zeros(cube.shape, np.uint32)
    if lost == "nan":
        cube[1] = np.nan
    else:
        dq[1] = DO_NOT_USE
    hdus = [fits.PrimaryHDU(), fits.ImageHDU(cube, name="SCI"), fits.ImageHDU(dq, name="DQ")]
    hdus[1].header["BUNIT"] = "electron"
    src, out = tmp_path / "ints.fits", tmp_path / "out.fits"
    fits.HDUList(hdus).writeto(src)
    r = cli("decouple", "--law", "donlon2018", src, out)
    assert r.returncode == 0, r.stderr
    assert "frame 1: no finite, unmasked pixel" in r.stderr and "left as it was" in r.stderr
    one = tmp_path / "one.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(cube[2], name="SCI")]).writeto(one)
    fits.setval(one, "BUNIT", value="electron", ext=1)
    assert cli("decouple", "--law", "donlon2018", one, tmp_path / "one_out.fits").returncode == 0
    with fits.open(out) as h, fits.open(tmp_path / "one_out.fits") as alone:
        got = h["SCI"].data
        np.testing.assert_array_equal(got[1], cube[1])  # as it came (NaN == NaN)
        np.testing.assert_array_equal(got[2], alone["SCI"].data)
        assert not np.array_equal(got[0], cube[0])
        history = "\n".join(h[0].header["HISTORY"])
        assert "frame     1: left as it was" in history
        assert h[0].header["S_IPC"] == "COMPLETE"


def test_every_frame_lost_is_still_refused(cli, tmp_path):
    cube = np.full((2, 8, 8), np.nan, np.float32)
    src = tmp_path / "ints.fits"
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(cube, name="SCI")]).writeto(src)
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits")
    _refused(r, tmp_path, "no finite, unmasked pixel")


# --- special and compressed input files ------------------------------------------------------


@pytest.mark.parametrize("special", ["/dev/zero", "fifo", "directory"])
def test_a_special_file_is_refused_before_it_is_read(cli, tmp_path, special):
    import os

    if special == "fifo":  # what <(zcat f.fits.gz) gives: opening it would wait for a writer
        special = tmp_path / "pipe"
        os.mkfifo(special)
    elif special == "directory":
        special = tmp_path / "d.fits"
        special.mkdir()
    r = cli("decouple", "--law", "donlon2018", special, tmp_path / "out.fits")
    _refused(r, tmp_path, str(special))


@pytest.mark.parametrize("packing", ["bz2", "zip"])
def test_bz2_and_zip_inputs_are_read_as_astropy_reads_them(cli, tmp_path, packing):
    import bz2
    import zipfile

    from ipc_taichi.cli.frames import output_name

    src = _plain(tmp_path)
    packed = tmp_path / f"in.fits.{packing}"
    if packing == "bz2":
        packed.write_bytes(bz2.compress(src.read_bytes()))
    else:
        with zipfile.ZipFile(packed, "w") as z:
            z.write(src, "in.fits")
    assert cli("decouple", "--law", "donlon2018", src, tmp_path / "plain.fits").returncode == 0
    r = cli("decouple", "--law", "donlon2018", packed, tmp_path / "out.fits")
    assert r.returncode == 0, r.stderr
    with fits.open(tmp_path / "out.fits") as a, fits.open(tmp_path / "plain.fits") as b:
        np.testing.assert_array_equal(a["SCI"].data, b["SCI"].data)
    assert output_name(str(packed), "d", "_x") == "d/in_x.fits"


# --- Roman ASDF ------------------------------------------------------------------------------


def test_an_asdf_input_with_a_fits_output_is_refused_before_the_work(cli, tmp_path, monkeypatch):
    from ipc_taichi.products import roman

    src = _roman_input(tmp_path, "rate")

    def work(*args, **kwargs):
        raise AssertionError("the work started")

    monkeypatch.setattr(roman, "correct_frames", work)
    r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits", "--gain", GAIN)
    _refused(r, tmp_path, "out.fits", ".asdf")


# --- what a run says: IRS2 cut-outs, header values, stale temporaries ------------------------


@pytest.mark.parametrize("shape", [(1, 2, 1600, 2048), (2048, 1600), (512, 512)])
def test_a_cut_of_an_irs2_frame_is_refused_not_taken_as_contiguous(shape):
    from ipc_taichi.products.arrangement import arrangement_of

    header = {"TELESCOP": "JWST", "INSTRUME": "NIRSPEC", "DETECTOR": "NRS1",
              "READPATT": "NRSIRS2", "NRS_NORM": 16, "NRS_REF": 4}
    with pytest.raises(IPCInputError, match=r"jw_uncal.fits\[SCI\]: an IRS2 frame .*refused"):
        arrangement_of(header, {}, shape, "jw_uncal.fits[SCI]")
    # the detector image (a rate, the samples removed by the pipeline) stays contiguous
    assert arrangement_of(header, {}, (2048, 2048), "x").identity


def _whole_prefix(card, text, separators):
    """``card`` is ``text`` whole, or a prefix of it ending before a separator, plus '...'."""
    if card == text:
        return True
    head = card.removesuffix("...")
    return card.endswith("...") and text.startswith(head) and text[len(head)] in separators


def test_header_values_are_never_cut_inside_a_number():
    from ipc_taichi.products import RunSettings
    from ipc_taichi.products.provenance import Provenance, card_text
    from tests.helpers import one_array_plan

    reason = ("reference pixels (NIRCam subarray SUB640 at x 1..640, y 1409..2048 of the "
              "detector): zero-signal neighbours")
    for width in range(20, len(reason) + 2):  # wider than its first word
        cut = card_text(reason, width)
        assert len(cut) <= width and _whole_prefix(cut, reason, " ,;"), (width, cut)
    model = CouplingModel.resolve("donlon2018", "horizontal=0.987654321,vertical=0.876543219,"
                                  "diagonal=0.0123456789,second=0.00234567891")
    plan = one_array_plan(model, (8, 8), "in.fits[SCI]", reason, "given: 20000.0 e-")
    # the record every reader writes (FITS, Roman, the Step)
    prov = Provenance(plan, RunSettings("decouple", 100, 1e-6))
    header = prov.primary(fits.Header())
    described = model.geometry.describe()
    assert len(described) > 68 and _whole_prefix(header["IPCGEOM"], described, ";"), header
    assert _whole_prefix(header["IPCEDGER"], reason, " ,;") and len(header["IPCEDGER"]) <= 60


def test_a_stale_temporary_of_a_killed_run_is_named_on_the_next(tmp_path, cli, caplog):
    src = _plain(tmp_path)
    stale = tmp_path / ".tmp-k1ll3d0aout.fits"  # what atomic_output names it
    stale.write_bytes(b"\0" * 2880 * 4)
    other = tmp_path / ".tmp-k1ll3d0bother.fits"  # another output's: not this run's business
    other.write_bytes(b"\0")
    with caplog.at_level("WARNING", logger="ipc_taichi"):
        r = cli("decouple", "--law", "donlon2018", src, tmp_path / "out.fits")
    assert r.returncode == 0, r.stderr
    said = [rec.getMessage() for rec in caplog.records if ".tmp-" in rec.getMessage()]
    assert len(said) == 1 and str(stale) in said[0] and "killed" in said[0], said
    assert stale.exists()  # named, never removed (another run may be writing it)


# --- a broken model file ---------------------------------------------------------------------


def _broken(doc, part):
    if part == "geometry pairs":
        doc["geometry"] = [[0, 1], [1, 0]]
    elif part == "geometry missing":
        del doc["geometry"]
    elif part == "table law":
        doc["law"] = {"kind": "table", "signal_min": 0.0, "table": [0.01, 0.01]}
    elif part == "table values":
        doc["law"] = {"kind": "table", "signal_min": 0.0, "signal_step": 100.0, "table": "abc"}
    else:
        del doc["law"]["floor"]
    return doc


@pytest.mark.parametrize("part, named", [
    ("geometry pairs", '"geometry": each entry must be [dy, dx, weight]'),
    ("geometry missing", 'no "geometry" list'),
    ("table law", 'a table law needs signal_min, signal_step, table: "signal_step" is missing'),
    ("table values", '"law" (table): a malformed value'),
    ("parametric law", 'a parametric law needs amp_diff'),
])
def test_a_broken_model_file_is_refused_naming_the_entry(cli, tmp_path, part, named):
    import json

    path = tmp_path / "m.json"
    path.write_text(json.dumps(_broken(MODEL.to_dict(), part)))
    src = _plain(tmp_path)
    r = cli("decouple", "--model", path, src, tmp_path / "out.fits")
    line = _refused(r, tmp_path, str(path), named)
    assert "KeyError" not in line and not line.rstrip(")").endswith("unpack")

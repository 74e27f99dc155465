"""Flat ramps read by sections (ipc_taichi.calibrate.stream) give what the
whole-file reader gives: the same charge and mask, the same block sums (to
summation order when a block is cut into row strips), the same noise sums of
the map; and the benchmark's generator writes ramps a detector would.

The sectioned path is forced on small files (``read_frames(..., sections=True)``;
``stream.STRIP_BYTES`` lowered to cut blocks into strips).
"""

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.bench import calfull
from ipc_taichi.calibrate import inputs, maps, rampsums, stream

SHAPE = (6, 48, 40)
"""Reads, rows, columns of each test ramp."""


def _ramp_file(path, seed, saturate=None, dq=True):
    """A raw uint16 DN ramp (1, 6, 48, 40) of a flat with a bias, a PIXELDQ
    flagging a few pixels DO_NOT_USE (1) and others HOT (2048, kept), a
    GROUPDQ saturating a few reads (2), a SATURATE level."""
    rng = np.random.default_rng(seed)
    ngroups, ny, nx = SHAPE
    charge = np.cumsum(rng.poisson(3000.0, (ngroups, ny, nx)), axis=0)
    dn = 9000 + rng.integers(-200, 200, (ny, nx)) + charge / 1.5 + rng.normal(0, 8, charge.shape)
    sci = fits.ImageHDU(np.clip(np.rint(dn), 0, 65535).astype(np.uint16)[None], name="SCI")
    sci.header["BUNIT"] = "DN"
    sci.header["GAIN"] = 1.5
    if saturate is not None:
        sci.header["SATURATE"] = saturate
    hdus = [fits.PrimaryHDU(), sci]
    if dq:
        pixel = np.zeros((ny, nx), np.uint32)
        pixel[rng.integers(0, ny, 6), rng.integers(0, nx, 6)] = 1
        pixel[rng.integers(0, ny, 6), rng.integers(0, nx, 6)] = 2048
        group = np.zeros((1, ngroups, ny, nx), np.uint8)
        group[0, rng.integers(1, ngroups, 5), rng.integers(0, ny, 5), rng.integers(0, nx, 5)] = 2
        hdus += [fits.ImageHDU(pixel, name="PIXELDQ"), fits.ImageHDU(group, name="GROUPDQ")]
    fits.HDUList(hdus).writeto(path)
    return str(path)


def _both(paths, monkeypatch):
    whole = [inputs.read_frames(p, role="flat") for p in paths]
    lazy = [inputs.read_frames(p, role="flat", sections=True) for p in paths]
    return whole, lazy


def test_flats_by_sections_when_all_together_are_large(tmp_path, monkeypatch):
    """The decision counts every flat (8 ramps of 671 MB at 2048^2 are 5 GB)."""
    paths = [_ramp_file(tmp_path / f"f{k}.fits", k, dq=False) for k in range(3)]
    one = 8 * np.prod(SHAPE)
    monkeypatch.setattr(stream, "STREAM_BYTES", 2 * one)
    assert stream.flats_by_sections(paths) and not stream.flats_by_sections(paths[:2])
    assert not stream.flats_by_sections([str(tmp_path / "missing.fits")])


@pytest.mark.parametrize("saturate", [None, 20000])
def test_sections_read_as_the_whole_file(tmp_path, monkeypatch, saturate):
    path = _ramp_file(tmp_path / "f.fits", 3, saturate=saturate)
    (whole,), (lazy,) = _both([path], monkeypatch)
    assert stream.is_lazy(lazy.data) and not stream.is_lazy(whole.data)
    assert lazy.meta == whole.meta and lazy.units == whole.units
    assert lazy.data.shape == whole.data.shape == (1,) + SHAPE
    assert whole.mask.sum() > 0  # the DQ, the first read's flags, saturation: all exercised
    np.testing.assert_array_equal(lazy.data[:, :, 5:31, 3:], whole.data[:, :, 5:31, 3:])
    np.testing.assert_array_equal(lazy.data[0, -1], whole.data[0, -1])
    np.testing.assert_array_equal(lazy.data[0][:, ::7], whole.data[0][:, ::7])
    np.testing.assert_array_equal(lazy.mask[0, 1:4, :, ::3], whole.mask[0, 1:4, :, ::3])


def test_a_lazy_ramp_is_never_held_whole(tmp_path):
    frames = inputs.read_frames(_ramp_file(tmp_path / "f.fits", 4), role="flat", sections=True)
    with pytest.raises(TypeError, match="never held whole"):
        np.asarray(frames.data)
    with pytest.raises(IndexError):
        frames.data[..., 0]


def test_a_file_all_masked_is_refused_by_sections(tmp_path):
    from ipc_taichi.errors import IPCInputError

    path = _ramp_file(tmp_path / "f.fits", 5, dq=False)
    with fits.open(path, mode="update") as h:
        h.append(fits.ImageHDU(np.ones(SHAPE[1:], np.uint32), name="PIXELDQ"))
    with pytest.raises(IPCInputError, match="every pixel of this flat ramp is masked"):
        inputs.read_frames(path, role="flat", sections=True)


@pytest.mark.parametrize("strip_bytes", [None, 4000])
def test_block_sums_by_sections_and_strips(tmp_path, monkeypatch, strip_bytes):
    paths = [_ramp_file(tmp_path / f"f{k}.fits", 10 + k) for k in range(3)]
    whole, lazy = _both(paths, monkeypatch)
    if strip_bytes:  # 4000 bytes: strips of 1-2 rows, each block cut in many
        monkeypatch.setattr(stream, "STRIP_BYTES", strip_bytes)
        assert len(stream.row_strips(48, 3 * 6 * 44 * 8)) > 20
    data_w = np.concatenate([f.data for f in whole])
    data_l = stream.concatenate([f.data for f in lazy])
    mask_l = stream.concatenate([f.mask for f in lazy])
    # 10 ke-: the last two reads (12 and 15 ke- since the first) are not used
    got = rampsums.block_sums(data_l, mask_l, 2, (3, 2), 10000.0)
    want = rampsums.block_sums(data_w, np.concatenate([f.mask for f in whole]), 2, (3, 2),
                               10000.0)
    assert got[0].shape[-1] == 3  # reads 0-3 used: 3 increments
    for g, w in zip(got[:3], want[:3], strict=True):  # sums, counts, increment sums
        # summation order only (a view against a copy, strips): ~1e-14 of the largest
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-12 * np.abs(w).max())
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_array_equal(got[3], want[3])
    assert got[4] == want[4]
    var_l, mean_l = stream.increment_variances(data_l, mask_l)
    var_w, mean_w = stream.increment_variances(data_w, np.concatenate([f.mask for f in whole]))
    np.testing.assert_array_equal(var_l, var_w)
    # 3000 e- Poisson a group, read noise 12 e- twice: ~3300 e-^2
    assert mean_l == mean_w and np.all((var_w > 3000) & (var_w < 3700))


def test_increment_variances_as_one_array(tmp_path):
    """The loop over increments gives numpy's variance over each increment's pixels."""
    rng = np.random.default_rng(1)
    data = np.cumsum(rng.normal(100, 5, (2, 5, 30, 20)), axis=1)
    mask = rng.random(data.shape) < 0.05
    var, mean = stream.increment_variances(data, mask)
    incs = np.diff(np.where(mask, np.nan, data), axis=1)
    np.testing.assert_array_equal(var, np.nanvar(incs.reshape(2, 4, -1), axis=-1))
    assert mean == pytest.approx(np.nanmean(np.abs(incs)), rel=1e-13)


def test_map_noise_sums_by_sections(tmp_path, monkeypatch):
    paths = [_ramp_file(tmp_path / f"f{k}.fits", 20 + k) for k in range(2)]
    whole, lazy = _both(paths, monkeypatch)
    got = maps.flat_noise_sums(lazy, (48, 40))
    want = maps.flat_noise_sums(whole, (48, 40))
    for lag in want.sum:
        for name in ("sum", "sq", "n"):
            np.testing.assert_array_equal(getattr(got, name)[lag], getattr(want, name)[lag])


def test_generator_writes_a_detector_ramp(tmp_path, cpu):
    """uint16 DN with BZERO, BUNIT DN, GAIN; the flat rises to ~40 ke- (the bias
    and coupling conserve the mean); calibrate reads it as a raw ramp."""
    path = str(tmp_path / "flat.fits")
    calfull.write_ramp(path, calfull.flat_reads(64, 5, seed=2), (5, 64, 64))
    with fits.open(path) as h:
        sci = h["SCI"]
        assert sci.data.dtype == np.uint16 and sci.data.shape == (1, 5, 64, 64)
        assert sci.header["BUNIT"] == "DN" and sci.header["GAIN"] == calfull.GAIN
        last = (sci.data[0, -1].astype(float) - calfull.BIAS) * calfull.GAIN
    assert last.mean() == pytest.approx(calfull.FLAT_LEVEL, rel=0.01)
    # Poisson (normal approximation) and read noise: the increments' variance ~ the rate
    frames = inputs.read_frames(path, role="flat")
    assert frames.meta["first_read_subtracted"] and frames.meta["stack"] == "ramp"
    inc = np.diff(frames.data[0], axis=0)[:, 2:-2, 2:-2]
    rate = calfull.FLAT_LEVEL / 5
    assert inc.mean() == pytest.approx(rate, rel=0.01)
    # the 1 % response adds (0.01 rate)^2; the coupling removes ~8 alpha of the variance
    assert inc.var() == pytest.approx(rate + 2 * 12.0 ** 2 + (0.01 * rate) ** 2, rel=0.1)

"""The output's memory map (ipc_taichi.products.pages): the bytes a view
spans, each finished frame's writeback started once it is final, and the
same file where the call is missing (another OS)."""

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.products import decouple_file, pages
from ipc_taichi.products.pages import OutputPages, byte_range


def test_byte_range_spans_the_view_first_to_last_element():
    base = np.zeros((3, 10, 12), dtype=">f4")
    assert byte_range(base, base) == (0, base.nbytes)
    frame = base[1]
    assert byte_range(frame, base) == (480, 960)
    region = base[2, 1:-1, 2:-2]  # a science region: rows 1-8, columns 2-9 of frame 2
    start = (2 * 120 + 1 * 12 + 2) * 4
    stop = (2 * 120 + 8 * 12 + 9) * 4 + 4
    assert byte_range(region, base) == (start, stop)
    flipped = base[0, ::-1, :]  # negative stride: still the lowest to the highest byte
    assert byte_range(flipped, base) == (0, 480)
    assert byte_range(base[1, 3:3], base)[1] - byte_range(base[1, 3:3], base)[0] == 0


def _skeleton(path, shape, offset=2880):
    with open(path, "wb") as f:
        f.truncate(offset + int(np.prod(shape)) * 4)


@pytest.mark.parametrize("kick", [True, False])
def test_frames_written_through_the_pages_are_the_file(tmp_path, monkeypatch, kick):
    """Whether or not the OS has the call that starts a frame's writeback,
    the file holds the frames, big-endian, at the offset, and nothing else
    is touched."""
    if not kick:
        monkeypatch.setattr(pages, "_sync_file_range", lambda: None)
    shape = (4, 33, 70)
    source = np.random.default_rng(3).normal(100, 10, shape).astype(">f4")
    path = tmp_path / "out.bin"
    _skeleton(path, shape)
    out = OutputPages(path, np.float32, 2880, shape)
    for k in range(shape[0]):
        out.array[k] = source[k] * 2
        out.written(out.array[k])
    out.close()
    raw = np.fromfile(path, dtype=">f4", offset=2880).reshape(shape)
    np.testing.assert_array_equal(raw, source * 2)
    with open(path, "rb") as f:
        assert not any(f.read(2880))


def test_a_product_is_the_same_with_and_without_the_writeback(cpu, tmp_path, monkeypatch):
    """A ramp decoupled through the product path: the same bytes whether its
    frames' writeback was started frame by frame or left to the end."""
    rng = np.random.default_rng(11)
    cube = rng.normal(2000.0, 30.0, (3, 40, 48)).astype(np.float32)
    src = tmp_path / "ramp.fits"
    hdu = fits.ImageHDU(cube, name="SCI")
    hdu.header["BUNIT"] = "electrons"
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(src)
    decouple_file(str(src), str(tmp_path / "a.fits"), law="constant:0.01", refpix=4)
    monkeypatch.setattr(pages, "_sync_file_range", lambda: None)
    decouple_file(str(src), str(tmp_path / "b.fits"), law="constant:0.01", refpix=4)
    with fits.open(tmp_path / "a.fits") as a, fits.open(tmp_path / "b.fits") as b:
        np.testing.assert_array_equal(a["SCI"].data, b["SCI"].data)
        assert not np.array_equal(a["SCI"].data, cube)  # it was decoupled


@pytest.mark.parametrize("tile", [0, 16])
def test_each_frame_is_final_when_its_writeback_starts(cpu, tmp_path, monkeypatch, tile):
    """The product path, whole or tile by tile, starts a frame's writeback
    only once every pixel of it (the science region and the reference
    border) holds its final value, once per frame, in order."""
    seen = []
    real = OutputPages.written

    def written(self, view):
        seen.append((byte_range(view, self.array), np.array(view)))
        real(self, view)

    monkeypatch.setattr(OutputPages, "written", written)
    cube = np.random.default_rng(5).normal(500.0, 20.0, (4, 24, 30)).astype(np.float32)
    src = tmp_path / "ramp.fits"
    hdu = fits.ImageHDU(cube, name="SCI")
    hdu.header["BUNIT"] = "electrons"
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(src)
    decouple_file(str(src), str(tmp_path / "out.fits"), law="constant:0.01", refpix=4,
                  tile=tile or None)
    with fits.open(tmp_path / "out.fits") as out:
        final = out["SCI"].data
        assert [r for r, _ in seen] == [(k * 24 * 30 * 4, (k + 1) * 24 * 30 * 4) for k in range(4)]
        for k, (_, frame) in enumerate(seen):
            np.testing.assert_array_equal(frame, final[k])

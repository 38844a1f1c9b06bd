"""Tests of lfsf.io: light-field containers and readers, lenslet images, PFM, FLO, KITTI
PNG and the PNG codec.

Byte-level expectations are built here by hand (struct, zlib, a per-byte reference PNG
filter) rather than with the code under test, so a format bug cannot cancel out in a
round trip. Tests on the real data sets in ../shared/data skip when it is absent.
"""

from __future__ import annotations

import contextlib
import io
import re
import signal
import struct
import warnings
import zipfile
import zlib
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from lfsf import Params
from lfsf import io as lio
from lfsf._errors import LfsfWarning

LUMA = np.array([0.299, 0.587, 0.114])


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    return b if pb <= pc else c


def _predict(kind: int, a: int, b: int, c: int) -> int:
    return (0, a, b, (a + b) // 2, _paeth(a, b, c))[kind]


def _filter_rows(rows: list[bytes], kinds: list[int], bpp: int) -> bytes:
    """Textbook per-byte PNG filtering of scanlines (PNG spec §9.2)."""
    out = bytearray()
    prior = bytes(len(rows[0]))
    for row, kind in zip(rows, kinds):
        out.append(kind)
        for i, x in enumerate(row):
            a = row[i - bpp] if i >= bpp else 0
            c = prior[i - bpp] if i >= bpp else 0
            out.append((x - _predict(kind, a, prior[i], c)) % 256)
        prior = row
    return bytes(out)


def _unfilter_rows(data: bytes, height: int, stride: int, bpp: int) -> bytes:
    """Textbook per-byte reconstruction, the inverse of _filter_rows."""
    out = bytearray()
    prior = bytearray(stride)
    for r in range(height):
        kind, line = data[r * (stride + 1)], data[r * (stride + 1) + 1:(r + 1) * (stride + 1)]
        row = bytearray(stride)
        for i, x in enumerate(line):
            a = row[i - bpp] if i >= bpp else 0
            c = prior[i - bpp] if i >= bpp else 0
            row[i] = (x + _predict(kind, a, prior[i], c)) % 256
        out += row
        prior = row
    return bytes(out)


def _image_rows(image: np.ndarray) -> list[bytes]:
    big = image.astype(">u2") if image.dtype == np.uint16 else image
    return [big[r].tobytes() for r in range(image.shape[0])]


def _png_by_hand(image: np.ndarray, kinds, interlace: bool = False) -> bytes:
    """PNG bytes of an (H, W, C) uint8/uint16 image; row r uses filter kinds[r % len]."""
    height, width, channels = image.shape
    depth = 8 * image.dtype.itemsize
    bpp = channels * image.dtype.itemsize
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[channels]
    if interlace:
        passes = [image[y0::dy, x0::dx] for x0, y0, dx, dy in
                  ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4),
                   (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))]
    else:
        passes = [image]
    scanlines = b""
    for sub in passes:
        if sub.size:
            rows = _image_rows(sub)
            scanlines += _filter_rows(rows, [kinds[r % len(kinds)] for r in range(len(rows))], bpp)
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour_type, 0, 0, int(interlace))
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr)
            + _chunk(b"IDAT", zlib.compress(scanlines)) + _chunk(b"IEND", b""))


def _random_image(rng, shape, dtype):
    return rng.integers(0, np.iinfo(dtype).max + 1, size=shape).astype(dtype)


def _bilinear(image: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    h, w = image.shape
    xs = np.clip(xs, 0, w - 1)
    ys = np.clip(ys, 0, h - 1)
    x0 = np.minimum(np.floor(xs).astype(int), w - 2)
    y0 = np.minimum(np.floor(ys).astype(int), h - 2)
    fx, fy = xs - x0, ys - y0
    top = image[y0, x0] * (1 - fx) + image[y0, x0 + 1] * fx
    bottom = image[y0 + 1, x0] * (1 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


@pytest.fixture
def file_size_limit():
    """Context manager making every file write past ``nbytes`` fail (EFBIG), like a full
    disk part-way through a write."""
    resource = pytest.importorskip("resource")
    if not hasattr(signal, "SIGXFSZ"):
        pytest.skip("no SIGXFSZ on this platform")
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)

    @contextlib.contextmanager
    def limit(nbytes: int):
        if hard != resource.RLIM_INFINITY and hard < nbytes:
            pytest.skip("hard file-size limit too low")
        handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, hard))
        try:
            yield
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
            signal.signal(signal.SIGXFSZ, handler)

    return limit


# --------------------------------------------------------------------------------------
# LightField
# --------------------------------------------------------------------------------------


def test_lightfield_properties():
    views = np.zeros((3, 5, 4, 6, 3), dtype=np.float32)
    lf = lio.LightField(views, source="scene")
    assert lf.grid == (3, 5)
    assert lf.shape == (3, 5, 4, 6, 3)
    assert (lf.height, lf.width) == (4, 6)
    assert lf.is_colour
    assert lf.centre_index == (1.0, 2.0)
    assert not lio.LightField(views[..., 0]).is_colour
    assert lio.LightField(np.zeros((2, 4, 1, 1))).centre_index == (0.5, 1.5)
    assert "3×5" in repr(lf) and "scene" in repr(lf)


def test_lightfield_converts_to_float32():
    lf = lio.LightField(np.full((1, 1, 2, 2), 255, dtype=np.uint8))
    assert lf.views.dtype == np.float32
    np.testing.assert_array_equal(lf.views, 1.0)
    lf16 = lio.LightField(np.full((1, 1, 2, 2), 65535 // 5, dtype=np.uint16))
    np.testing.assert_allclose(lf16.views, 0.2, rtol=1e-6)
    lf64 = lio.LightField(np.full((1, 1, 2, 2, 1), 0.25))        # float64, one channel
    assert lf64.views.dtype == np.float32 and lf64.shape == (1, 1, 2, 2)
    assert lf64.views.flags.c_contiguous


def test_centre_of_odd_grid_is_the_middle_view():
    views = np.random.default_rng(0).random((3, 5, 4, 4)).astype(np.float32)
    lf = lio.LightField(views)
    np.testing.assert_array_equal(lf.centre, views[1, 2])


@pytest.mark.parametrize("grid, expected", [
    ((4, 4), (11 + 12 + 21 + 22) / 4),     # rows 1, 2 and columns 1, 2
    ((3, 2), (10 + 11) / 2),               # row 1, columns 0, 1
    ((2, 3), (1 + 11) / 2),                # rows 0, 1, column 1
])
def test_centre_of_even_grid_is_the_bilinear_mean(grid, expected):
    a, b = np.meshgrid(np.arange(grid[0]), np.arange(grid[1]), indexing="ij")
    views = np.broadcast_to((10 * a + b)[:, :, None, None] / 100, grid + (2, 3)).copy()
    centre = lio.LightField(views).centre
    assert centre.shape == (2, 3)
    np.testing.assert_allclose(centre, expected / 100, rtol=1e-6)


def test_grey_uses_bt601_luma():
    pixels = np.array([[0.2, 0.4, 0.6], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    views = pixels.reshape(1, 1, 1, 5, 3)
    grey = lio.LightField(views, source="s", meta={"k": 1}).grey()
    assert isinstance(grey, lio.LightField) and grey.shape == (1, 1, 1, 5)
    np.testing.assert_allclose(grey.views[0, 0, 0],
                               [0.299 * 0.2 + 0.587 * 0.4 + 0.114 * 0.6, 0.299, 0.587, 0.114, 1.0],
                               rtol=1e-6)
    assert grey.source == "s" and grey.meta == {"k": 1}
    assert grey.grey() is grey


def test_view_access_and_bounds():
    views = np.random.default_rng(1).random((2, 3, 4, 5)).astype(np.float32)
    lf = lio.LightField(views, source="here")
    np.testing.assert_array_equal(lf.view(1, 2), views[1, 2])
    np.testing.assert_array_equal(lf.view(-1, -3), views[1, 0])    # from the end, as NumPy counts
    for a, b in ((2, 0), (0, 3), (-3, 0), (0, -4)):
        with pytest.raises(IndexError, match=rf"here: view \({a}, {b}\) is outside the 2×3 grid"):
            lf.view(a, b)


@pytest.mark.parametrize("views, message", [
    (np.zeros((4, 4, 8)), r"got an array of 3 dimensions, shape \(4, 4, 8\): a stack of 4 views\? give them as a "
                          r"2×2 grid, row by row: views.reshape\(2, 2, 4, 8\)$"),
    (np.zeros((5, 4, 8)), r"got an array of 3 dimensions, shape \(5, 4, 8\)$"),
    (np.zeros((1, 1, 2, 2, 3, 1)), "got an array of 6 dimensions"),
    (np.zeros((1, 1, 2, 2, 4)), "got 4"),
    (np.zeros((1, 1, 2, 2, 2)), "got 2"),
    (np.zeros((0, 1, 2, 2)), "non-empty"),
    (np.zeros((1, 1, 2, 2), dtype=complex), "real-valued"),
    (np.array([[[["a"]]]]), "real-valued"),
])
def test_lightfield_rejects_bad_arrays(views, message):
    with pytest.raises(ValueError, match=message) as info:
        lio.LightField(views, source="my/scene")
    assert str(info.value).startswith("my/scene: expected")


def test_lightfield_rejects_non_finite_and_says_where():
    views = np.zeros((3, 2, 4, 4, 3), dtype=np.float32)
    views[1, 0, 2, 2, 1] = np.nan
    views[1, 0, 2, 2, 2] = np.inf        # same pixel: counted once
    views[2, 1, 0, 0, 0] = -np.inf
    with pytest.raises(ValueError) as info:
        lio.LightField(views, source="lf.npz")
    message = str(info.value)
    assert message.startswith("lf.npz:")
    assert "2 NaN or infinite pixel(s) in 2 view(s)" in message
    assert "(1, 0)" in message
    # finite values that float32 cannot hold are said to be that, not NaN or infinite
    wide = np.zeros((2, 2, 4, 4))
    wide[1, 0, 2, 2] = 1e300
    wide[0, 1, 0, 0] = np.inf
    with pytest.raises(ValueError, match=r"^lf.npz: expected pixel values within float32's range \(±3.4e\+38\), "
                                         r"got 1 pixel\(s\) beyond it in 1 view\(s\), the first in view "
                                         r"\(a, b\) = \(1, 0\)$"):
        lio.LightField(wide, source="lf.npz")


def test_check_pair():
    lf = lio.LightField(np.random.default_rng(0).random((3, 3, 4, 5, 3)), source="t1")
    lio.check_pair(lf, lio.LightField(np.ones((3, 3, 4, 5, 3)), source="t2"))
    # grey against RGB: the t1 colours would shape the estimate alone, the t2 ones be dropped
    with pytest.raises(ValueError, match=r"^t2: grey views, but those of t1 are RGB: give both light fields in "
                                         r"colour, or both grey \(in Python LightField.grey\(\) makes the luma of "
                                         r"an RGB one; lfsf decode --bayer none decodes a raw image grey\)$"):
        lio.check_pair(lf, lio.LightField(np.ones((3, 3, 4, 5)), source="t2"))
    with pytest.raises(ValueError, match=r"^t1: RGB views, but those of t2 are grey"):
        lio.check_pair(lio.LightField(np.ones((3, 3, 4, 5)), source="t2"), lf)
    lio.check_pair(lf.grey(), lio.LightField(np.ones((3, 3, 4, 5)), source="t2"))
    # an RGB light field of three equal channels (grey saved as RGB) pairs with a grey one
    lio.check_pair(lio.LightField(np.repeat(lf.grey().views[..., None], 3, -1)), lf.grey())
    for shape in [(3, 5, 4, 5), (3, 3, 4, 6), (3, 3, 5, 5)]:
        with pytest.raises(ValueError, match="^t2: expected .*t1") as info:
            lio.check_pair(lf, lio.LightField(np.zeros(shape), source="t2"))
        assert "3×3 grid of 5×4 views" in str(info.value)


def test_check_pair_refuses_light_fields_scaled_differently():
    """One light field in [0, 1] and the other in counts ([0, 255] as floats): the joint
    stretch would leave the first nearly black and the estimate meaningless."""
    rng = np.random.default_rng(0)
    unit = rng.random((3, 3, 6, 7)).astype(np.float32)
    counts = lio.LightField(unit * 255, source="t2")
    with pytest.raises(ValueError, match=r"^t2: its brightest value is 25\d\.\d+ against 0\.99\d+ in t1: "
                                         r"the two light fields look scaled differently"):
        lio.check_pair(lio.LightField(unit, source="t1"), counts)
    with pytest.raises(ValueError, match="scaled differently"):
        lio.check_pair(counts, lio.LightField(unit, source="t1"))
    lio.check_pair(counts, lio.LightField(unit * 200, source="t1"))        # both in counts: stretched alike
    lio.check_pair(lio.LightField(unit, source="t1"), lio.LightField(unit / 10, source="t2"))  # dark, in [0, 1]
    lio.check_pair(lio.LightField(unit * 1.9, source="t1"), lio.LightField(unit * 0.2, source="t2"))
    # uint8 counts against the same counts as int16: 1 against 0.0078
    eight = (unit * 255).astype(np.uint8)
    with pytest.raises(ValueError, match=r"^t2: its brightest value is 0\.0077\d* against 0\.99\d* in t1"):
        lio.check_pair(lio.LightField(eight, source="t1"), lio.LightField(eight.astype(np.int16), source="t2"))


@pytest.mark.parametrize("dtype, values, fix", [
    (np.int64, (0, 255), r" \(these would be 2\.8e-17 at most\): give them as np\.uint8 \(\.astype\(np\.uint8\)\) if "
                         r"they are 8-bit values"),
    (np.int32, (0, 4095), r" \(these would be 1\.9e-06 at most\): give them as np\.uint16 "
                          r"\(\.astype\(np\.uint16\)\) if they are 16-bit values"),
    (np.uint32, (0, 70000), r" \(these would be 1\.6e-05 at most\): give them as floats in \[0, 1\] \(divided by their "
                            r"full scale\)$"),
    (np.int64, (-1, 200), r" \(these would be .*\): give them as floats in \[0, 1\]"),
    (np.int64, (0, 1), r" \(these would be .*\): give them as bool, or as floats in \[0, 1\]"),  # (not 1/255)
    (np.uint64, (0, 2 ** 64 - 1), r": give them as floats in \[0, 1\] \(divided by their full scale\)$")])
def test_integers_wider_than_16_bits_are_refused(dtype, values, fix):
    """``np.array`` of Python ints is int64, which scaled by its type's maximum would be
    views of nothing (0…255 → 0…2.8e-17): refused, with what to give instead."""
    views = np.zeros((3, 3, 4, 5), dtype)
    views[0, 0, 0, :2] = values
    with pytest.raises(ValueError, match=rf"^views\.npz: integer views of dtype {np.dtype(dtype).name} \(values "
                                         rf"{values[0]}…{values[1]}\); lfsf scales integers by their type's maximum "
                                         rf"and takes those of 8 and 16 bits{fix}"):
        lio.LightField(views, source="views.npz")
    lio.LightField(views.astype(np.uint16) if values[0] >= 0 and values[1] <= 65535 else views.astype(np.float32)
                   / np.float32(values[1]), source="views.npz")


# --------------------------------------------------------------------------------------
# Lenslet images
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(2, 3, 4, 5), (3, 2, 5, 4, 3)])
def test_lenslet_layout_and_round_trip(shape):
    views = np.arange(np.prod(shape)).reshape(shape)
    raw = lio.views_to_lenslet(views)
    A, B, Y, X = shape[:4]
    assert raw.shape == (Y * A, X * B) + shape[4:]
    for a in range(A):
        for b in range(B):
            for y in range(Y):
                for x in range(X):
                    np.testing.assert_array_equal(raw[y * A + a, x * B + b], views[a, b, y, x])
    back = lio.lenslet_to_views(raw, (A, B))
    np.testing.assert_array_equal(back, views)
    assert back.flags.c_contiguous


def test_lenslet_hand_checked_element():
    views = np.zeros((2, 3, 4, 5), dtype=np.float32)
    views[1, 2, 3, 4] = 7
    raw = lio.views_to_lenslet(lio.LightField(views))
    assert raw[3 * 2 + 1, 4 * 3 + 2] == 7 and raw.sum() == 7
    raw2 = np.zeros((6, 9))
    raw2[5, 8] = 1                       # y = 2, a = 1, x = 2, b = 2
    assert lio.lenslet_to_views(raw2, grid=(2, 3))[1, 2, 2, 2] == 1


def test_lenslet_rejects_indivisible_size():
    with pytest.raises(ValueError, match="multiple of the 2×3 grid"):
        lio.lenslet_to_views(np.zeros((7, 9)), (2, 3))
    with pytest.raises(ValueError):
        lio.views_to_lenslet(np.zeros((2, 2, 2)))


# --------------------------------------------------------------------------------------
# PNG codec and image helpers
# --------------------------------------------------------------------------------------

PNG_FORMATS = [(np.uint16, 3), (np.uint16, 4), (np.uint16, 2), (np.uint16, 1),
               (np.uint8, 3), (np.uint8, 1)]


@pytest.mark.parametrize("kinds", [(0, 1, 2, 3, 4), (0, 1, 2), (3,), (4,)])
@pytest.mark.parametrize("dtype, channels", PNG_FORMATS)
def test_decode_png_hand_made_bytes(kinds, dtype, channels):
    rng = np.random.default_rng(len(kinds) * 10 + channels)
    # a gradient plus noise, so that predictions matter and differences wrap
    image = (_random_image(rng, (7, 6, channels), dtype) // 4
             + np.arange(6, dtype=dtype)[None, :, None] * (np.iinfo(dtype).max // 8))
    decoded = lio.decode_png(_png_by_hand(image, kinds))
    np.testing.assert_array_equal(decoded, image[..., 0] if channels == 1 else image)
    assert decoded.dtype == dtype


def test_decode_png_exact_small_file():
    # one 16-bit RGB pixel row, filter None, values chosen so the low byte matters
    scanlines = b"\x00" + struct.pack(">6H", 1, 258, 65535, 0, 4660, 43981)
    data = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 1, 16, 2, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(scanlines)) + _chunk(b"IEND", b""))
    np.testing.assert_array_equal(lio.decode_png(data),
                                  [[[1, 258, 65535], [0, 4660, 43981]]])


def test_decode_png_in_bands(monkeypatch):
    """The wavefront unfilter carries the reconstructed row across band seams."""
    monkeypatch.setattr(lio, "_WAVEFRONT_BAND_BYTES", 2000)
    image = _random_image(np.random.default_rng(5), (40, 30, 3), np.uint16)
    np.testing.assert_array_equal(lio.decode_png(_png_by_hand(image, (4, 3, 1, 0, 2))), image)


@pytest.mark.parametrize("size", [(9, 11), (1, 1), (2, 3), (8, 8), (17, 5)])
def test_decode_png_interlaced(size):
    image = _random_image(np.random.default_rng(size[0]), size + (3,), np.uint16)
    np.testing.assert_array_equal(lio.decode_png(_png_by_hand(image, (4, 1, 3), True)), image)


@pytest.mark.parametrize("dtype, channels", PNG_FORMATS)
def test_encode_png_structure(dtype, channels):
    image = _random_image(np.random.default_rng(2), (5, 4, channels), dtype)
    data = lio.encode_png(image)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    chunks, pos = [], 8
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        assert struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])[0] == zlib.crc32(kind + body)
        chunks.append((kind, body))
        pos += 12 + length
    assert pos == len(data)
    assert [k for k, _ in chunks] == [b"IHDR", b"IDAT", b"IEND"] and chunks[2][1] == b""
    depth = 8 * np.dtype(dtype).itemsize
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[channels]
    assert chunks[0][1] == struct.pack(">IIBBBBB", 4, 5, depth, colour_type, 0, 0, 0)
    bpp = channels * depth // 8
    pixels = _unfilter_rows(zlib.decompress(chunks[1][1]), 5, 4 * bpp, bpp)
    assert pixels == b"".join(_image_rows(image))


@pytest.mark.parametrize("dtype, channels", PNG_FORMATS)
def test_png_round_trip(tmp_path, dtype, channels):
    image = _random_image(np.random.default_rng(3), (13, 17, channels), dtype)
    if channels == 1:
        image = image[..., 0]
    lio.write_png(tmp_path / "a.png", image)
    back = lio.read_image(tmp_path / "a.png")
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, image)


def test_pillow_reads_what_we_write(tmp_path):
    """An independent decoder agrees with our encoder (Pillow keeps only the high byte of
    16-bit colour; accept a full read too, should a later Pillow manage it)."""
    rng = np.random.default_rng(4)
    for image in (_random_image(rng, (6, 7, 3), np.uint8), _random_image(rng, (6, 7), np.uint16)):
        lio.write_png(tmp_path / "x.png", image)
        np.testing.assert_array_equal(iio.imread(tmp_path / "x.png"), image)
    rgb16 = _random_image(rng, (6, 7, 3), np.uint16)
    lio.write_png(tmp_path / "y.png", rgb16)
    pillow = iio.imread(tmp_path / "y.png")
    expected = rgb16 if pillow.dtype == np.uint16 else (rgb16 >> 8).astype(np.uint8)
    np.testing.assert_array_equal(pillow, expected)


def test_decoder_matches_pillow_on_its_adaptive_filters():
    rng = np.random.default_rng(6)
    image = (rng.integers(0, 60, (30, 40, 3)) + np.arange(40)[None, :, None] * 5).astype(np.uint8)
    buffer = io.BytesIO()
    iio.imwrite(buffer, image, extension=".png")
    np.testing.assert_array_equal(lio.decode_png(buffer.getvalue()), image)


def test_read_image_keeps_16_bit_colour(tmp_path):
    image = np.array([[[1, 258, 65535], [32767, 4660, 0]]], dtype=np.uint16)
    (tmp_path / "c.png").write_bytes(_png_by_hand(image, (4,)))
    np.testing.assert_array_equal(lio.read_image(tmp_path / "c.png"), image)


def test_write_png_converts_float_and_bool(tmp_path):
    lio.write_png(tmp_path / "f.png", np.array([[0.0, 0.5, 1.0, 2.0, -1.0]]))
    np.testing.assert_array_equal(lio.read_image(tmp_path / "f.png"), [[0, 128, 255, 255, 0]])
    lio.write_png(tmp_path / "b.png", np.array([[True, False]]))
    np.testing.assert_array_equal(lio.read_image(tmp_path / "b.png"), [[255, 0]])
    with pytest.raises(ValueError, match="NaN"):
        lio.write_png(tmp_path / "n.png", np.array([[np.nan]]))
    with pytest.raises(ValueError, match="int32"):
        lio.write_png(tmp_path / "i.png", np.zeros((2, 2), dtype=np.int32))
    assert not (tmp_path / "n.png").exists() and not (tmp_path / "i.png").exists()


def test_corrupt_png_names_the_file(tmp_path):
    image = _random_image(np.random.default_rng(7), (8, 8, 3), np.uint16)
    good = _png_by_hand(image, (1,))
    bad_crc = bytearray(good)
    bad_crc[40] ^= 0xFF                                          # inside IDAT
    cases = {"crc.png": (bytes(bad_crc), "CRC"), "short.png": (good[:60], "truncated"),
             "junk.png": (b"not a png at all", "cannot read"),
             # two bytes: Pillow's header read raised struct.error ("unpack_from requires a buffer …")
             "two.png": (b"xx", r"cannot read image \(the file ends inside its header: truncated, or not an image\)")}
    for name, (data, problem) in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ValueError, match=f"{name}: .*{problem}"):
            lio.read_image(tmp_path / name)
    with pytest.raises(FileNotFoundError, match="nothere.png"):
        lio.read_image(tmp_path / "nothere.png")


def test_decode_png_rejects_truncated_image_data():
    image = np.zeros((4, 4, 3), dtype=np.uint16)
    scanlines = b"\x00" + bytes(4 * 6)                            # one row of four
    data = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 16, 2, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(scanlines)) + _chunk(b"IEND", b""))
    with pytest.raises(ValueError, match="src.png: truncated PNG image data"):
        lio.decode_png(data, source="src.png")
    assert lio.decode_png(_png_by_hand(image, (0,))).shape == (4, 4, 3)


@pytest.mark.parametrize("interlace", [0, 1])
def test_decode_png_claiming_a_huge_size_fails_before_allocating(interlace):
    """A 70-byte file claiming 10000×10000 16-bit RGB pixels: interlaced, the image
    (0.6 GB; 56 GiB at 100000×100000) was allocated before the data were checked, a
    MemoryError; and a small IDAT that inflates far beyond what the header promises is
    cut off at that size. Beyond Pillow's limit of pixels a PNG is refused as Pillow
    refuses it: 16000×16000 blank pixels had been decompressed from 1.5 MB, 1.5 GB."""
    def claiming(width, height):
        return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 16, 2, 0, 0, interlace))
                + _chunk(b"IDAT", zlib.compress(bytes(64))) + _chunk(b"IEND", b""))

    with pytest.raises(ValueError, match=r"bomb.png: truncated PNG image data: expected 6000\d{5} bytes "
                                         r"for 10000×10000 pixels, got 64"):
        lio.decode_png(claiming(10000, 10000), source="bomb.png")
    with pytest.raises(ValueError, match=r"bomb.png: a PNG of 16000×16000 pixels, more than the 178956970 that"):
        lio.decode_png(claiming(16000, 16000), source="bomb.png")
    # 2×2 grey promises 2·(2 + 1) = 6 bytes; 100 MB of zeros (100 kB compressed) behind them
    bomb = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 2, 8, 0, 0, 0, interlace))
            + _chunk(b"IDAT", zlib.compress(bytes(100_000_000), 9)) + _chunk(b"IEND", b""))
    np.testing.assert_array_equal(lio.decode_png(bomb), np.zeros((2, 2), np.uint8))


# --------------------------------------------------------------------------------------
# PFM
# --------------------------------------------------------------------------------------


def test_a_nul_byte_in_a_file_name_is_named_in_the_error():
    """open() says only 'embedded null byte'; which name held it is the useful part."""
    for read in (lio.read_pfm, lio.read_flo):
        with pytest.raises(ValueError, match=re.escape("'gt\\x00.pfm': not a usable file name (embedded null byte)")):
            read("gt\0.pfm")


def test_pfm_hand_made_little_endian(tmp_path):
    # 3 wide, 2 high; the file stores the bottom row first
    top, bottom = [1.5, -2.0, 0.25], [3.0, np.inf, -0.125]
    data = b"Pf\n3 2\n-1\n" + struct.pack("<6f", *bottom, *top)
    (tmp_path / "hand.pfm").write_bytes(data)
    image = lio.read_pfm(tmp_path / "hand.pfm")
    assert image.dtype == np.float32 and image.shape == (2, 3)
    np.testing.assert_array_equal(image, [top, bottom])
    lio.write_pfm(tmp_path / "ours.pfm", image)
    assert (tmp_path / "ours.pfm").read_bytes() == data


def test_pfm_hand_made_big_endian_colour_with_odd_whitespace(tmp_path):
    pixels = np.arange(12, dtype=np.float32).reshape(2, 2, 3) - 5.5       # rows top to bottom
    body = struct.pack(">12f", *pixels[::-1].ravel())
    for header in (b"PF\n2 2\n1\n", b"PF \n\n 2\t2 \n  1.0  \r\n", b"PF 2 2 1.0 "):
        (tmp_path / "c.pfm").write_bytes(header + body)
        np.testing.assert_array_equal(lio.read_pfm(tmp_path / "c.pfm"), pixels)
    lio.write_pfm(tmp_path / "ours.pfm", pixels, little_endian=False)
    assert (tmp_path / "ours.pfm").read_bytes() == b"PF\n2 2\n1\n" + body


def test_pfm_comment_lines_are_skipped_and_a_scale_other_than_1_is_warned_about(tmp_path):
    """Header lines starting with '#' (no part of the format, but some writers put them, and
    the HCI toolkit's reader skips them) had been a "bad PFM dimensions" error; a scale of
    magnitude other than 1, which that reader multiplies the values by, was read silently
    as stored. Data bytes that happen to be '#' (0x23) are data."""
    top, bottom = [1.5, -2.0, 0.25], [3.0, np.inf, -0.125]
    body = struct.pack("<6f", *bottom, *top)
    (tmp_path / "c.pfm").write_bytes(b"Pf\n# made by a tool\n3 2\n  # another\n-1\n" + body)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(lio.read_pfm(tmp_path / "c.pfm"), [top, bottom])
    hashes = np.frombuffer(b"#\x00\x80?" * 6, "<f4").reshape(2, 3)   # floats whose bytes hold '#'
    lio.write_pfm(tmp_path / "h.pfm", hashes)
    np.testing.assert_array_equal(lio.read_pfm(tmp_path / "h.pfm"), hashes)
    (tmp_path / "s.pfm").write_bytes(b"Pf\n3 2\n-2.0\n" + body)
    with pytest.warns(LfsfWarning, match=r"s.pfm: PFM scale -2.0: the values are read as stored; the HCI "
                                              r"toolkit's reader multiplies them by 2"):
        np.testing.assert_array_equal(lio.read_pfm(tmp_path / "s.pfm"), [top, bottom])


def test_ply_colours_of_16_bit_integers_are_scaled_by_their_maximum(tmp_path):
    """16-bit colours (a 16-bit view's) had been clipped as floats, to 0 or 255."""
    points = np.arange(12, dtype=np.float32).reshape(4, 3)
    colours = np.array([[0, 32768, 65535]] * 4, np.uint16)
    assert lio.write_ply(tmp_path / "c.ply", points, colours=colours) == 4
    data = (tmp_path / "c.ply").read_bytes()
    body = np.frombuffer(data[data.index(b"end_header\n") + 11:], dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    np.testing.assert_array_equal(body["rgb"], [[0, 128, 255]] * 4)
    with pytest.raises(ValueError, match="integer colours of dtype int64 .*give them as np.uint16"):
        lio.write_ply(tmp_path / "d.ply", points, colours=colours.astype(np.int64))


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 3), (1, 1)])
@pytest.mark.parametrize("little_endian", [True, False])
def test_pfm_round_trip(tmp_path, shape, little_endian):
    image = np.random.default_rng(8).normal(size=shape).astype(np.float32)
    image.flat[0] = np.nan
    lio.write_pfm(tmp_path / "r.pfm", image, little_endian=little_endian)
    np.testing.assert_array_equal(lio.read_pfm(tmp_path / "r.pfm"), image)


def test_pfm_accepts_single_channel_3d_and_rejects_bad_shapes(tmp_path):
    lio.write_pfm(tmp_path / "one.pfm", np.ones((2, 3, 1)))
    assert lio.read_pfm(tmp_path / "one.pfm").shape == (2, 3)
    with pytest.raises(ValueError, match="bad.pfm"):
        lio.write_pfm(tmp_path / "bad.pfm", np.ones((2, 3, 2)))
    assert not (tmp_path / "bad.pfm").exists()


@pytest.mark.parametrize("content, problem", [
    (b"P6\n2 2\n255\n" + bytes(12), "magic"),
    (b"Pg\n2 2\n-1\n" + bytes(16), "magic"),
    (b"Pf\n0 2\n-1\n", "dimensions"),
    (b"Pf\n-2 2\n-1\n" + bytes(16), "dimensions"),
    (b"Pf\n2 x\n-1\n" + bytes(16), "dimensions"),
    (b"Pf\n2 2\n0\n" + bytes(16), "scale"),
    (b"Pf\n2 2\nnan\n" + bytes(16), "scale"),
    (b"Pf\n2 2\nabc\n" + bytes(16), "scale"),
    (b"Pf\n2 2\n-1\n" + bytes(15), "truncated"),
    (b"PF\n2 2\n-1\n" + bytes(16), "truncated"),
    (b"Pf\n100000 100000\n-1\n" + bytes(16), "truncated"),
    # a damaged header's digits cut short (5000 had filled the message)
    (b"Pf\n" + b"9" * 5000 + b" 5\n-1\n" + bytes(16), r"dimensions: .*got b'9{24}'… \(5000 bytes\) b'5'$"),
    (b"Pf\n" + b"9" * 400 + b" 5\n-1\n" + bytes(16), r"truncated PFM data: expected 1.99e401 bytes for "
                                                       r"9.99e399×5×1 float32, got 16$"),
    (b"Pf\n2", "header"),
])
def test_corrupt_pfm_names_the_file(tmp_path, content, problem):
    (tmp_path / "broken.pfm").write_bytes(content)
    with pytest.raises(ValueError, match=problem) as info:
        lio.read_pfm(tmp_path / "broken.pfm")
    assert "broken.pfm" in str(info.value)


def test_a_tiff_is_read_by_tifffile_or_pillow_alone_and_its_size_checked_first(tmp_path, monkeypatch, capfd):
    """A TIFF larger than lfsf reads is refused from its header (an 825-KB tiled file of
    20000×20000 had taken 2.9 GB); a truncated one is tifffile's error, without OpenCV's
    WARN and ERROR lines or Pillow's warning on stderr (imageio had fallen through to
    them, and named no fault)."""
    import tifffile

    image = (np.arange(20 * 30, dtype=np.uint16).reshape(20, 30) * 97).astype(np.uint16)
    tifffile.imwrite(tmp_path / "v.tif", image)
    assert np.array_equal(lio.read_image(tmp_path / "v.tif"), image)
    monkeypatch.setattr(lio, "MAX_PNG_PIXELS", 599)
    with pytest.raises(ValueError, match=r"v.tif: a TIFF of 30×20 pixels, more than the 599 that lfsf reads"):
        lio.read_image(tmp_path / "v.tif")
    monkeypatch.undo()
    (tmp_path / "cut.tif").write_bytes((tmp_path / "v.tif").read_bytes()[:20])
    capfd.readouterr()
    with pytest.raises(ValueError, match=r"cut.tif: cannot read image \(TiffFileError"):
        lio.read_image(tmp_path / "cut.tif")
    assert capfd.readouterr().err == ""
    # a stack's values counted, not its first page's alone (30 pages of 8000×8000 had passed)
    tifffile.imwrite(tmp_path / "stack.tif", np.zeros((30, 8, 10), np.uint8), bigtiff=True)
    monkeypatch.setattr(lio, "MAX_TIFF_VALUES", 30 * 80 - 1)
    with pytest.raises(ValueError, match=r"stack.tif: a TIFF of shape \(30, 8, 10\), 2400 values, more than the 2399"):
        lio.read_image(tmp_path / "stack.tif")
    monkeypatch.undo()
    # a BigTIFF known by its header whatever its name
    (tmp_path / "stack.tif").rename(tmp_path / "stack.png")
    assert lio.read_image(tmp_path / "stack.png").shape == (30, 8, 10)


def test_a_tiff_tifffile_cannot_decode_is_read_by_pillow_if_it_is_one_page(tmp_path):
    """LZW or JPEG TIFFs need imagecodecs in tifffile: Pillow reads a one-page one; of a
    stack it would give the first page alone, so a stack stays tifffile's error (or its
    pages, where imagecodecs is installed)."""
    from PIL import Image

    pages = [Image.fromarray(np.full((6, 7, 3), 40 * k, np.uint8)) for k in range(1, 4)]
    pages[0].save(tmp_path / "one.tif", compression="tiff_lzw")
    assert np.array_equal(lio.read_image(tmp_path / "one.tif"), np.full((6, 7, 3), 40, np.uint8))
    pages[0].save(tmp_path / "three.tif", compression="tiff_lzw", save_all=True, append_images=pages[1:])
    try:
        import imagecodecs  # noqa: F401
    except ImportError:
        with pytest.raises(ValueError, match=r"three.tif: cannot read image \(ValueError: .*imagecodecs"):
            lio.read_image(tmp_path / "three.tif")
    else:
        assert lio.read_image(tmp_path / "three.tif").shape == (3, 6, 7, 3)


def test_readers_given_no_path_say_what_they_got(tmp_path):
    """None, a number, bytes or "" had been pathlib's TypeError (or "" the current folder)."""
    from lfsf import SceneFlow, evaluate
    from lfsf.camera import Camera
    from lfsf.decode import read_raw

    readers = (lio.read_image, lio.read_kitti_flow, lio.read_kitti_disparity, read_raw, Camera.from_file,
               evaluate.load_estimate, evaluate.load_ground_truth, SceneFlow.load, Params.from_toml)
    for reader in readers:
        for given in (None, 3, b"x.png", ""):
            with pytest.raises(ValueError, match=r"^expected .*(got (NoneType|int|bytes)|got an empty one)"):
                reader(given)


def test_a_decode_report_with_a_count_no_lens_holds_is_not_taken(tmp_path):
    """decode.json's "views" of 400 digits had been an OverflowError in the estimate."""
    _hci_folder(tmp_path / "hci", 2)
    (tmp_path / "hci" / "decode.json").write_text('{"lattice": {"a": 1}, "views": 1' + "0" * 400 + "}")
    assert "lens_views" not in lio.read_lightfield(tmp_path / "hci").meta
    (tmp_path / "hci" / "decode.json").write_text('{"lattice": {"a": 1}, "views": 15}')
    assert lio.read_lightfield(tmp_path / "hci").meta["lens_views"] == 15


def test_missing_files_raise_file_not_found(tmp_path):
    for reader in (lio.read_pfm, lio.read_flo, lio.read_kitti_flow, lio.read_lightfield):
        with pytest.raises(FileNotFoundError, match="absent"):
            reader(tmp_path / "absent")


# --------------------------------------------------------------------------------------
# Middlebury .flo
# --------------------------------------------------------------------------------------


def test_flo_hand_made_bytes(tmp_path):
    # 3 wide, 2 high, (u, v) interleaved, row-major; pixel (1, 2) unknown
    values = [0.5, -1.0, 2.0, 3.5, -0.25, 0.0,
              1.0, 1.0, 4.0, -4.0, 1e10, 1e10]
    data = b"PIEH" + struct.pack("<ii", 3, 2) + struct.pack("<12f", *values)
    assert data[:4] == struct.pack("<f", 202021.25)
    (tmp_path / "hand.flo").write_bytes(data)
    flow = lio.read_flo(tmp_path / "hand.flo")
    assert flow.dtype == np.float32 and flow.shape == (2, 3, 2)
    np.testing.assert_array_equal(flow[0], [[0.5, -1.0], [2.0, 3.5], [-0.25, 0.0]])
    np.testing.assert_array_equal(flow[1, :2], [[1.0, 1.0], [4.0, -4.0]])
    assert np.isnan(flow[1, 2]).all()
    lio.write_flo(tmp_path / "ours.flo", flow)
    assert (tmp_path / "ours.flo").read_bytes() == data


def test_flo_round_trip_with_unknown_pixels(tmp_path):
    flow = np.random.default_rng(9).normal(scale=5, size=(6, 8, 2)).astype(np.float32)
    flow[2, 3] = np.nan
    flow[4, 1, 0] = np.inf               # one bad component makes the pixel unknown
    flow[5, 5, 1] = 2e9                  # beyond Middlebury's 1e9 threshold
    lio.write_flo(tmp_path / "f.flo", flow)
    back = lio.read_flo(tmp_path / "f.flo")
    unknown = np.zeros((6, 8), dtype=bool)
    unknown[2, 3] = unknown[4, 1] = unknown[5, 5] = True
    assert np.array_equal(np.isnan(back).all(axis=2), unknown)
    assert not np.isnan(back[~unknown]).any()
    np.testing.assert_array_equal(back[~unknown], flow[~unknown])


@pytest.mark.parametrize("content, problem", [
    (b"PIEX" + struct.pack("<ii", 1, 1) + bytes(8), "magic"),
    (b"PIEH" + struct.pack("<ii", 0, 5) + bytes(8), "size"),
    (b"PIEH" + struct.pack("<ii", 1_000_000, 1) + bytes(8), "size"),
    (b"PIEH" + struct.pack("<ii", 2, -3) + bytes(8), "size"),
    (b"PIEH" + struct.pack("<ii", 2, 2) + bytes(31), "truncated"),
    (b"PIEH\x01\x00", "truncated"),
])
def test_corrupt_flo_names_the_file(tmp_path, content, problem):
    (tmp_path / "broken.flo").write_bytes(content)
    with pytest.raises(ValueError, match=problem) as info:
        lio.read_flo(tmp_path / "broken.flo")
    assert "broken.flo" in str(info.value)


# --------------------------------------------------------------------------------------
# KITTI
# --------------------------------------------------------------------------------------


def test_kitti_flow_hand_made(tmp_path):
    raw = np.array([[[32768 + 96, 32768 - 128, 1], [65535, 0, 0]],
                    [[0, 65535, 7], [32768, 32768, 1]]], dtype=np.uint16)
    (tmp_path / "k.png").write_bytes(_png_by_hand(raw, (0,)))
    flow, valid = lio.read_kitti_flow(tmp_path / "k.png")
    np.testing.assert_array_equal(valid, [[True, False], [True, True]])
    np.testing.assert_array_equal(flow[0, 0], [1.5, -2.0])
    np.testing.assert_array_equal(flow[1, 0], [-512.0, 65535 / 64 - 512])
    np.testing.assert_array_equal(flow[1, 1], [0.0, 0.0])
    assert np.isnan(flow[0, 1]).all()


def test_kitti_flow_round_trip_with_invalid_pixels(tmp_path):
    rng = np.random.default_rng(10)
    flow = np.round(rng.normal(scale=50, size=(5, 6, 2)) * 64) / 64
    flow[1, 2] = np.nan
    lio.write_kitti_flow(tmp_path / "a.png", flow)
    back, valid = lio.read_kitti_flow(tmp_path / "a.png")
    assert valid.sum() == 29 and not valid[1, 2]
    np.testing.assert_array_equal(back[valid], flow[valid])
    assert np.isnan(back[~valid]).all()
    np.testing.assert_array_equal(lio.read_image(tmp_path / "a.png")[1, 2], [0, 0, 0])

    mask = np.ones((5, 6), dtype=bool)
    mask[0, 0] = mask[1, 2] = False
    lio.write_kitti_flow(tmp_path / "b.png", flow, valid=mask)
    assert np.array_equal(lio.read_kitti_flow(tmp_path / "b.png")[1], mask)
    nearly = flow + rng.uniform(-0.007, 0.007, flow.shape)     # rounds to the nearest 1/64
    lio.write_kitti_flow(tmp_path / "c.png", nearly)
    np.testing.assert_array_equal(lio.read_kitti_flow(tmp_path / "c.png")[0][valid], flow[valid])


def test_kitti_flow_refuses_unrepresentable_flow(tmp_path):
    with pytest.raises(ValueError, match="KITTI range"):
        lio.write_kitti_flow(tmp_path / "x.png", np.full((2, 2, 2), 600.0))
    nan_flow = np.zeros((2, 2, 2))
    nan_flow[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="marked valid"):
        lio.write_kitti_flow(tmp_path / "x.png", nan_flow, valid=np.ones((2, 2), dtype=bool))
    lio.write_png(tmp_path / "rgb8.png", np.zeros((2, 2, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="rgb8.png: expected a 16-bit RGB PNG"):
        lio.read_kitti_flow(tmp_path / "rgb8.png")
    assert not (tmp_path / "x.png").exists()


def test_kitti_ranges_at_their_ends(tmp_path):
    """The formats' last values round-trip and the next ones are refused: u = 512 px would
    be 65536, which a 16-bit PNG stores as 0, read back as −512 (a mutation survived)."""
    top = 511.984375  # (65535 − 2¹⁵) / 64
    flow = np.zeros((1, 2, 2))
    flow[0, 0] = (top, -512.0)
    lio.write_kitti_flow(tmp_path / "f.png", flow)
    back, _ = lio.read_kitti_flow(tmp_path / "f.png")
    np.testing.assert_array_equal(back, flow.astype(np.float32))
    flow[0, 0, 0] = 512.0
    with pytest.raises(ValueError, match=r"KITTI range \[-512, 511.98\] px, got -512 … 512"):
        lio.write_kitti_flow(tmp_path / "g.png", flow)
    lio.write_kitti_disparity(tmp_path / "d.png", np.array([[65535 / 256]]))
    assert lio.read_kitti_disparity(tmp_path / "d.png")[0][0, 0] == np.float32(65535 / 256)
    with pytest.raises(ValueError, match=r"KITTI range \[0, 255.996\]"):
        lio.write_kitti_disparity(tmp_path / "e.png", np.array([[256.0]]))
    assert not (tmp_path / "g.png").exists() and not (tmp_path / "e.png").exists()


def test_pfm_with_bytes_after_its_data(tmp_path):
    """Bytes after the data (a newline, junk) are ignored: the data start right after the
    header's whitespace byte, not at the file's last 4·count bytes."""
    a = np.arange(6, dtype=np.float32).reshape(2, 3) + 0.5
    for extra in (b"\n", b"junk at the end\n"):
        lio.write_pfm(tmp_path / "a.pfm", a)
        with open(tmp_path / "a.pfm", "ab") as f:
            f.write(extra)
        np.testing.assert_array_equal(lio.read_pfm(tmp_path / "a.pfm"), a)


def test_written_files_have_the_mode_open_gives(tmp_path):
    """Results are as readable as files open() makes (0o666 less the umask), not
    mkstemp's private 0o600 (colleagues, a web server)."""
    import os
    import stat

    old = os.umask(0o022)
    try:
        lio.write_pfm(tmp_path / "d.pfm", np.zeros((2, 2)))
        lio.write_flo(tmp_path / "f.flo", np.zeros((2, 2, 2)))
        lio.write_png(tmp_path / "p.png", np.zeros((2, 2), np.uint8))
        with open(tmp_path / "plain", "w"):
            pass
    finally:
        os.umask(old)
    for name in ("d.pfm", "f.flo", "p.png", "plain"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o644, name


def test_an_output_file_that_is_a_folder_is_refused_before_any_work(tmp_path):
    from lfsf._files import output_file

    with pytest.raises(ValueError, match="is a folder, not a file to write"):
        output_file(tmp_path)
    (tmp_path / "a_file").write_text("")
    with pytest.raises(ValueError, match=r"a_file/report\.json: cannot be written: .*a_file is a file, not a folder$"):
        output_file(tmp_path / "a_file" / "report.json")
    assert output_file(tmp_path / "report.json") == tmp_path / "report.json"


def test_kitti_disparity(tmp_path):
    raw = np.array([[896, 0], [1, 65535]], dtype=np.uint16)
    lio.write_png(tmp_path / "hand.png", raw)
    disp, valid = lio.read_kitti_disparity(tmp_path / "hand.png")
    np.testing.assert_array_equal(valid, [[True, False], [True, True]])
    np.testing.assert_array_equal(disp[valid], [3.5, 1 / 256, 65535 / 256])
    assert np.isnan(disp[0, 1])

    values = np.array([[0.0, 3.5, np.nan], [10.25, 0.001, 200.0]])
    lio.write_kitti_disparity(tmp_path / "d.png", values)
    back, valid = lio.read_kitti_disparity(tmp_path / "d.png")
    np.testing.assert_array_equal(valid, [[True, True, False], [True, True, True]])
    np.testing.assert_array_equal(back[valid], [1 / 256, 3.5, 10.25, 1 / 256, 200.0])
    with pytest.raises(ValueError, match="negative|range"):
        lio.write_kitti_disparity(tmp_path / "neg.png", np.array([[-1.0]]))
    assert not (tmp_path / "neg.png").exists()


# --------------------------------------------------------------------------------------
# Atomic writes
# --------------------------------------------------------------------------------------

_BIG = np.random.default_rng(11).random((64, 64, 3)).astype(np.float32)
WRITERS = {
    "pfm": ("out.pfm", lambda p, a: lio.write_pfm(p, a)),
    "flo": ("out.flo", lambda p, a: lio.write_flo(p, a[..., :2])),
    "png": ("out.png", lambda p, a: lio.write_png(p, (a * 65535).astype(np.uint16))),
    "kitti": ("out.png", lambda p, a: lio.write_kitti_flow(p, a[..., :2] * 100)),
    "npz": ("out.npz", lambda p, a: lio.write_lightfield(a[None, None], p)),
    "folder": ("lf/input_Cam000.png", lambda p, a: lio.write_lightfield(a[None, None], p.parent)),
}


@pytest.mark.parametrize("writer", sorted(WRITERS))
def test_failed_write_leaves_old_file_and_no_debris(tmp_path, file_size_limit, writer):
    name, write = WRITERS[writer]
    target = tmp_path / name
    write(target, _BIG[:2, :2])                  # a small, complete earlier file
    before = target.read_bytes()
    listing = sorted(p.name for p in target.parent.iterdir())
    with file_size_limit(1000):
        with pytest.raises(OSError):
            write(target, _BIG)                  # needs far more than 1000 bytes
    assert sorted(p.name for p in target.parent.iterdir()) == listing
    assert target.read_bytes() == before


# --------------------------------------------------------------------------------------
# Light fields on disk
# --------------------------------------------------------------------------------------


def _hci_folder(folder: Path, side: int, size=(4, 5), drop=(), channels=3) -> np.ndarray:
    """Write an HCI-layout folder of 8-bit views with imageio; view k = r·side + c."""
    folder.mkdir()
    shape = size + ((channels,) if channels > 1 else ())
    views = np.random.default_rng(side).integers(0, 256, (side, side) + shape).astype(np.uint8)
    for k in range(side * side):
        if k not in drop:
            iio.imwrite(folder / f"input_Cam{k:03d}.png", views[k // side, k % side])
    return views


def test_read_hci_folder(tmp_path):
    views = _hci_folder(tmp_path / "hci", 3)
    (tmp_path / "hci" / "parameters.cfg").write_text(
        "[intrinsics]\nfocal_length_mm = 100\nsensor_size_mm = 35.5\n\n"
        "[extrinsics]\nnum_cams_x = 3\nnum_cams_y = 3\n\n[meta]\nkind = synthetic\n")
    lf = lio.read_lightfield(tmp_path / "hci")
    assert lf.shape == (3, 3, 4, 5, 3) and lf.views.dtype == np.float32
    np.testing.assert_array_equal(lf.views, views / np.float32(255))
    assert lf.source == str(tmp_path / "hci")
    params = lf.meta["parameters"]
    assert params["intrinsics"] == {"focal_length_mm": 100, "sensor_size_mm": 35.5}
    assert params["extrinsics"]["num_cams_x"] == 3 and params["meta"]["kind"] == "synthetic"
    assert lf.meta["layout"] == "hci"


def test_hci_folder_takes_its_grid_from_parameters_cfg(tmp_path):
    """A rig that is not square, in the HCI layout: parameters.cfg's num_cams_x and
    num_cams_y give the grid (the count alone read 9 views as 3×3); a count that does not
    match them is an error naming both."""
    folder = tmp_path / "rig"
    folder.mkdir()
    views = np.random.default_rng(5).integers(0, 256, (9, 4, 5)).astype(np.uint8)
    for k in range(9):
        iio.imwrite(folder / f"input_Cam{k:03d}.png", views[k])
    for rows, cols in ((1, 9), (9, 1)):
        (folder / "parameters.cfg").write_text(f"[extrinsics]\nnum_cams_x = {cols}\nnum_cams_y = {rows}\n")
        lf = lio.read_lightfield(folder)
        assert lf.grid == (rows, cols)
        np.testing.assert_array_equal(lf.views.reshape(9, 4, 5), views / np.float32(255))
    (folder / "parameters.cfg").write_text("[extrinsics]\nnum_cams_x = 9.0\nnum_cams_y = 1.0\n")
    assert lio.read_lightfield(folder).grid == (1, 9)
    (folder / "parameters.cfg").write_text("[extrinsics]\nnum_cams_x = 5\nnum_cams_y = 2\n")
    with pytest.raises(ValueError, match=r"rig: parameters.cfg gives a grid of 2×5 views .* but there are 9"):
        lio.read_lightfield(folder)
    # (each had been read as a square 3×3 grid without a word)
    for text, needle in (("num_cams_x = 9\n", "it gives num_cams_x but not num_cams_y"),
                         ("num_cams_x = 9\nnum_cams_y = 0\n", "num_cams_y = 0"),
                         ("num_cams_x = 9 # nine\nnum_cams_y = 1\n", "num_cams_x = '9 # nine'")):
        (folder / "parameters.cfg").write_text("[meta]\n" + text)
        with pytest.raises(ValueError, match=rf"parameters.cfg: {needle}; the grid of views needs num_cams_x"):
            lio.read_lightfield(folder)
    (folder / "parameters.cfg").unlink()
    (folder / "input_Cam008.png").unlink()
    with pytest.raises(ValueError, match=r"square number of HCI views .* num_cams_x and num_cams_y in parameters"):
        lio.read_lightfield(folder)


def test_read_hci_folder_with_bad_parameters_warns(tmp_path):
    _hci_folder(tmp_path / "hci", 2)
    (tmp_path / "hci" / "parameters.cfg").write_text("no section header here\n")
    with pytest.warns(LfsfWarning, match="parameters.cfg"):
        lf = lio.read_lightfield(tmp_path / "hci")
    assert lf.grid == (2, 2) and lf.meta["parameters"] == {}


def test_hci_missing_view_is_named(tmp_path):
    _hci_folder(tmp_path / "hci", 3, drop=(4,))
    with pytest.raises(ValueError, match="input_Cam004.png") as info:
        lio.read_lightfield(tmp_path / "hci")
    assert str(info.value).startswith(str(tmp_path / "hci"))


def test_hci_non_square_count(tmp_path):
    _hci_folder(tmp_path / "hci", 3, drop=(8,))           # input_Cam000 … 007: 8 views
    with pytest.raises(ValueError, match="square") as info:
        lio.read_lightfield(tmp_path / "hci")
    assert "got 8" in str(info.value)


def test_view_size_mismatch_names_the_file(tmp_path):
    _hci_folder(tmp_path / "hci", 2)
    iio.imwrite(tmp_path / "hci" / "input_Cam002.png", np.zeros((4, 6, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="input_Cam002.png") as info:
        lio.read_lightfield(tmp_path / "hci")
    assert "5×4 RGB" in str(info.value) and "6×4 RGB" in str(info.value)
    iio.imwrite(tmp_path / "hci" / "input_Cam002.png", np.zeros((4, 5), dtype=np.uint8))
    with pytest.raises(ValueError, match="input_Cam002.png.*grey"):
        lio.read_lightfield(tmp_path / "hci")


def test_read_rowcol_folder_16_bit_grey(tmp_path):
    folder = tmp_path / "rc"
    folder.mkdir()
    views = np.random.default_rng(12).integers(0, 65536, (2, 3, 4, 5)).astype(np.uint16)
    for r in range(2):
        for c in range(3):
            iio.imwrite(folder / f"2067_{r + 1:02d}_{c + 1:02d}.png", views[r, c])
    (folder / "notes.txt").write_text("not a view")
    lf = lio.read_lightfield(folder)
    assert lf.shape == (2, 3, 4, 5) and not lf.is_colour
    np.testing.assert_allclose(lf.views, views / 65535.0, rtol=1e-6)
    assert lf.meta == {"layout": "rowcol", "prefix": "2067"}


def test_read_rowcol_folder_rgba_drops_alpha(tmp_path):
    folder = tmp_path / "rc"
    folder.mkdir()
    views = np.random.default_rng(13).integers(0, 256, (1, 2, 3, 3, 4)).astype(np.uint8)
    for c in range(2):
        iio.imwrite(folder / f"s_1_{c + 1}.png", views[0, c])
    lf = lio.read_lightfield(folder)
    assert lf.shape == (1, 2, 3, 3, 3)
    np.testing.assert_array_equal(lf.views, views[..., :3] / np.float32(255))


def test_grey_alpha_views_stay_grey(tmp_path):
    folder = tmp_path / "la"
    folder.mkdir()
    views = np.random.default_rng(18).integers(0, 256, (1, 1, 3, 4, 2)).astype(np.uint8)
    iio.imwrite(folder / "input_Cam000.png", views[0, 0])
    lf = lio.read_lightfield(folder)
    assert lf.shape == (1, 1, 3, 4)
    np.testing.assert_array_equal(lf.views, views[..., 0] / np.float32(255))


def test_rowcol_incomplete_grid_names_missing_views(tmp_path):
    folder = tmp_path / "rc"
    folder.mkdir()
    for r, c in [(1, 1), (1, 2), (2, 1)]:
        iio.imwrite(folder / f"scene_{r:02d}_{c:02d}.png", np.zeros((2, 2), dtype=np.uint8))
    with pytest.raises(ValueError, match="scene_02_02.png"):
        lio.read_lightfield(folder)
    iio.imwrite(folder / "other_01_01.png", np.zeros((2, 2), dtype=np.uint8))
    with pytest.raises(ValueError, match="several"):
        lio.read_lightfield(folder)


def test_a_pair_of_one_source_is_told_apart_as_t1_and_t2():
    """A light field and its crop keep one source: the message had named it twice."""
    lf = lio.LightField(np.zeros((3, 3, 20, 24), np.float32), source="syn/lf1.npz")
    with pytest.raises(ValueError, match=re.escape("syn/lf1.npz (t2): expected the grid and view size of "
                                                   "syn/lf1.npz (t1) (a 3×3 grid of 24×20 views), got a 3×3 "
                                                   "grid of 12×10 views")):
        lio.check_pair(lf, lf.crop(0, 0, 10, 12))


def test_a_whole_inner_grid_of_rowcol_views_is_told_to_start_at_01(tmp_path):
    """The inner 7×7 of a 9×9 (views 02…08 linked into a folder) had been refused only as
    an 8×8 grid missing 15 views, as though the user had lost them."""
    folder = tmp_path / "inner"
    folder.mkdir()
    for r in range(2, 5):
        for c in range(2, 5):
            iio.imwrite(folder / f"2067_{r:02d}_{c:02d}.png", np.zeros((2, 2), dtype=np.uint8))
    with pytest.raises(ValueError, match=re.escape("the 4×4 grid of views is incomplete, 7 missing: ")
                       + r".*" + re.escape("; the views there make a whole 3×3 grid from 2067_02_02.png: to read it "
                                           "alone, number its views from 01 (or give the views as an array)")):
        lio.read_lightfield(folder)
    (folder / "2067_03_03.png").unlink()  # not a whole grid: no such hint
    with pytest.raises(ValueError, match=r"8 missing: [^;]*$"):
        lio.read_lightfield(folder)


def test_a_stray_name_with_big_numbers_is_counted_not_listed(tmp_path):
    """A phone photo's name (IMG_20240101_120000.png) reads as view (20240101, 120000),
    a stray input_Cam99999999.png as view 10^8: the missing views are counted and the
    first few named, in milliseconds (listing them all hung, or ran out of memory)."""
    (tmp_path / "photos").mkdir()
    iio.imwrite(tmp_path / "photos" / "IMG_20240101_120000.png", np.zeros((2, 2), dtype=np.uint8))
    _hci_folder(tmp_path / "hci", 3)
    iio.imwrite(tmp_path / "hci" / "input_Cam99999999.png", np.zeros((4, 5, 3), dtype=np.uint8))
    previous = signal.signal(signal.SIGALRM, lambda *_: pytest.fail("still listing the missing views after 20 s"))
    signal.alarm(20)
    try:
        with pytest.raises(ValueError, match=r"the 20240101×120000 grid of views is incomplete, 2428812119999 "
                                             r"missing: IMG_00000001_000001.png, .* and 2428812119991 more$"):
            lio.read_lightfield(tmp_path / "photos")
        with pytest.raises(ValueError, match=r"input_Cam000 … input_Cam99999999 are incomplete, 99999990 "
                                             r"missing: input_Cam009.png, .*input_Cam016.png and 99999982 more$"):
            lio.read_lightfield(tmp_path / "hci")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_a_folder_with_views_in_both_layouts_is_an_error(tmp_path):
    """It was read as the HCI light field without a word about the other."""
    _hci_folder(tmp_path / "both", 2)
    iio.imwrite(tmp_path / "both" / "scene_01_01.png", np.zeros((4, 5, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match=r"both: holds views in two layouts, HCI \(input_Cam000.png, …\) and "
                                         r"row-column \(scene_01_01.png, …\)"):
        lio.read_lightfield(tmp_path / "both")


def test_a_views_name_on_no_image_file_or_on_frames_is_named_as_such(tmp_path):
    """A link to nothing, a link loop or a folder under a view's name had been told as the
    view missing; an animated PNG as an image of 32 channels, its width (a fuzzing helper)."""
    from PIL import Image

    _hci_folder(tmp_path / "v", 2)
    view = tmp_path / "v" / "input_Cam001.png"
    for make, said in ((lambda: view.symlink_to(tmp_path / "nowhere"), "a link to nothing (or a loop of links)"),
                       (lambda: view.symlink_to(view), "a link to nothing (or a loop of links)"),
                       (lambda: view.mkdir(), "a folder")):
        view.rmdir() if view.is_dir() and not view.is_symlink() else view.unlink()
        make()
        with pytest.raises(ValueError, match=re.escape(f"{view}: named as a view, but {said}")):
            lio.read_lightfield(tmp_path / "v")
    view.rmdir()
    frames = [Image.fromarray(np.full((4, 5), k * 80, np.uint8)) for k in range(2)]
    frames[0].save(view, save_all=True, append_images=frames[1:])
    with pytest.raises(ValueError, match=re.escape(f"{view}: expected a grey, RGB or RGBA image, got one of shape "
                                                   "(2, 4, 5) (an animated image's frames?)")):
        lio.read_lightfield(tmp_path / "v")


def test_writing_views_beside_those_of_the_other_layout_is_refused(tmp_path):
    """write_lightfield(hci) then write_lightfield(rowcol) into one folder wrote a folder
    that read_lightfield refuses (two layouts)."""
    views = np.random.default_rng(3).random((2, 2, 4, 5)).astype(np.float32)
    lio.write_lightfield(views, tmp_path / "mix")
    with pytest.raises(ValueError, match=r"mix: already holds views that these would mix with \(input_Cam000"):
        lio.write_lightfield(views, tmp_path / "mix", layout="rowcol")
    assert lio.read_lightfield(tmp_path / "mix").shape == (2, 2, 4, 5)


def test_writers_refuse_targets_they_cannot_write_before_writing(tmp_path, monkeypatch):
    """Each was a raw OSError (IsADirectoryError naming a temporary file, EBUSY,
    FileExistsError), or for '' a light field written into the current folder."""
    monkeypatch.chdir(tmp_path)
    image, views = np.zeros((3, 4), np.float32), np.zeros((2, 2, 8, 8), np.float32)
    (tmp_path / "adir.pfm").mkdir()
    (tmp_path / "afile").write_text("x")
    for write, needle in ((lambda: lio.write_pfm(tmp_path / "adir.pfm", image), "adir.pfm: is a folder"),
                          (lambda: lio.write_flo(".", np.zeros((3, 4, 2))), ".: is a folder"),
                          (lambda: lio.write_pfm("", image), "an empty file name"),
                          (lambda: lio.write_pfm(tmp_path / "afile" / "x.pfm", image), "afile is a file, not a folder"),
                          (lambda: lio.write_lightfield(views, tmp_path / "afile"), "afile is a file, not a folder"),
                          (lambda: lio.write_lightfield(views, ""), "an empty path")):
        with pytest.raises(ValueError, match=re.escape(needle)):
            write()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir.pfm", "afile"]


def test_readers_refuse_what_is_not_a_regular_file(tmp_path):
    """A named pipe blocked every reader for ever (waiting for a writer); /dev/zero was a
    MemoryError; a path of bytes or None a TypeError from pathlib."""
    import os

    from lfsf import evaluate

    os.mkfifo(tmp_path / "pipe.npz")
    for read in (lio.read_lightfield, lio.read_pfm, lio.read_flo, evaluate.load_ground_truth, evaluate.load_estimate):
        with pytest.raises(ValueError, match="pipe.npz: not a regular file"):
            read(tmp_path / "pipe.npz")
    with pytest.raises(ValueError, match="/dev/zero: not a regular file"):
        lio.read_flo("/dev/zero")
    for path in (b"x.pfm", None):
        with pytest.raises(ValueError, match="expected a file name"):
            lio.read_pfm(path)


def test_rowcol_indices_are_one_based(tmp_path):
    folder = tmp_path / "rc"
    folder.mkdir()
    iio.imwrite(folder / "s_00_01.png", np.zeros((2, 2), dtype=np.uint8))
    with pytest.raises(ValueError, match="1-based"):
        lio.read_lightfield(folder)


def test_other_tools_layouts_are_read_or_told(tmp_path):
    """Layouts of other tools and file systems (a helper's survey of public datasets):
    hidden files (macOS's ._view_01_01.png) are skipped in both layouts; views numbered
    from 0 (row-column) or from 1 (HCI), a parameters.cfg of another grid, a grey view
    among colour ones, an ESLF image and .npy / .h5 / .mat files are each told what to do."""
    views = np.random.default_rng(3).integers(0, 255, (3, 3, 6, 8), dtype=np.uint8)
    rc = tmp_path / "rc"
    lio.write_lightfield(views, rc, bit_depth=8, layout="rowcol")
    for name in sorted(p.name for p in rc.iterdir()):
        (rc / f"._{name}").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    (rc / ".view_02_02.png").write_bytes(b"")
    read = lio.read_lightfield(rc)
    np.testing.assert_array_equal(read.views, views / np.float32(255))
    hci = tmp_path / "hci"
    lio.write_lightfield(views, hci, bit_depth=8)
    (hci / "._input_Cam000.png").write_bytes(b"\x00")
    assert lio.read_lightfield(hci).grid == (3, 3)
    lio.write_lightfield(views, hci, bit_depth=8)  # (hidden files are no views that these would mix with)
    lio.write_lightfield(views, rc, bit_depth=8, layout="rowcol")

    zero = tmp_path / "zero"
    zero.mkdir()
    for r in range(2):
        for c in range(2):
            iio.imwrite(zero / f"view_{r:02d}_{c:02d}.png", views[r, c])
    with pytest.raises(ValueError, match=r"got \(0, 0\): numbered from 0\? rename the views from view_01_01.png"):
        lio.read_lightfield(zero)
    one = tmp_path / "one"
    one.mkdir()
    for k in range(9):
        iio.imwrite(one / f"input_Cam{k + 1:03d}.png", views[k // 3, k % 3])
    with pytest.raises(ValueError, match=r"1 missing: input_Cam000.png; the views seem numbered from 1"):
        lio.read_lightfield(one)
    (hci / "parameters.cfg").write_text((hci / "parameters.cfg").read_text().replace("num_cams_x = 3",
                                                                                    "num_cams_x = 9"))
    with pytest.raises(ValueError, match=r"correct num_cams_x and num_cams_y in its \[extrinsics\]"):
        lio.read_lightfield(hci)
    mixed = tmp_path / "mixed"
    colour = np.repeat(views[..., None], 3, axis=-1)
    lio.write_lightfield(colour, mixed, bit_depth=8)
    iio.imwrite(mixed / "input_Cam004.png", views[1, 1])
    with pytest.raises(ValueError, match=r"input_Cam004.png: expected the colour of input_Cam000.png \(8×6 RGB\), "
                                         r"got 8×6 grey"):
        lio.read_lightfield(mixed)

    eslf = tmp_path / "IMG_0001.eslf.png"
    iio.imwrite(eslf, lio.views_to_lenslet(views))
    with pytest.raises(ValueError, match=r"an ESLF image .*lfsf.io.lenslet_to_views\(lfsf.io.read_image"):
        lio.read_lightfield(eslf)
    # (the recipe it gives reads the views back, as stored: integers, which an .npz scales by their type)
    np.savez(tmp_path / "lf.npz", views=lio.lenslet_to_views(lio.read_image(eslf), (3, 3)))
    np.testing.assert_array_equal(lio.read_lightfield(tmp_path / "lf.npz").views, views / np.float32(255))
    for name, said in (("lf.npy", r"a .npy array: .*np.savez\('lf.npz', views=np.load\('.*lf.npy'\)\)"),
                       ("lf.h5", "an HDF5 file: read its light-field array with h5py"),
                       ("IMG__Decoded.mat", r"a MATLAB file \(LFToolbox's \*__Decoded.mat holds LF as \[j, i, l, k, c\]")):
        (tmp_path / name).write_bytes(b"\x93NUMPY" if name.endswith(".npy") else b"\x89HDF")
        with pytest.raises(ValueError, match=f"unknown light-field format .*; this is {said}"):
            lio.read_lightfield(tmp_path / name)


def test_folder_without_views_says_what_was_looked_for(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("hello")
    with pytest.raises(ValueError) as info:
        lio.read_lightfield(tmp_path / "empty")
    message = str(info.value)
    assert "input_Cam000.png" in message and "_RR_CC.png" in message and "views.npz" in message


@pytest.mark.parametrize("name", ["lf_01_01.tif", "input_Cam000.JPG"])
def test_views_in_another_image_format_are_named_as_such(tmp_path, name):
    """They had been "no light-field views" though named as views."""
    (tmp_path / "v").mkdir()
    (tmp_path / "v" / name).write_bytes(b"")
    with pytest.raises(ValueError, match=re.escape(f"PNG files only; found 1 named as views but in another "
                                                   f"format ({name}, …)")):
        lio.read_lightfield(tmp_path / "v")


def test_single_image_is_a_raw_lenslet_image(tmp_path):
    lio.write_png(tmp_path / "raw.png", np.zeros((4, 4), dtype=np.uint16))
    with pytest.raises(ValueError, match="lfsf decode"):
        lio.read_lightfield(tmp_path / "raw.png")
    (tmp_path / "x.weird").write_bytes(b"")
    with pytest.raises(ValueError, match="unknown light-field format"):
        lio.read_lightfield(tmp_path / "x.weird")


def test_read_npz(tmp_path):
    floats = np.random.default_rng(14).random((2, 2, 3, 4, 3)).astype(np.float32) * 1.5
    np.savez(tmp_path / "f.npz", views=floats)
    np.testing.assert_array_equal(lio.read_lightfield(tmp_path / "f.npz").views, floats)
    np.savez(tmp_path / "u8.npz", views=np.full((1, 2, 2, 2), 51, dtype=np.uint8))
    np.testing.assert_allclose(lio.read_lightfield(tmp_path / "u8.npz").views, 0.2, rtol=1e-6)
    np.savez(tmp_path / "u16.npz", views=np.full((1, 2, 2, 2), 13107, dtype=np.uint16))
    np.testing.assert_allclose(lio.read_lightfield(tmp_path / "u16.npz").views, 0.2, rtol=1e-6)
    np.savez(tmp_path / "nokey.npz", other=floats)
    with pytest.raises(ValueError, match="nokey.npz.*'views'"):
        lio.read_lightfield(tmp_path / "nokey.npz")
    (tmp_path / "corrupt.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ValueError, match="corrupt.npz"):
        lio.read_lightfield(tmp_path / "corrupt.npz")
    bad = floats.copy()
    bad[1, 1, 0, 0, 0] = np.nan
    np.savez(tmp_path / "nan.npz", views=bad)
    with pytest.raises(ValueError, match=r"nan.npz: .*\(1, 1\)"):
        lio.read_lightfield(tmp_path / "nan.npz")


def test_folder_with_only_views_npz(tmp_path):
    (tmp_path / "dec").mkdir()
    views = np.random.default_rng(15).random((3, 3, 2, 2)).astype(np.float32)
    np.savez(tmp_path / "dec" / "views.npz", views=views)
    np.testing.assert_array_equal(lio.read_lightfield(tmp_path / "dec").views, views)


def _damaged_compressed_npz(path: Path, **arrays) -> None:
    """A ``np.savez_compressed`` file whose first member's deflate stream starts with an
    invalid block type (0b11), so that decompressing it fails in zlib, not in a CRC check."""
    np.savez_compressed(path, **arrays)
    data = bytearray(path.read_bytes())
    assert data[:4] == b"PK\x03\x04" and struct.unpack("<H", data[8:10])[0] == 8   # deflated
    name_length, extra_length = struct.unpack("<HH", data[26:30])
    start = 30 + name_length + extra_length
    data[start:start + 2] = b"\xff\xff"
    path.write_bytes(bytes(data))


def test_damaged_compressed_npz_names_the_file(tmp_path):
    _damaged_compressed_npz(tmp_path / "views.npz", views=np.zeros((2, 2, 8, 8), np.float32))
    with pytest.raises(ValueError, match=r"views.npz: cannot read as .npz \(zlib.error"):
        lio.read_lightfield(tmp_path / "views.npz")


def _npz_claiming_shape(path: Path, key: str, shape: tuple, version: tuple = (1, 0)) -> None:
    """A small .npz whose member's .npy header (of format ``version``) claims ``shape`` but
    holds 16 bytes."""
    header = io.BytesIO()
    write = np.lib.format.write_array_header_1_0 if version == (1, 0) else np.lib.format.write_array_header_2_0
    write(header, {"descr": "<f4", "fortran_order": False, "shape": shape})
    header = bytearray(header.getvalue())
    header[6] = version[0]   # (3.0: 2.0's layout, another version byte)
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr(key + ".npy", bytes(header) + bytes(16))


def test_npz_whose_header_claims_a_huge_shape_is_a_value_error(tmp_path):
    """Read before any allocation: not a MemoryError (a traceback, status 1) for 3 TB."""
    _npz_claiming_shape(tmp_path / "huge.npz", "views", (9, 9, 99999, 99999))
    with pytest.raises(ValueError, match=r"huge.npz: 'views' is damaged: its header claims shape "
                                         r"\(9, 9, 99999, 99999\).* holds 16 bytes"):
        lio.read_lightfield(tmp_path / "huge.npz")
    _npz_claiming_shape(tmp_path / "fits.npz", "views", (1, 1, 2, 2))    # exactly 16 bytes
    assert lio.read_lightfield(tmp_path / "fits.npz").views.shape == (1, 1, 2, 2)
    # format 3.0 (UTF-8 field names) too: it had reached np.load's allocation, "out of memory"
    for version in ((2, 0), (3, 0)):
        _npz_claiming_shape(tmp_path / "v.npz", "views", (9, 9, 99999, 99999), version)
        with pytest.raises(ValueError, match=r"v.npz: 'views' is damaged: its header claims shape"):
            lio.read_lightfield(tmp_path / "v.npz")


def test_npz_that_is_not_a_zip_says_so(tmp_path):
    (tmp_path / "text.npz").write_bytes(b"just some text, no zip archive\n")
    np.save(tmp_path / "array.npy", np.zeros((1, 1, 2, 2), np.float32))
    (tmp_path / "array.npy").rename(tmp_path / "array.npz")     # np.load gives an ndarray
    for name in ("text.npz", "array.npz"):
        with pytest.raises(ValueError, match=rf"{name}: not a valid .npz \(zip\) file") as info:
            lio.read_lightfield(tmp_path / name)
        assert "pickle" not in str(info.value)
    (tmp_path / "empty.npz").write_bytes(b"")
    with pytest.raises(ValueError, match="empty.npz: empty file"):
        lio.read_lightfield(tmp_path / "empty.npz")


def test_empty_view_png_is_one_line_naming_the_file(tmp_path):
    _hci_folder(tmp_path / "hci", 2)
    (tmp_path / "hci" / "input_Cam003.png").write_bytes(b"")
    with pytest.raises(ValueError, match="input_Cam003.png: cannot read image: empty file") as info:
        lio.read_lightfield(tmp_path / "hci")
    assert "\n" not in str(info.value)
    (tmp_path / "hci" / "input_Cam003.png").write_bytes(b"no image in here")
    with pytest.raises(ValueError, match="input_Cam003.png: cannot read image") as info:
        lio.read_lightfield(tmp_path / "hci")
    assert "\n" not in str(info.value) and "pyav" not in str(info.value)


def test_float64_views_beyond_float32_fail_without_an_overflow_warning(tmp_path):
    views = np.full((2, 2, 3, 3), 0.5)
    views[1, 0, 1, 1] = 1e300
    np.savez(tmp_path / "huge.npz", views=views)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"huge.npz: expected pixel values within float32's range.*\(1, 0\)"):
            lio.read_lightfield(tmp_path / "huge.npz")


@pytest.mark.parametrize("colour", [True, False])
def test_write_lightfield_round_trips(tmp_path, colour):
    shape = (3, 3, 5, 6) + ((3,) if colour else ())
    views = np.random.default_rng(16).random(shape).astype(np.float32)
    lf = lio.LightField(views)
    lio.write_lightfield(lf, tmp_path / "lf.npz")
    with np.load(tmp_path / "lf.npz") as data:
        assert data["views"].dtype == np.float32
    np.testing.assert_array_equal(lio.read_lightfield(tmp_path / "lf.npz").views, views)
    for bit_depth in (16, 8):
        folder = tmp_path / f"hci{bit_depth}"
        lio.write_lightfield(views, folder, bit_depth=bit_depth)
        assert (folder / "input_Cam008.png").is_file()
        assert lio.read_image(folder / "input_Cam000.png").dtype == f"uint{bit_depth}"
        back = lio.read_lightfield(folder)
        assert back.shape == views.shape and back.meta["layout"] == "hci"
        step = 1 / (2 ** bit_depth - 1)
        assert np.abs(back.views - views).max() <= 0.5 * step + 1e-7


def test_write_lightfield_non_square_grid(tmp_path):
    views = np.random.default_rng(17).random((2, 3, 4, 4)).astype(np.float32)
    with pytest.raises(ValueError, match="square"):
        lio.write_lightfield(views, tmp_path / "hci")
    lio.write_lightfield(views, tmp_path / "rc", layout="rowcol")
    back = lio.read_lightfield(tmp_path / "rc")
    assert back.grid == (2, 3)
    np.testing.assert_allclose(back.views, views, atol=0.5 / 65535 + 1e-7)


def test_write_lightfield_refuses_to_mix_with_other_views(tmp_path):
    lio.write_lightfield(np.zeros((3, 3, 2, 2)), tmp_path / "hci")
    with pytest.raises(ValueError, match="input_Cam004.png"):
        lio.write_lightfield(np.ones((2, 2, 2, 2)), tmp_path / "hci")
    lio.write_lightfield(np.ones((3, 3, 2, 2)), tmp_path / "hci")          # same grid: fine
    np.testing.assert_array_equal(lio.read_lightfield(tmp_path / "hci").views, 1.0)
    with pytest.raises(ValueError, match="nan"):
        lio.write_lightfield(np.full((1, 1, 2, 2), np.nan), tmp_path / "nan")


# --------------------------------------------------------------------------------------
# Real data (../shared/data)
# --------------------------------------------------------------------------------------


def _data(name: str) -> Path:
    from conftest import data_path

    return data_path(name)


@pytest.fixture(scope="module")
def antinous():
    return lio.read_lightfield(_data("hci-antinous"))


@pytest.fixture(scope="module")
def lytro():
    return lio.read_lightfield(_data("lytro-illum-2067"))


def _hand_parsed_pfm(path: Path) -> np.ndarray:
    magic, size, scale, body = path.read_bytes().split(b"\n", 3)
    assert magic == b"Pf" and scale == b"-1"
    width, height = (int(n) for n in size.split())
    return np.frombuffer(body, dtype="<f4").reshape(height, width)[::-1]


def test_real_hci_light_field(antinous):
    assert antinous.shape == (9, 9, 512, 512, 3)
    assert antinous.views.dtype == np.float32
    folder = _data("hci-antinous")
    np.testing.assert_array_equal(antinous.centre,
                                  iio.imread(folder / "input_Cam040.png") / np.float32(255))
    np.testing.assert_array_equal(antinous.view(2, 7),
                                  iio.imread(folder / "input_Cam025.png") / np.float32(255))


def test_real_lytro_light_field(lytro):
    assert lytro.shape == (9, 9, 383, 552, 3)
    folder = _data("lytro-illum-2067")
    np.testing.assert_array_equal(lytro.view(0, 1),
                                  iio.imread(folder / "2067_01_02.png") / np.float32(255))


@pytest.mark.parametrize("name, shape", [
    ("hci-antinous/gt_disp_lowres.pfm", (512, 512)),
    ("lytro-illum-2067/epinet_disparity_estimate.pfm", (361, 530)),
])
def test_real_pfm_matches_hand_parse(tmp_path, name, shape):
    path = _data(name.split("/")[0]) / name.split("/")[1]
    disparity = lio.read_pfm(path)
    assert disparity.shape == shape and disparity.dtype == np.float32
    np.testing.assert_array_equal(disparity, _hand_parsed_pfm(path))
    lio.write_pfm(tmp_path / "copy.pfm", disparity)
    assert (tmp_path / "copy.pfm").read_bytes() == path.read_bytes()


def test_real_hci_disparity_range():
    disparity = lio.read_pfm(_data("hci-antinous") / "gt_disp_lowres.pfm")
    assert -3.2 < disparity.min() < -3.0 and 2.6 < disparity.max() < 2.8


def test_our_png_decoder_on_a_real_file():
    path = _data("hci-antinous") / "input_Cam040.png"
    np.testing.assert_array_equal(lio.decode_png(path.read_bytes()), iio.imread(path))


def _warp_errors(lf, disparity, crop, view):
    """Mean |grey difference| to the centre of view (a, b) warped by ±disparity and not
    warped; MODEL.md §1: a centre pixel p is seen in view φ at p − d·φ."""
    a, b = view
    phi_x, phi_y = b - lf.centre_index[1], a - lf.centre_index[0]
    h, w = disparity.shape
    y, x = np.mgrid[crop:crop + h, crop:crop + w].astype(np.float64)
    side = lf.view(a, b) @ LUMA
    centre = (lf.centre @ LUMA)[crop:crop + h, crop:crop + w]
    border = (slice(15, -15), slice(15, -15))
    errors = []
    for sign in (1, -1, 0):
        warped = _bilinear(side, x - sign * disparity * phi_x, y - sign * disparity * phi_y)
        errors.append(np.abs(warped - centre)[border].mean())
    return errors


@pytest.mark.parametrize("view", [(4, 8), (8, 4), (0, 0)])
def test_hci_disparity_sign_convention(antinous, view):
    disparity = lio.read_pfm(_data("hci-antinous") / "gt_disp_lowres.pfm")
    right, wrong, unwarped = _warp_errors(antinous, disparity, 0, view)
    assert right < 0.015
    assert right < 0.5 * wrong and right < 0.5 * unwarped


@pytest.mark.parametrize("view", [(4, 8), (8, 4)])
def test_lytro_views_follow_the_convention(lytro, view):
    disparity = lio.read_pfm(_data("lytro-illum-2067") / "epinet_disparity_estimate.pfm")
    right, wrong, unwarped = _warp_errors(lytro, disparity, 11, view)
    assert right < 0.6 * wrong and right < 0.6 * unwarped


@pytest.mark.parametrize("path", [None, 3, "", "  "])
def test_read_lightfield_needs_a_path(path):
    with pytest.raises(ValueError, match="needs the path of a light field"):
        lio.read_lightfield(path)


@pytest.mark.parametrize("end", [b"\n", b" ", b"\r\n", b"  \n", b"\t"])
def test_pfm_header_end_and_data_that_starts_with_a_newline_byte(tmp_path, end):
    """One whitespace byte ends the header (the spec); more (CRLF, trailing spaces) is
    told apart from data whose first byte is itself whitespace (here 0x0a)."""
    first = struct.unpack("<f", b"\n\x00\x80\x3f")[0]
    a = np.array([[1, 2], [first, 4]], np.float32)
    path = tmp_path / "h.pfm"
    path.write_bytes(b"Pf\n2 2\n-1" + end + a[::-1].astype("<f4").tobytes())
    np.testing.assert_array_equal(lio.read_pfm(path), a)


def test_small_api_gaps_are_closed(tmp_path):
    """meta=None was a TypeError; big-endian uint16 samples were refused by write_png."""
    assert lio.LightField(np.zeros((2, 2, 8, 8)), meta=None).meta == {}
    image = (np.arange(12).reshape(3, 4) * 1000).astype(">u2")
    lio.write_png(tmp_path / "be.png", image)
    np.testing.assert_array_equal(lio.read_image(tmp_path / "be.png"), image.astype(np.uint16))


@pytest.mark.parametrize("where", ["atomic_path", "file_set"])
def test_an_os_error_without_a_file_name_names_what_was_being_written(tmp_path, where):
    """A full disk's ``[Errno 28] No space left on device`` names no file: the writers add
    the file (or the folder of a set of results) being written, and leave nothing
    behind; an error that names its file is passed on as it is."""
    import errno
    import os

    from lfsf import _files

    def write(exc):
        if where == "atomic_path":
            with _files.atomic_path(tmp_path / "r.pfm") as tmp:
                tmp.write_bytes(b"x")
                raise exc(tmp) if callable(exc) else exc
        with _files.file_set(tmp_path / "out", ["a.pfm"]) as tmp:
            (tmp / "a.pfm").write_bytes(b"x")
            raise exc(tmp / "a.pfm") if callable(exc) else exc

    target = os.fspath(tmp_path / ("r.pfm" if where == "atomic_path" else "out"))
    with pytest.raises(OSError) as raised:
        write(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))
    assert raised.value.errno == errno.ENOSPC and raised.value.filename == target
    assert str(raised.value) == f"[Errno 28] No space left on device: '{target}'"
    # one that names the temporary file names the file it was to become (the temporary
    # name, ".lfsf-set.HOST-PID.XXXX/a.pfm", means nothing to whoever reads the message)
    named = os.fspath(tmp_path / ("r.pfm" if where == "atomic_path" else "out/a.pfm"))
    with pytest.raises(OSError) as raised:
        write(lambda tmp: OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), os.fspath(tmp)))
    assert str(raised.value) == f"[Errno 28] No space left on device: '{named}'"
    with pytest.raises(OSError) as raised:
        write(FileNotFoundError(errno.ENOENT, "gone", "/else/where"))
    assert type(raised.value) is FileNotFoundError and raised.value.filename == "/else/where"
    left = sorted(p.name for p in tmp_path.rglob("*"))
    assert left == [], left  # (the set's folder too, made for it)


def test_a_tiff_with_no_pixels_is_an_error_naming_the_file_and_why(tmp_path, capsys):
    """A TIFF header before garbage: tifffile logs "invalid offset to first page" and
    decodes nothing; read_image says so in its error instead of passing on an empty array
    (decode then said "expected a 2-D sensor image, got shape (0,)") and of the log line."""
    path = tmp_path / "bad.tif"
    path.write_bytes(b"II*\x00" + np.random.default_rng(1).integers(0, 256, 1000, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match=r"bad\.tif: cannot read image: no pixels decoded \(invalid offset"):
        lio.read_image(path)
    assert capsys.readouterr().err == ""


def test_a_set_of_results_is_written_through_a_symbolic_link(tmp_path):
    """file_set (lfsf run's results): a link in a result's place stays a link, and the
    file it names gets the new contents, as a single file's atomic write does."""
    import os

    from lfsf import _files

    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "a.pfm").write_bytes(b"old")
    (tmp_path / "out").mkdir()
    os.symlink(tmp_path / "elsewhere" / "a.pfm", tmp_path / "out" / "a.pfm")
    with _files.file_set(tmp_path / "out", ["a.pfm", "b.pfm"]) as tmp:
        (tmp / "a.pfm").write_bytes(b"new a")
        (tmp / "b.pfm").write_bytes(b"new b")
    assert (tmp_path / "out" / "a.pfm").is_symlink()
    assert (tmp_path / "elsewhere" / "a.pfm").read_bytes() == b"new a"
    assert (tmp_path / "out" / "b.pfm").read_bytes() == b"new b"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.pfm", "b.pfm"]
    assert sorted(p.name for p in (tmp_path / "elsewhere").iterdir()) == ["a.pfm"]


@pytest.mark.parametrize("fails", ["b.pfm", "c.pfm", "old.png"])
def test_a_set_whose_move_fails_puts_the_earlier_files_back(tmp_path, monkeypatch, fails):
    """A result file that cannot be replaced (immutable, another user's, open in a viewer
    elsewhere) after others were: the earlier set is put back whole, and the error names
    the file. (A helper's immutable sceneflow.npz had left disp1.pfm, disp2.pfm and
    flow.flo of the new run beside the earlier run's sceneflow.npz and pictures.)"""
    import errno
    import os

    from lfsf import _files

    out = tmp_path / "out"
    out.mkdir()
    earlier = {"a.pfm": b"old a", "b.pfm": b"old b", "old.png": b"old picture", "mine.txt": b"the user's"}
    for name, data in earlier.items():
        (out / name).write_bytes(data)
    replace = os.replace

    def refused(src, dst, *args, **kwargs):
        if Path(src) == out / fails or (Path(dst) == out / fails and fails != "old.png"):
            raise PermissionError(errno.EPERM, os.strerror(errno.EPERM), os.fspath(src), os.fspath(dst))
        return replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(_files.os, "replace", refused)
    with pytest.raises(OSError) as raised:
        with _files.file_set(out, ["a.pfm", "b.pfm", "c.pfm"], stale=["old.png"]) as tmp:
            for name in ("a.pfm", "b.pfm", "c.pfm"):
                (tmp / name).write_bytes(b"new " + name.encode())
    assert raised.value.errno == errno.EPERM and raised.value.filename == os.fspath(out / fails)
    assert "nothing was replaced: the earlier files are as they were" in str(raised.value)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == earlier


def test_a_file_held_open_for_a_moment_is_replaced_on_a_later_try(tmp_path, monkeypatch):
    """Windows refuses to replace a file that a viewer, a virus scanner or the search
    indexer holds open (PermissionError), often for a moment: lfsf's writes try again there
    (REPLACE_TRIES), and give up with the error after the last try."""
    import os
    import time

    from lfsf import _files

    real, tries = os.replace, []

    def held(src, dst):
        tries.append(dst)
        if len(tries) < 3:
            raise PermissionError(13, "Permission denied", os.fspath(dst))
        real(src, dst)

    monkeypatch.setattr(_files.os, "replace", held)
    monkeypatch.setattr(time, "sleep", lambda seconds: None)   # (replace's waits between tries)
    monkeypatch.setattr(_files, "REPLACE_TRIES", 3)
    _files.write_bytes_atomic(tmp_path / "a.pfm", b"new")
    assert (tmp_path / "a.pfm").read_bytes() == b"new" and len(tries) == 3
    tries.clear()
    monkeypatch.setattr(_files, "REPLACE_TRIES", 2)
    with pytest.raises(PermissionError):
        _files.write_bytes_atomic(tmp_path / "b.pfm", b"new")
    assert len(tries) == 2 and [p.name for p in tmp_path.iterdir()] == ["a.pfm"]   # (no temporary file left)


def test_a_temporary_folders_process_is_gone_only_where_it_can_be_told(tmp_path, monkeypatch):
    """One rule for every temporary folder lfsf removes (file_set's, lfsf batch's pairs',
    Warp's builds): a process of this machine, not this one, that no longer runs. A
    process id beyond C's long in a folder's name had raised OverflowError in dead_set."""
    import os
    import subprocess
    import sys

    from lfsf import _files

    ended = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                               text=True).stdout)
    other = "0123456789ab" if _files._host() != "0123456789ab" else "ba9876543210"
    assert _files.gone(ended) and _files.gone(ended, _files._host())
    assert not _files.gone(os.getpid()) and not _files.gone(os.getppid())
    assert not _files.gone(ended, other)   # (another machine's: its processes cannot be asked)
    assert not _files.gone(10 ** 30)       # (no process id at all: not known to be gone)
    huge = tmp_path / f"{_files.SET_PREFIX}{_files._host()}-{10 ** 30}.abcd"
    huge.mkdir()
    assert not _files.dead_set(huge)
    dead = tmp_path / f"{_files.SET_PREFIX}{_files._host()}-{ended}.abcd"
    dead.mkdir()
    assert _files.dead_set(dead)
    monkeypatch.setattr(_files.os, "name", "nt")   # (off POSIX a process cannot be asked: Windows' kill ends it)
    assert not _files.gone(ended) and not _files.dead_set(dead)


@pytest.mark.parametrize("signum", ["SIGINT", "SIGTERM"])
def test_a_signal_as_a_set_is_tidied_away_leaves_no_hidden_folder(tmp_path, monkeypatch, signum):
    """A signal while file_set removed its temporary folder (which keeps the earlier set's
    files until the new one is in place) had cut the removal short: a hidden folder with the
    earlier result stayed in the output (a helper's lfsf run, 10 of 12 times). The signal
    is held back until the folder is gone, and then delivered."""
    import shutil
    import signal

    from lfsf import _files
    from lfsf._errors import Terminated, terminate_as_interrupt

    out = tmp_path / "out"
    out.mkdir()
    (out / "a.pfm").write_bytes(b"earlier")
    rmtree = shutil.rmtree

    def signalled(path, *args, **kwargs):  # (the signal as the removal starts)
        signal.raise_signal(getattr(signal, signum))
        return rmtree(path, *args, **kwargs)

    monkeypatch.setattr(shutil, "rmtree", signalled)
    with terminate_as_interrupt(), pytest.raises(KeyboardInterrupt) as raised:
        with _files.file_set(out, ["a.pfm"]) as tmp:
            (tmp / "a.pfm").write_bytes(b"new")
    assert isinstance(raised.value, Terminated) == (signum == "SIGTERM")
    assert [p.name for p in out.iterdir()] == ["a.pfm"] and (out / "a.pfm").read_bytes() == b"new"


@pytest.mark.parametrize("name", ["lf.h5", "lf.mat", "lf.npy"])
def test_write_lightfield_refuses_a_file_format_it_does_not_write(tmp_path, name):
    """A folder of PNG views named lf.h5 was made without a word."""
    views = np.zeros((3, 3, 8, 8), np.float32)
    with pytest.raises(ValueError, match=f"not as {name[2:]}; give a .npz or a folder name"):
        lio.write_lightfield(views, tmp_path / name)
    assert not (tmp_path / name).exists()
    (tmp_path / name).mkdir()          # a folder of that name that exists is the user's choice
    assert lio.read_lightfield(lio.write_lightfield(views, tmp_path / name)).grid == (3, 3)


def test_the_checkouts_model_is_the_workspaces():
    """docs/MODEL.md is a copy of the workspace's ../shared/MODEL.md, which the docstrings
    cite for the conventions (a clone had nothing to follow): kept the same."""
    from conftest import ROOT

    shared = ROOT.parent / "shared" / "MODEL.md"
    if not shared.is_file():
        pytest.skip(f"{shared} not present")
    assert (ROOT / "docs" / "MODEL.md").read_bytes() == shared.read_bytes(), "copy ../shared/MODEL.md to docs/"


def test_a_masked_array_with_masked_values_is_refused():
    """np.asarray drops a masked array's mask, so its masked values were used as data."""
    views = np.ma.masked_array(np.full((3, 3, 8, 8), 0.5, np.float32))
    assert lio.LightField(views).views.shape == (3, 3, 8, 8)  # (nothing masked: as the values)
    views[1, 1, 2, 3] = np.ma.masked
    with pytest.raises(ValueError, match=r"<array>: a masked array with 1 masked values"):
        lio.LightField(views)


def test_crop_and_downsample_take_the_same_region_and_block_means_of_every_view():
    rng = np.random.default_rng(3)
    views = rng.random((3, 2, 9, 11, 3)).astype(np.float32)
    lf = lio.LightField(views, source="lf", meta={"layout": "npz"})
    part = lf.crop(top=2, left=3, height=5, width=4)
    np.testing.assert_array_equal(part.views, views[:, :, 2:7, 3:7])
    assert part.source == "lf" and part.meta == {"layout": "npz"} and not np.shares_memory(part.views, views)
    small = lf.downsample(2)
    assert small.shape == (3, 2, 4, 5, 3)
    # by hand: view (1, 0), pixel (3, 4), green
    expected = views[1, 0, 6:8, 8:10, 1].astype(np.float64).mean()
    assert small.views[1, 0, 3, 4, 1] == pytest.approx(expected, rel=1e-6)
    np.testing.assert_array_equal(lf.downsample(1).views, views)
    assert lf.downsample(4).shape[2:4] == (2, 2)
    with pytest.raises(ValueError, match=r"^lf: the crop of 2×0 px is empty"):
        lf.crop(top=0, left=0, height=0, width=2)
    with pytest.raises(ValueError, match=r"^lf: the crop of 10×200 px at column 0, row 100 does not lie"):
        lf.crop(np.uint8(100), 0, np.uint8(200), 10)   # (uint8: 100 + 200 had wrapped round to 44)
    decoded = lio.LightField(views, meta={"lattice": 1, "plane_origin": (0, 0), "decode": {}, "lens_views": 5})
    assert decoded.crop(0, 0, 4, 4).meta == decoded.downsample(2).meta == {"lens_views": 5}
    for bad in [dict(top=-1, left=0, height=2, width=2), dict(top=0, left=0, height=10, width=2),
                dict(top=0, left=8, height=2, width=4)]:
        with pytest.raises(ValueError, match=r"^lf: the crop of \d+×\d+ px at column -?\d+, row -?\d+ does not lie "
                                             r"within the 11×9 views"):
            lf.crop(**bad)
    with pytest.raises(ValueError, match=r"^lf: crop's height must be a whole number of pixels, got 2\.5"):
        lf.crop(0, 0, 2.5, 2)
    for factor in (0, 1.5, True):
        with pytest.raises(ValueError, match=r"^lf: the factor must be a whole number, 1 or more"):
            lf.downsample(factor)
    with pytest.raises(ValueError, match=r"^lf: a factor of 10 leaves nothing of 11×9 views"):
        lf.downsample(10)


def test_a_downsampled_ground_truth_shrinks_its_disparities_and_flows_with_the_views():
    """δ (px per view step) and the flow (px) of views shrunk by k are 1/k of the full
    size's; valid only where the whole block is, occluded where any of it is."""
    from lfsf import evaluate

    disp = np.arange(16, dtype=np.float32).reshape(4, 4)
    valid = np.ones((4, 4), bool)
    valid[0, 1] = False
    occluded = np.zeros((4, 4), bool)
    occluded[3, 3] = True
    disp[2, 0] = np.nan
    small = evaluate.downsample_truth({"disp1": disp, "u": 2 * disp, "v": disp, "valid": valid,
                                       "occluded": occluded, "other": disp}, 2)
    assert sorted(small) == ["disp1", "occluded", "u", "v", "valid"]
    np.testing.assert_allclose(small["disp1"], [[(0 + 1 + 4 + 5) / 8, (2 + 3 + 6 + 7) / 8], [np.nan, (10 + 11 + 14 + 15) / 8]])
    np.testing.assert_allclose(small["u"], 2 * small["disp1"])
    np.testing.assert_array_equal(small["valid"], [[False, True], [True, True]])
    np.testing.assert_array_equal(small["occluded"], [[False, False], [False, True]])
    with pytest.raises(ValueError, match="the factor must be a whole number"):
        evaluate.downsample_truth({"disp1": disp}, 0)
    with pytest.raises(ValueError, match=r"^the ground truth: a factor of 5 leaves nothing of its 4×4 maps"):
        evaluate.downsample_truth({"disp1": disp}, 5)
    with pytest.raises(ValueError, match=r"maps must be 2-D and of one size"):
        evaluate.downsample_truth({"disp1": disp, "u": disp[:2]}, 2)
    np.testing.assert_allclose(lio.block_mean(np.arange(48.0).reshape(4, 4, 3), 2, axes=(-3, -2)),
                               lio.block_mean(np.arange(48.0).reshape(4, 4, 3), 2))


def test_a_single_image_is_told_apart_from_one_view_of_a_light_field(tmp_path):
    image = np.zeros((8, 8), np.uint8)
    for name in ("input_Cam040.png", "scene_05_05.png"):
        lio.write_png(tmp_path / name, image)
        with pytest.raises(ValueError, match=rf"^{re.escape(str(tmp_path / name))}: one view of a light field; give "
                                             rf"the folder of all its views, {re.escape(str(tmp_path))}$"):
            lio.read_lightfield(tmp_path / name)
    import imageio.v3 as iio

    iio.imwrite(tmp_path / "photo.jpg", np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(ValueError, match=r"photo.jpg: a single image, not a light field \(a folder of its views: the "
                                         r"HCI layout .*\), nor a raw lenslet image that lfsf decode reads"):
        lio.read_lightfield(tmp_path / "photo.jpg")
    lio.write_png(tmp_path / "raw.png", image)
    with pytest.raises(ValueError, match=r"raw.png: a single image is a raw lenslet image, which must be decoded "
                                         r"first: run `lfsf decode .*raw.png --white WHITE --out DIR` and read DIR "
                                         r"\(one view of a light field\? give the folder of all its views\)$"):
        lio.read_lightfield(tmp_path / "raw.png")


def test_a_small_hci_folder_without_its_grid_is_read_square_with_a_warning(tmp_path):
    """Nine HCI views may be a rig of one row: read as 3×3 (the documented rule), with a
    warning that says how to give the grid (a helper's 1×9 rig read as 3×3 gave δ1 errors
    60 times as large, with status 0). lfsf's own writer gives the grid in
    parameters.cfg, so its folders read back without one."""
    import warnings

    views = np.random.default_rng(0).random((3, 3, 12, 16)).astype(np.float32)
    lio.write_lightfield(views, tmp_path / "own")
    assert "num_cams_x = 3" in (tmp_path / "own" / "parameters.cfg").read_text()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert lio.read_lightfield(tmp_path / "own").grid == (3, 3)
    (tmp_path / "own" / "parameters.cfg").unlink()
    with pytest.warns(LfsfWarning, match=r"9 HCI views with no grid given .* read as a 3×3 grid; a rig of one row"):
        assert lio.read_lightfield(tmp_path / "own").grid == (3, 3)
    # a 1×9 rig with its grid given reads as one
    (tmp_path / "own" / "parameters.cfg").write_text("[extrinsics]\nnum_cams_x = 9\nnum_cams_y = 1\n")
    assert lio.read_lightfield(tmp_path / "own").grid == (1, 9)
    # a user's parameters.cfg is left as it is
    lio.write_lightfield(views, tmp_path / "own")
    assert "num_cams_x = 9" in (tmp_path / "own" / "parameters.cfg").read_text()


def test_hci_views_missing_at_the_end_are_named(tmp_path):
    """80 of 9×9 views: the message names input_Cam080.png (it had only asked for a grid
    that is not square)."""
    views = np.random.default_rng(0).random((9, 9, 8, 8)).astype(np.float32)
    lio.write_lightfield(views, tmp_path / "hci", bit_depth=8)
    (tmp_path / "hci" / "parameters.cfg").unlink()
    (tmp_path / "hci" / "input_Cam080.png").unlink()
    with pytest.raises(ValueError, match=r"got 80 .*; a 9×9 grid misses input_Cam080\.png; for a grid"):
        lio.read_lightfield(tmp_path / "hci")


def test_a_pair_check_blames_the_light_field_whose_axes_are_turned(tmp_path):
    """t1 stored [y, x, a, b], t2 right: the message is about t1's axes, not t2's size."""
    rng = np.random.default_rng(0)
    turned = lio.LightField(rng.random((48, 64, 9, 9)).astype(np.float32), source="t1.npz")
    right = lio.LightField(rng.random((9, 9, 48, 64)).astype(np.float32), source="t2.npz")
    for a, b in ((turned, right), (right, turned)):
        with pytest.raises(ValueError, match=r"^t1\.npz: 48×64 views of 9×9 pixels.*\[y, x, a, b\]"):
            lio.check_pair(a, b)


def test_channels_before_the_pixels_are_told_how_to_move(tmp_path):
    with pytest.raises(ValueError, match=r"got 96 in shape \(9, 9, 3, 72, 96\); are the channels before the "
                                         r"pixels, \[a, b, c, y, x\]\? np\.moveaxis\(views, 2, -1\)"):
        lio.LightField(np.zeros((9, 9, 3, 72, 96), np.float32))


@pytest.mark.parametrize("n, article", [(1, "a"), (8, "an"), (9, "a"), (11, "an"), (18, "an"), (80, "an"),
                                        (111, "a"), (800, "an")])
def test_the_article_before_a_number(n, article):
    assert lio._a(n) == article


def test_saving_with_a_ground_truth_file_of_another_size_names_the_file(tmp_path):
    """SceneFlow.save(…, gt=PATH) with a truth of another shape: the message names the
    file (as lfsf run --gt's does), and no folder is made."""
    from lfsf import Params
    from lfsf.estimate import SceneFlow

    zeros = np.zeros((12, 16), np.float32)
    sf = SceneFlow(zeros, zeros, zeros, zeros, Params.preset("fast"), 1.0, "cpu")
    np.savez(tmp_path / "gt.npz", disp1=np.zeros((24, 32), np.float32))
    with pytest.raises(ValueError, match=r"^" + re.escape(str(tmp_path / "gt.npz")) + r": expected gt\['disp1'\] of "
                                         r"shape \(12, 16\)"):
        sf.save(tmp_path / "out", zeros, zeros, gt=tmp_path / "gt.npz")
    assert not (tmp_path / "out").exists()


def test_a_view_is_asked_for_by_whole_numbers():
    lf = lio.LightField(np.zeros((3, 3, 8, 8), np.float32))
    assert lf.view(-1, 2).shape == (8, 8)
    for a in (True, 4.5, "a", np.bool_(False)):
        with pytest.raises(IndexError, match="a view's row and column are whole numbers"):
            lf.view(a, 0)


def test_a_result_changed_after_it_was_made_is_checked_before_it_is_saved(tmp_path):
    """save had written maps of two shapes, which load then refused."""
    from lfsf import Params
    from lfsf.estimate import SceneFlow

    zeros = np.zeros((12, 16), np.float32)
    sf = SceneFlow(zeros, zeros, zeros, zeros, Params.preset("fast"), 1.0, "cpu")
    sf.disp1 = np.zeros((3, 3))
    with pytest.raises(ValueError, match=r"disp2 is \(12, 16\), disp1 \(3, 3\): the maps must have one shape"):
        sf.save(tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_meta_must_be_a_dict_and_a_grid_must_have_views():
    from lfsf import Params

    with pytest.raises(ValueError, match="meta must be a dict .*got list"):
        lio.LightField(np.zeros((3, 3, 8, 8), np.float32), meta=[1])
    for grid in (0, (0, 3), (3, -1)):
        with pytest.raises(ValueError, match="a grid of views has at least one row and one column"):
            Params.preset("fast").sample_offsets(grid)


@pytest.mark.parametrize("name", ["01_01.png", "cam-01-01.png"])
def test_views_named_by_row_and_column_another_way_are_told_the_rule(tmp_path, name):
    """01_01.png or cam-01-01.png had got the generic "found no light-field views"."""
    lio.write_png(tmp_path / name, np.zeros((8, 8), np.uint8))
    with pytest.raises(ValueError, match=re.escape(f"; {name} is not named <name>_RR_CC.png: rename the views so")):
        lio.read_lightfield(tmp_path)


def test_library_inputs_of_the_wrong_shape_or_range_get_a_value_error_naming_them():
    """A helper's library testing: these had ended in matmul's core-dimension message,
    Warp's launch error, zlib.error or an empty array; whole numbers given as floats
    (2.0) were refused as "not a whole number" by some functions and taken by others
    (Params, render_scene)."""
    from lfsf import decode, evaluate, viz

    with pytest.raises(ValueError, match=re.escape("luma: expected RGB values (…, 3), got shape (2, 2, 4)")):
        lio.luma(np.zeros((2, 2, 4)))
    with pytest.raises(ValueError, match=re.escape("<white>: expected a white image of shape (H, W) or (H, W, 3), "
                                                   "got (10, 10, 4)")):
        decode.calibrate(np.zeros((10, 10, 4)))
    with pytest.raises(ValueError, match=re.escape("demosaic: expected a 2-D mosaic (H, W), got shape (4, 4, 3)")):
        decode.demosaic(np.zeros((4, 4, 3)), "RGGB", device="cpu")
    with pytest.raises(ValueError, match="compress_level must be a whole number −1…9, got 10"):
        lio.encode_png(np.zeros((2, 2), np.uint8), compress_level=10)
    with pytest.raises(ValueError, match=re.escape("block_mean: a factor of 5 leaves nothing of axes of 4×4")):
        lio.block_mean(np.zeros((4, 4)), 5)
    lf = lio.LightField(np.arange(3 * 3 * 8 * 8, dtype=np.float32).reshape(3, 3, 8, 8))
    assert np.array_equal(lf.crop(1.0, 2, 3, 4.0).views, lf.crop(1, 2, 3, 4).views)
    assert np.array_equal(lf.downsample(2.0).views, lf.downsample(2).views)
    assert evaluate.check_border(3.0) == 3 and viz.flow_wheel_legend(4.0).shape == (4, 4, 3)
    for bad in (2.5, True, "2", float("nan")):
        with pytest.raises(ValueError, match="whole number"):
            lf.downsample(bad)

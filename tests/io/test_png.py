"""The fast grey-PNG decoder against libpng (cv2) and a hand-written encoder."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from dropvision.io.readers.png import PngError, decode_grey_png


def _chunk(ctype: bytes, payload: bytes) -> bytes:
    return struct.pack(">I", len(payload)) + ctype + payload + struct.pack(">I", zlib.crc32(ctype + payload))


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def encode_png(img: np.ndarray, filters, *, interlace: int = 0, extra: bytes = b"") -> bytes:
    """A PNG of a grey image with the given filter type per row (independent reference encoder)."""
    bpp = img.dtype.itemsize
    data = img.astype(">u2").tobytes() if bpp == 2 else img.tobytes()
    h, w = img.shape
    raw = np.frombuffer(data, np.uint8).reshape(h, w * bpp).astype(np.int64)
    out = []
    prev = np.zeros(w * bpp, np.int64)
    for y in range(h):
        x = raw[y]
        left = np.r_[np.zeros(bpp, np.int64), x[:-bpp]]
        upleft = np.r_[np.zeros(bpp, np.int64), prev[:-bpp]]
        f = int(filters[y % len(filters)])
        pred = {0: 0, 1: left, 2: prev, 3: (left + prev) // 2, 4: _paeth(left, prev, upleft)}[f]
        out.append(bytes([f]) + ((x - pred) % 256).astype(np.uint8).tobytes())
        prev = x
    ihdr = struct.pack(">IIBBBBB", w, h, 8 * bpp, 0, 0, 0, interlace)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + extra
            + _chunk(b"IDAT", zlib.compress(b"".join(out), 6)) + _chunk(b"IEND", b""))


def _libpng(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


@pytest.fixture(scope="module")
def images():
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:37, 0:53]
    smooth = 120 + 100 * np.sin(xx / 7.0) * np.cos(yy / 5.0)
    img8 = np.clip(smooth + rng.normal(0, 20, smooth.shape), 0, 255).astype(np.uint8)
    img16 = np.clip(smooth * 250 + rng.normal(0, 3000, smooth.shape), 0, 65535).astype(np.uint16)
    return {8: img8, 16: img16}


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("filters", [[0], [1], [2], [0, 1, 2], [2, 2, 2, 1, 0, 2, 2], [1, 1, 2, 0]])
def test_none_sub_up_rows_decode_exactly(images, bits, filters):
    img = images[bits]
    data = encode_png(img, filters)
    out = decode_grey_png(data)
    assert out is not None and out.dtype == img.dtype and out.shape == img.shape
    np.testing.assert_array_equal(out, img)
    np.testing.assert_array_equal(out, _libpng(data))


@pytest.mark.parametrize("bits", [8, 16])
def test_cv2_written_png_matches_libpng(images, bits, tmp_path):
    img = images[bits]
    ok, buf = cv2.imencode(".png", img)
    assert ok
    np.testing.assert_array_equal(decode_grey_png(buf.tobytes()), img)


FILTER_MIXES = [[3], [4], [1, 4, 2], [4, 4, 2, 2, 3, 0, 1], [2, 3], [3, 2, 2, 4, 4, 4, 1],
                [0, 1, 2, 3, 4], [2, 2, 2, 2, 2, 2, 4], [4, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 2]]


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("filters", FILTER_MIXES)
def test_average_and_paeth_rows_decode_exactly(images, bits, filters):
    img = images[bits]
    data = encode_png(img, filters)
    out = decode_grey_png(data)
    assert out is not None and out.dtype == img.dtype and out.shape == img.shape
    np.testing.assert_array_equal(out, img)
    np.testing.assert_array_equal(out, _libpng(data))


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("seed", range(6))
def test_random_filter_per_row_decodes_exactly(bits, seed):
    """Every row a random filter (many short Average/Paeth runs, past the one-libpng-call
    limit too), odd sizes down to one row or one column, extreme values (wrap-around)."""
    rng = np.random.default_rng(seed)
    h, w = [(37, 53), (1, 9), (9, 1), (64, 3), (200, 17), (2, 2)][seed]
    hi = 255 if bits == 8 else 65535
    img = rng.integers(0, hi + 1, (h, w)).astype(np.uint8 if bits == 8 else np.uint16)
    extreme = rng.random((h, w)) < 0.4
    img[extreme] = rng.choice(np.array([0, 1, hi - 1, hi]), int(extreme.sum()))
    filters = rng.integers(0, 5, h)
    data = encode_png(img, filters)
    out = decode_grey_png(data)
    np.testing.assert_array_equal(out, img)
    np.testing.assert_array_equal(out, _libpng(data))


@pytest.mark.parametrize("bits", [8, 16])
def test_many_average_paeth_runs_take_one_libpng_call(images, bits, monkeypatch):
    from dropvision.io.readers import png

    calls = []
    real = png._libpng_unfilter
    monkeypatch.setattr(png, "_libpng_unfilter", lambda *a: calls.append(a[1].shape[0]) or real(*a))
    img = images[bits]
    data = encode_png(img, [1, 4, 2])  # 12 Paeth runs in 37 rows
    monkeypatch.setattr(png, "_MAX_LIBPNG_RUNS", 4)
    np.testing.assert_array_equal(decode_grey_png(data), img)
    assert calls == [37 - 1]  # from the first Paeth row (row 1) to the end
    calls.clear()
    monkeypatch.setattr(png, "_MAX_LIBPNG_RUNS", 24)
    np.testing.assert_array_equal(decode_grey_png(data), img)
    assert calls == [1] * 12


def test_other_png_kinds_are_left_to_libpng(images):
    img = images[8]
    assert decode_grey_png(encode_png(img, [1], interlace=1)) is None
    assert decode_grey_png(encode_png(img, [1], extra=_chunk(b"tRNS", b"\x00\x07"))) is None
    ok, rgb = cv2.imencode(".png", np.dstack([img, img, img]))
    assert decode_grey_png(rgb.tobytes()) is None
    ok, bmp = cv2.imencode(".bmp", img)
    assert decode_grey_png(bmp.tobytes()) is None  # not a PNG at all


def test_ancillary_chunks_and_split_idat(images):
    img = images[16]
    data = encode_png(img, [1, 2])
    # split the IDAT into three chunks and add an sBIT and a text chunk
    sig, rest = data[:8], data[8:]
    ihdr = rest[:25]
    (length,) = struct.unpack(">I", rest[25:29])
    z = rest[33:33 + length]
    parts = [z[:10], z[10:len(z) // 2], z[len(z) // 2:]]
    rebuilt = (sig + ihdr + _chunk(b"sBIT", b"\x0c") + b"".join(_chunk(b"IDAT", p) for p in parts)
               + _chunk(b"tEXt", b"Comment\x00x") + _chunk(b"IEND", b""))
    np.testing.assert_array_equal(decode_grey_png(rebuilt), img)
    np.testing.assert_array_equal(_libpng(rebuilt), img)


def test_broken_files_raise(images):
    data = encode_png(images[8], [1])
    with pytest.raises(PngError, match="truncated"):
        decode_grey_png(data[: len(data) // 2])
    bad_crc = bytearray(data)
    bad_crc[45] ^= 0xFF  # inside the IDAT payload
    with pytest.raises(PngError, match="CRC"):
        decode_grey_png(bytes(bad_crc))
    # a valid chunk structure around a broken zlib stream
    ihdr = struct.pack(">IIBBBBB", 53, 37, 8, 0, 0, 0, 0)
    broken = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", b"\x78\x9c garbage")
              + _chunk(b"IEND", b""))
    with pytest.raises(PngError, match="corrupt"):
        decode_grey_png(broken)
    short = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(b"\x01" * 100))
             + _chunk(b"IEND", b""))
    with pytest.raises(PngError, match="bytes"):
        decode_grey_png(short)
    long = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(b"\x00" * 10**6))
            + _chunk(b"IEND", b""))
    with pytest.raises(PngError, match="more image data"):  # inflates no more than the header's size
        decode_grey_png(long)
    nocheck = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr)
               + _chunk(b"IDAT", zlib.compress(b"\x00" * 37 * 54)[:-4]) + _chunk(b"IEND", b""))
    with pytest.raises(PngError, match="checksum"):
        decode_grey_png(nocheck)
    rows = np.zeros((37, 54), np.uint8)
    rows[5, 0] = 9
    badf = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(rows.tobytes()))
            + _chunk(b"IEND", b""))
    with pytest.raises(PngError, match="filter type 9 in row 5"):
        decode_grey_png(badf)


def test_trailing_chunks_cut_after_the_image_data_still_decode(images):
    data = encode_png(images[8], [1])
    np.testing.assert_array_equal(decode_grey_png(data[:-6]), images[8])


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("noise", [0.0, 3.0])
def test_pil_written_png_decodes_exactly(images, bits, noise, tmp_path):
    """Pillow's adaptive filtering (Sub, Up, Average and Paeth rows mixed), through read_png."""
    pil = pytest.importorskip("PIL.Image")
    from dropvision.io.readers.png import read_png

    img = images[bits]
    big = np.tile(img, (6, 6)).astype(float)
    big += np.random.default_rng(3).normal(0, noise * (1 if bits == 8 else 256), big.shape)
    big = np.clip(big, 0, 255 if bits == 8 else 65535).astype(img.dtype)
    path = tmp_path / "pil.png"
    pil.fromarray(big).save(path, format="PNG")
    out = decode_grey_png(path.read_bytes())
    assert out is not None
    np.testing.assert_array_equal(out, big)
    np.testing.assert_array_equal(read_png(path), _libpng(path.read_bytes()))

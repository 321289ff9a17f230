"""PNG reader, with a fast decoder for grey PNG strobe frames.

Decoding a 640 x 1024 8-bit PNG with libpng (OpenCV, imageio, imagecodecs' libpng and spng
alike) costs about 4.5-5.8 ms here, several times what measuring the frame costs. Nearly all of
it is zlib's inflate and the per-row unfiltering. :func:`decode_grey_png` decodes the PNGs drop
watchers, Pillow and `dropvision synth` write (grey, 8 or 16 bits, not interlaced, any of the
five row filters) with Intel ISA-L's inflate (``isal``) and vectorised unfiltering: about 1.5 ms
for an OpenCV-written frame (every row Sub) and 2.1 ms for a Pillow-written one (adaptive
filtering: Sub, Up and a few Paeth rows), bit-identical to libpng.

How the filters are undone (see :func:`_unfilter`): None and Sub rows all at once
(``imagecodecs.delta_decode`` along the rows); Up rows all at once as one running sum down the
image less its value above each run of Up rows; Average and Paeth rows, which depend on the
left pixel of their own row too, run by run by libpng itself: the run and the decoded row above
it are wrapped in a small stored (uncompressed) PNG and decoded with ``cv2.imdecode`` (about
12 us for one row; no second inflate, exact by construction). A numba kernel was measured as
the alternative: importing numba alone costs ~0.18 s of every command's start-up, more than it
would save on a 181-frame sequence.

Resources are bounded before decoding: the IHDR size against
:data:`dropvision.io.readers.base.MAX_PIXELS`, the file size against
:data:`~dropvision.io.readers.base.MAX_FILE_BYTES` (checked before the file is read), the number
of chunks against :data:`MAX_CHUNKS`.

Every other PNG (colour, palette, 1/2/4-bit, interlaced, a ``tRNS`` chunk) is left to libpng:
:func:`decode_grey_png` returns None and :func:`read_png` decodes it with OpenCV. Broken files
raise :class:`PngError`.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
from imagecodecs import delta_decode
from isal import isal_zlib

import dropvision.io.readers.base as base
from dropvision.io.readers.base import Reader, UnreadableImage, check_pixels, imdecode, read_file

__all__ = ["PngReader", "PngError", "decode_grey_png", "read_png", "png_significant_bits",
           "PNG_SIGNATURE"]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_CRITICAL = (b"IHDR", b"IDAT", b"IEND", b"PLTE")
_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"
#: Most chunks walked in one file (a file of millions of empty chunks is refused, not walked
#: for minutes; libpng writes one IDAT chunk per 8 KiB, so a 2 GiB image needs ~260 000).
MAX_CHUNKS = 1_000_000


class PngError(ValueError):
    """A PNG file that is truncated or corrupt (the message says how)."""


def decode_grey_png(data) -> np.ndarray | None:
    """Decode a grey PNG, or return None when it is a kind this fast path does not handle.

    Parameters
    ----------
    data : bytes-like
        The whole PNG file.

    Returns
    -------
    image : ndarray of uint8 or uint16, shape (height, width), or None
        Native byte order, as ``cv2.imread(..., cv2.IMREAD_UNCHANGED)`` returns it. None for
        data that is not a PNG or a PNG that is not a non-interlaced 8/16-bit grey image
        (decode those with libpng).

    Raises
    ------
    PngError
        Truncated data, a bad chunk CRC in a critical chunk, a broken zlib stream, image data of
        the wrong length, an invalid filter type, a header claiming more than
        :data:`~dropvision.io.readers.base.MAX_PIXELS` pixels, more than :data:`MAX_CHUNKS` chunks.
    """
    mv = memoryview(data)
    if len(mv) < 8 or bytes(mv[:8]) != PNG_SIGNATURE:
        return None
    pos = 8
    header = None
    idat: list = []
    idat_done = False
    n = len(mv)
    n_chunks = 0
    while pos < n:
        n_chunks += 1
        if n_chunks > MAX_CHUNKS:
            raise PngError(f"more than {MAX_CHUNKS} chunks (corrupt file)")
        # a cut chunk is fatal unless every IDAT chunk before it is complete (the zlib
        # stream then tells whether the image data is whole)
        if pos + 12 > n:
            if not idat:
                raise PngError("truncated file (ends inside a chunk header)")
            break
        length, ctype = struct.unpack_from(">I4s", mv, pos)
        end = pos + 12 + length
        if end > n:
            if not idat or ctype == b"IDAT":
                raise PngError(f"truncated file (chunk {ctype.decode('latin-1')!r} is cut short)")
            break
        if ctype in _CRITICAL:
            (crc,) = struct.unpack_from(">I", mv, pos + 8 + length)
            if isal_zlib.crc32(mv[pos + 4:pos + 8 + length]) != crc:
                raise PngError(f"CRC error in chunk {ctype.decode('latin-1')!r}")
        if ctype == b"IHDR":
            if length != 13:
                raise PngError("malformed IHDR chunk")
            header = struct.unpack_from(">IIBBBBB", mv, pos + 8)
            if header[0] * header[1] > base.MAX_PIXELS:
                try:
                    check_pixels(header[0], header[1], "PNG")
                except UnreadableImage as exc:
                    raise PngError(str(exc)) from None
        elif ctype == b"IDAT":
            if idat_done:
                raise PngError("IDAT chunks are not consecutive")
            idat.append(mv[pos + 8:pos + 8 + length])
        else:
            if idat:
                idat_done = True
            if ctype == b"tRNS":
                return None
            if ctype == b"IEND":
                break
        pos = end
    if header is None:
        raise PngError("no IHDR chunk")
    width, height, bit_depth, colour_type, compression, filter_method, interlace = header
    if colour_type != 0 or bit_depth not in (8, 16) or interlace != 0:
        return None
    if compression != 0 or filter_method != 0 or width == 0 or height == 0:
        raise PngError("invalid IHDR (compression or filter method, or an empty image)")
    if not idat:
        raise PngError("no image data (IDAT)")
    bpp = bit_depth // 8
    stride = width * bpp
    expected = height * (stride + 1)
    inflater = isal_zlib.decompressobj()
    try:  # never inflate more than the header's size (a corrupt size or a zip bomb)
        raw = inflater.decompress(b"".join(idat), expected)
    except isal_zlib.error as exc:  # corrupt stream or checksum
        raise PngError(f"corrupt image data ({exc})") from None
    if inflater.unconsumed_tail:
        raise PngError(f"more image data than the {expected} bytes a {width}x{height} "
                       f"{bit_depth}-bit image needs (corrupt header or data)")
    if len(raw) < expected:
        raise PngError(f"image data holds {len(raw)} of the {expected} bytes a {width}x{height} "
                       f"{bit_depth}-bit image needs (truncated or corrupt)")
    if not inflater.eof:
        raise PngError("image data stream is cut short before its checksum (truncated)")
    rows = np.frombuffer(raw, np.uint8).reshape(height, stride + 1)
    out = _unfilter(rows, bpp)
    if bpp == 2:
        return out.view(">u2").astype(np.uint16)
    return out


def _unfilter(rows: np.ndarray, bpp: int) -> np.ndarray:
    """Undo the PNG row filters of ``rows`` (filter byte + filtered bytes per row).

    None and Sub rows depend on no other row and are undone for all of them at once. Up rows
    are a running sum down each run of Up rows, seeded by the row above the run: one running
    sum down the whole image, less its value at the row above each run (modulo 256), undoes
    them all at once too. Average and Paeth rows also depend on the left pixel of the same row,
    so they are undone run by run, by libpng itself (:func:`_libpng_unfilter`), and the Up rows
    between them block by block.
    """
    ftype = rows[:, 0]
    body = rows[:, 1:]
    height, stride = body.shape
    kinds = np.bincount(ftype, minlength=5)
    if kinds.size > 5:
        bad = int(np.flatnonzero(ftype > 4)[0])
        raise PngError(f"invalid filter type {int(ftype[bad])} in row {bad}")

    def sub(block: np.ndarray) -> np.ndarray:  # running sum along the row, bpp bytes apart
        if bpp == 1:
            return delta_decode(block, axis=-1)
        shaped = np.ascontiguousarray(block).reshape(block.shape[0], stride // bpp, bpp)
        return delta_decode(shaped, axis=1).reshape(block.shape)

    if kinds[1] == height:  # the common case (OpenCV writes every row with Sub)
        return sub(body)
    out = body.copy()  # None rows done; Up rows hold their filtered bytes
    if kinds[1]:
        out[ftype == 1] = sub(body[ftype == 1])
    if not (kinds[3] or kinds[4]):
        if kinds[2]:
            _undo_up(out, ftype, 0, height)
        return out
    slow = np.flatnonzero(ftype >= 3)  # Average / Paeth rows, in runs of consecutive rows
    breaks = np.flatnonzero(np.diff(slow) > 1)
    starts = slow[np.r_[0, breaks + 1]].tolist()
    stops = (slow[np.r_[breaks, slow.size - 1]] + 1).tolist()
    if len(starts) > _MAX_LIBPNG_RUNS:  # many short runs: one libpng call from the first on
        starts, stops = starts[:1], [height]
    pos = 0
    zero = np.zeros((1, stride), np.uint8)
    for s, e in zip(starts, stops):
        if kinds[2]:
            _undo_up(out, ftype, pos, s)
        out[s:e] = _libpng_unfilter(out[s - 1:s] if s > 0 else zero, rows[s:e], bpp)
        pos = e
    if kinds[2]:
        _undo_up(out, ftype, pos, height)
    return out


#: More runs of Average/Paeth rows than this in one image and libpng unfilters every row from
#: the first such run on in one call (each call costs some 20-40 us).
_MAX_LIBPNG_RUNS = 24


def _undo_up(out: np.ndarray, ftype: np.ndarray, a: int, b: int) -> None:
    """Undo the Up rows among rows ``a:b`` of ``out`` in place (no Average/Paeth rows there;
    the other rows, and the row above ``a``, already decoded; Up rows hold their filtered
    bytes). Row i of a run of Up rows starting below row s is ``C[i] - C[s]`` (mod 256), with C
    the running sum down rows ``a - 1 .. b`` (the row above ``a``, or zeros, first)."""
    if b <= a:
        return
    up = ftype[a:b] == 2
    if not up.any():
        return
    n, stride = b - a, out.shape[1]
    ext = np.empty((n + 2, stride), np.uint8)  # a zero row, the row above a, rows a:b
    ext[0] = 0
    ext[1] = out[a - 1] if a > 0 else 0
    ext[2:] = out[a:b]
    # the running sum down the rows, along rows of the transpose (3x faster than along axis 0)
    ext_t = cv2.transpose(ext)
    csum = cv2.transpose(delta_decode(ext_t, axis=-1, out=ext_t))
    idx = np.arange(n + 2)
    is_start = np.r_[True, True, ~up]
    start = np.maximum.accumulate(np.where(is_start, idx, 0))
    ri = np.flatnonzero(up) + 2
    out[a + ri - 2] = csum[ri] - csum[start[ri] - 1]


def _libpng_unfilter(seed: np.ndarray, rows: np.ndarray, bpp: int) -> np.ndarray:
    """Undo the filters of ``rows`` (filter byte + bytes, any filter types) below the decoded
    row ``seed`` with libpng: a small PNG of the seed row (filter None) and these rows in a
    stored (uncompressed) zlib stream, decoded by ``cv2.imdecode``. Exact by construction
    (libpng's own Average and Paeth code) and, with no inflate to do, about as fast as the
    unfiltering itself; only the rows that need it are passed, never the whole image."""
    n, stride1 = rows.shape
    stride = stride1 - 1
    raw = np.empty((n + 1, stride1), np.uint8)
    raw[0, 0] = 0
    raw[0, 1:] = seed
    raw[1:] = rows
    ihdr = b"IHDR" + struct.pack(">IIBBBBB", stride // bpp, n + 1, 8 * bpp, 0, 0, 0, 0)
    idat = b"IDAT" + zlib.compress(raw.data, 0)
    png = b"".join((PNG_SIGNATURE, struct.pack(">I", 13), ihdr, struct.pack(">I", isal_zlib.crc32(ihdr)),
                    struct.pack(">I", len(idat) - 4), idat, struct.pack(">I", isal_zlib.crc32(idat)),
                    _IEND))
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.shape != (n + 1, stride // bpp):  # never: the PNG is made right here
        raise PngError("libpng could not unfilter Average/Paeth rows")
    if bpp == 2:
        img = img.astype(">u2").view(np.uint8)
    return img[1:].reshape(n, stride)


def read_png(path: Path) -> np.ndarray:
    """Decode a PNG file: grey PNGs with :func:`decode_grey_png`, any other with libpng (cv2).

    Returns the array as ``cv2.imread(..., cv2.IMREAD_UNCHANGED)`` does (colour in BGR(A)
    order). Raises :class:`~dropvision.io.readers.base.UnreadableImage` for a file that cannot be
    read or decoded.
    """
    data = read_file(path, "PNG")
    _check_ihdr(data)
    try:
        img = decode_grey_png(data)
    except PngError as exc:
        raise UnreadableImage(f"cannot decode PNG ({exc})") from None
    if img is None:
        img = imdecode(data, "PNG")
    return img


def _check_ihdr(data: bytes) -> None:
    """Refuse a PNG whose IHDR (the first chunk) claims an empty image or more than
    :data:`~dropvision.io.readers.base.MAX_PIXELS` pixels, before any decoder allocates it."""
    if len(data) >= 24 and data[12:16] == b"IHDR" and data[:8] == PNG_SIGNATURE:
        width, height = struct.unpack_from(">II", data, 16)
        if width * height > base.MAX_PIXELS or width == 0 or height == 0:
            check_pixels(width, height, "PNG")


def png_significant_bits(path: Path) -> int | None:
    """Grey significant bits from a PNG ``sBIT`` chunk (None without one, or unreadable)."""
    try:
        with open(path, "rb") as fh:
            if fh.read(8) != PNG_SIGNATURE:
                return None
            for _ in range(64):
                head = fh.read(8)
                if len(head) < 8:
                    return None
                length, ctype = struct.unpack(">I4s", head)
                if ctype == b"sBIT":
                    data = fh.read(length)
                    return max(data) if data else None
                if ctype in (b"IDAT", b"IEND"):
                    return None
                fh.seek(length + 4, os.SEEK_CUR)
    except OSError:
        return None
    return None


class PngReader(Reader):
    """PNG files: one frame each; ``sBIT`` gives the significant bits of 16-bit frames."""

    suffixes = (".png",)
    bgr = True

    def decode(self, path: Path, page: int | None) -> np.ndarray:
        """Decode the PNG with :func:`read_png` (``page`` is ignored)."""
        return read_png(path)

    def significant_bits(self, path: Path, page: int | None) -> int | None:
        """Grey significant bits from the ``sBIT`` chunk (:func:`png_significant_bits`)."""
        return png_significant_bits(path)

    def header_size(self, path: Path, page: int | None) -> tuple[int, int] | None:
        """(width, height) from the IHDR chunk (the first 24 bytes), None when it cannot be read."""
        try:
            with open(path, "rb") as fh:
                data = fh.read(24)
        except OSError:
            return None
        if len(data) < 24 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
            return None
        width, height = struct.unpack_from(">II", data, 16)
        return int(width), int(height)

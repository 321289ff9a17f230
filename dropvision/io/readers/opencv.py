"""Generic OpenCV reader: formats decoded with ``cv2.imread`` (BMP; PGM/PPM/PBM/PNM, 8- and
16-bit).

Before decoding, the file size is checked against
:data:`dropvision.io.readers.base.MAX_FILE_BYTES` and the header's width x height (BMP DIB
header, PNM text header) against :data:`~dropvision.io.readers.base.MAX_PIXELS`.
"""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np

from dropvision.io.readers.base import Reader, UnreadableImage, check_pixels, imdecode, read_file

__all__ = ["OpenCVReader"]


def _check_bmp_header(head: bytes) -> None:
    """Refuse a BMP whose header claims an empty image or more than MAX_PIXELS pixels."""
    if len(head) < 26 or head[:2] != b"BM":
        return  # not a BMP header: left to OpenCV (which then reports it undecodable)
    (dib_size,) = struct.unpack_from("<I", head, 14)
    if dib_size == 12:  # BITMAPCOREHEADER: 16-bit unsigned width and height
        width, height = struct.unpack_from("<HH", head, 18)
    else:  # BITMAPINFOHEADER and later: 32-bit signed (negative height: top-down rows)
        width, height = struct.unpack_from("<ii", head, 18)
    check_pixels(abs(width), abs(height), "BMP")


def _check_pnm_header(head: bytes) -> None:
    """Refuse a PNM (P1..P6) whose text header claims an empty image or more than MAX_PIXELS
    pixels."""
    if len(head) < 2 or head[:1] != b"P" or head[1:2] not in b"123456":
        return  # left to OpenCV
    tokens, i, n = [], 2, len(head)
    while len(tokens) < 2 and i < n:
        c = head[i:i + 1]
        if c == b"#":  # comment to the end of the line
            while i < n and head[i:i + 1] not in (b"\n", b"\r"):
                i += 1
        elif c.isspace():
            i += 1
        else:
            j = i
            while j < n and head[j:j + 1].isdigit():
                j += 1
            if j == i:
                return  # malformed: left to OpenCV
            tokens.append(int(head[i:j]))
            i = j
    if len(tokens) == 2:
        check_pixels(tokens[0], tokens[1], "PNM")


class OpenCVReader(Reader):
    """Single-image files decoded by OpenCV (``cv2.IMREAD_UNCHANGED``; colour in BGR order)."""

    suffixes = (".bmp", ".pgm", ".ppm", ".pbm", ".pnm")
    bgr = True

    def decode(self, path: Path, page: int | None) -> np.ndarray:
        """Decode the file with ``cv2.imread`` (from its bytes when cv2 cannot open the path,
        e.g. a non-ASCII name on Windows); ``page`` is ignored."""
        kind = Path(path).suffix.lstrip(".").upper() or "image"
        head = read_file(path, kind, limit=26 if kind == "BMP" else 4096)
        if kind == "BMP":
            _check_bmp_header(head)
        else:
            _check_pnm_header(head)
        try:
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        except (cv2.error, MemoryError):
            img = None  # imdecode below says why
        if img is None:  # e.g. a path cv2 cannot open: decode from bytes
            try:
                data = np.fromfile(path, dtype=np.uint8)
            except OSError as exc:
                raise UnreadableImage(f"cannot read file ({exc.strerror})") from None
            img = imdecode(data, kind)
        return img

"""JPEG reader (``.jpg``, ``.jpeg``, ``.jpe``, ``.jfif``): 8-bit grey and colour, decoded by
libjpeg-turbo: 8-bit grey and 3-component colour files by imagecodecs (``jpeg8_decode``; a
colour file straight to its luma plane, JFIF's Y = the BT.601 grey rule, returned as a
`ColourLuma`), any other kind (CMYK, 12-bit) by OpenCV's bundled libjpeg-turbo
(``cv2.imdecode``).

Why imagecodecs: measured with ``tools/bench_decoders.py`` (one thread, full resolution, the six
real 2048x1536 colour drop-watcher JPEGs of the development set, ``../shared/realdata/watcher-dod``), decoding to
grey takes 3.95 ms with imagecodecs (libjpeg-turbo 3.1) against 4.1 ms with ``cv2.imdecode``
(interleaved medians; the two are within a few per cent, both libjpeg-turbo) and gives the
same array, bit for bit (tests/io/test_readers_formats.py); imagecodecs is already a dependency
and reports a broken file as an error where OpenCV only warns.

Before decoding, the file size is checked against
:data:`dropvision.io.readers.base.MAX_FILE_BYTES` and the frame header's (SOFn) width x height
against :data:`~dropvision.io.readers.base.MAX_PIXELS`. EXIF orientation is ignored (the
``orientation`` of sequence.json says how the frames are turned); colour is returned in BGR
order and made grey by the sequence layer (ITU-R BT.601 luminance, docs/FORMAT.md).
"""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import imagecodecs
import numpy as np

from dropvision.io.readers.base import ColourLuma, Reader, UnreadableImage, check_pixels, imdecode, read_file

__all__ = ["JpegReader", "jpeg_size"]

#: Start-of-frame markers (baseline, extended, progressive, lossless, arithmetic); not DHT
#: (C4), JPG (C8) or DAC (CC).
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: Markers without a length field.
_STANDALONE = frozenset(range(0xD0, 0xDA)) | {0x01}


def jpeg_size(data: bytes) -> tuple[int, int, int] | None:
    """(width, height, components) from the first SOFn segment of JPEG bytes; None when the
    bytes are not a JPEG or no frame header is found (left to the decoder to report)."""
    found = _walk(data)
    return None if found is None else found[:3]


def _walk(data: bytes) -> tuple[int, int, int, int, int] | None:
    """(width, height, components, position of the first SOS after the frame header, sample
    precision in bits)."""
    if len(data) < 4 or data[:2] != b"\xff\xd8":
        return None
    frame = None
    pos, n = 2, len(data)
    while pos + 4 <= n:
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in _STANDALONE:
            pos += 2
            continue
        if marker == 0xDA and frame is not None:  # start of scan
            return (*frame[:3], pos, frame[3])
        if marker in (0xD9, 0xDA):  # end of image / a scan before any frame header
            return None
        (length,) = struct.unpack_from(">H", data, pos + 2)
        if marker in _SOF and frame is None:
            if pos + 10 > n:
                return None
            height, width = struct.unpack_from(">HH", data, pos + 5)
            frame = (width, height, data[pos + 9], data[pos + 4])
        pos += 2 + length
    return None


class JpegReader(Reader):
    """JPEG files, one frame each (8-bit grey; colour files decoded to their luma Y)."""

    suffixes = (".jpg", ".jpeg", ".jpe", ".jfif")
    bgr = True

    def decode(self, path: Path, page: int | None) -> np.ndarray:
        """Decode with imagecodecs (8-bit grey or 3-component colour) or ``cv2.imdecode``
        (other kinds); ``page`` is ignored; colour files to their luma."""
        data = read_file(path, "JPEG")
        found = _walk(data)
        if found is not None and found[1] > 0:  # height 0: a DNL marker, left to the decoder
            check_pixels(found[0], found[1], "JPEG")
        # libjpeg-turbo fills the missing rows of a cut file with grey and only warns: a file
        # without an end-of-image marker after its first scan is refused here
        if found is not None and data.rfind(b"\xff\xd9") < found[3]:
            raise UnreadableImage("cannot decode JPEG (truncated file: no end-of-image marker)")
        # a colour JPEG is decoded straight to its luma: JFIF's Y is the BT.601 luminance of the
        # grey rule (docs/FORMAT.md), without the chroma upsampling and colour conversion
        # (2048 x 1536: 6.8 instead of 15.6 ms)
        # (imagecodecs never applies the EXIF orientation; any flag but IMREAD_UNCHANGED makes
        # OpenCV apply it: ignored, as documented)
        if found is not None and found[4] == 8 and found[2] in (1, 3):
            try:
                img = imagecodecs.jpeg8_decode(data, outcolorspace="GRAY" if found[2] == 3 else None)
            except (imagecodecs.Jpeg8Error, MemoryError, ValueError) as exc:
                raise UnreadableImage(f"cannot decode JPEG ({exc}; truncated or corrupt file)") from None
            if img.ndim != 2:  # never for these kinds; guards the ColourLuma contract
                raise UnreadableImage(f"cannot decode JPEG (decoded to shape {img.shape})")
            return img.view(ColourLuma) if found[2] == 3 else img
        if found is not None and found[2] >= 3:
            return imdecode(data, "JPEG", cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION).view(ColourLuma)
        return imdecode(data, "JPEG")

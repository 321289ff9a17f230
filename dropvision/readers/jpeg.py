"""JPEG reader (``.jpg``, ``.jpeg``, ``.jpe``, ``.jfif``): 8-bit grey and colour, decoded by
OpenCV's bundled libjpeg-turbo (``cv2.imdecode``; a colour file straight to its luma plane,
JFIF's Y = the BT.601 grey rule, returned as a `ColourLuma`).

Why OpenCV: measured with ``tools/bench_decoders.py`` (one thread, full resolution),
``cv2.imdecode`` decodes as fast as simplejpeg and PyTurboJPEG (all three are libjpeg-turbo;
the differences are within the run-to-run noise) and needs no new dependency; PyTurboJPEG also
needs a system libturbojpeg, which pip cannot install.

Before decoding, the file size is checked against
:data:`dropvision.readers.base.MAX_FILE_BYTES` and the frame header's (SOFn) width x height
against :data:`~dropvision.readers.base.MAX_PIXELS`. EXIF orientation is ignored (the
``orientation`` of sequence.json says how the frames are turned); colour is returned in BGR
order and made grey by the sequence layer (ITU-R BT.601 luminance, docs/FORMAT.md).
"""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np

from dropvision.readers.base import ColourLuma, Reader, UnreadableImage, check_pixels, imdecode, read_file

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


def _walk(data: bytes) -> tuple[int, int, int, int] | None:
    """(width, height, components, position of the first SOS after the frame header)."""
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
            return (*frame, pos)
        if marker in (0xD9, 0xDA):  # end of image / a scan before any frame header
            return None
        (length,) = struct.unpack_from(">H", data, pos + 2)
        if marker in _SOF and frame is None:
            if pos + 10 > n:
                return None
            height, width = struct.unpack_from(">HH", data, pos + 5)
            frame = (width, height, data[pos + 9])
        pos += 2 + length
    return None


class JpegReader(Reader):
    """JPEG files, one frame each (8-bit grey; colour files decoded to their luma Y)."""

    suffixes = (".jpg", ".jpeg", ".jpe", ".jfif")
    bgr = True

    def decode(self, path: Path, page: int | None) -> np.ndarray:
        """Decode with ``cv2.imdecode`` (``page`` is ignored); colour files to their luma."""
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
        # (any flag but IMREAD_UNCHANGED makes OpenCV apply the EXIF orientation: ignored, as documented)
        if found is not None and found[2] >= 3:
            return imdecode(data, "JPEG", cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION).view(ColourLuma)
        return imdecode(data, "JPEG")

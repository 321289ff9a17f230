"""Image-format readers and their registry (how to add one: docs/READERS.md).

Each module of this package reads one image format behind the :class:`Reader` interface of
:mod:`dropvision.io.readers.base`; :data:`READERS` lists one instance of each, and
:func:`reader_for` picks the reader of a file by its suffix. Adding a format is one new module
plus one entry in :data:`READERS`.
"""

from __future__ import annotations

from pathlib import PurePath

from dropvision.io.readers.base import ImageInfo, InvalidImage, OpenImage, Reader, UnreadableImage
from dropvision.io.readers.jpeg import JpegReader
from dropvision.io.readers.opencv import OpenCVReader
from dropvision.io.readers.png import PngReader
from dropvision.io.readers.tiff import TiffReader
from dropvision.io.readers.video import VideoReader

__all__ = ["READERS", "IMAGE_SUFFIXES", "reader_for", "Reader", "ImageInfo", "OpenImage",
           "UnreadableImage", "InvalidImage", "VIDEO_SUFFIXES"]

#: The registered readers, one per format. The order fixes the order of
#: :data:`IMAGE_SUFFIXES` (as listed in messages); a suffix belongs to one reader only.
READERS: tuple[Reader, ...] = (
    PngReader(),
    TiffReader(),
    OpenCVReader(),
    JpegReader(),
    VideoReader(),
)

_BY_SUFFIX: dict[str, Reader] = {}
for _reader in READERS:
    for _suffix in _reader.suffixes:
        if _suffix in _BY_SUFFIX:
            raise RuntimeError(f"image suffix {_suffix!r} registered twice "
                               f"({_BY_SUFFIX[_suffix]!r}, {_reader!r})")
        _BY_SUFFIX[_suffix] = _reader
del _reader, _suffix

#: Image file types read (lower-case suffixes).
IMAGE_SUFFIXES: tuple[str, ...] = tuple(_BY_SUFFIX)
#: The suffixes of video files (one file, many frames; delays from ``frame_rate_hz``).
VIDEO_SUFFIXES: tuple[str, ...] = VideoReader.suffixes


def reader_for(path) -> Reader | None:
    """The registered reader of ``path`` by its (case-insensitive) suffix, else None."""
    return _BY_SUFFIX.get(PurePath(path).suffix.lower())

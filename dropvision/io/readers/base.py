"""The interface every image-format reader implements (see docs/READERS.md).

A reader turns one image file into frames: :meth:`Reader.probe` tells how many frames (pages)
the file holds and which delays it stores, :meth:`Reader.decode` decodes one of them to a
numpy array. The sequence layer (:mod:`dropvision.io.sequence`) picks the reader by file suffix
from the registry in :mod:`dropvision.io.readers`, converts colour to grey, checks pixel types and
rotates frames into the canonical orientation; readers do none of that.

Errors: a file that cannot be decoded (truncated, corrupt) raises :class:`UnreadableImage`
(the frame is then reported as unreadable and the sequence goes on); a readable file that
cannot be used as asked (a page that does not exist, contradictory metadata) raises
:class:`InvalidImage` (the sequence layer turns it into a ``SequenceError``).
"""

from __future__ import annotations

import os

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Reader", "ImageInfo", "OpenImage", "UnreadableImage", "InvalidImage", "ColourLuma", "is_number",
           "MAX_PIXELS", "MAX_FILE_BYTES", "check_pixels", "check_file_size", "imdecode"]

#: Largest frame decoded, in pixels (width x height, any number of channels): 100 megapixels.
#: Checked from the file header BEFORE decoding; a larger frame is an :class:`UnreadableImage`
#: (skipped and reported). Readers look the value up at each call, so assigning
#: ``dropvision.io.readers.base.MAX_PIXELS`` changes it for every reader.
MAX_PIXELS = 100_000_000
#: Largest image file read whole into memory (PNG, BMP): 2 GiB. Checked from the file size
#: before reading; a larger file is an :class:`UnreadableImage`. TIFF files are read page by
#: page (any file size); each page's stored data must fit this limit.
MAX_FILE_BYTES = 2 * 1024 ** 3


class UnreadableImage(Exception):
    """An image file that cannot be decoded (zero-byte, truncated, corrupt); the message says
    why, without the file name."""


class InvalidImage(Exception):
    """A readable image file that cannot be used as asked; the message names the file."""


class ColourLuma(np.ndarray):
    """A colour file that its reader decoded straight to its BT.601 luma (the grey rule of the
    sequence layer): a 2-D array view that tells the sequence to note the conversion once."""


def imdecode(data, kind: str, flags: int | None = None) -> np.ndarray:
    """``cv2.imdecode`` of a file's bytes (``IMREAD_UNCHANGED`` by default), its failures as
    :class:`UnreadableImage` naming the format ``kind``."""
    import cv2

    buf = data if isinstance(data, np.ndarray) else np.frombuffer(data, np.uint8)
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED if flags is None else flags) if buf.size else None
    except (cv2.error, MemoryError) as exc:
        raise UnreadableImage(f"cannot decode {kind} ({type(exc).__name__}; truncated, "
                              "corrupt or too large)") from None
    if img is None:
        raise UnreadableImage(f"cannot decode {kind} (truncated or corrupt file)")
    return img


def is_number(value) -> bool:
    """True for an int or float (Python or numpy), False for bool and everything else."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def check_pixels(width: int, height: int, kind: str, depth: int = 1) -> None:
    """Raise :class:`UnreadableImage` when a header claims more than :data:`MAX_PIXELS`
    pixels (or an empty image)."""
    width, height, depth = int(width), int(height), int(depth)
    if width <= 0 or height <= 0 or depth <= 0:
        raise UnreadableImage(f"cannot decode {kind} (header claims an empty "
                              f"{width}x{height} image; corrupt file)")
    n = width * height * depth
    if n > MAX_PIXELS:
        raise UnreadableImage(f"{kind} header claims {width}x{height}"
                              f"{'' if depth == 1 else f'x{depth}'} pixels ({n / 1e6:.0f} "
                              f"megapixels), over the limit of {MAX_PIXELS / 1e6:g} megapixels "
                              "per frame (dropvision.io.readers.base.MAX_PIXELS)")


def check_file_size(size: int, kind: str) -> None:
    """Raise :class:`UnreadableImage` for a file over :data:`MAX_FILE_BYTES`."""
    if size > MAX_FILE_BYTES:
        raise UnreadableImage(f"{kind} file of {size} bytes is over the limit of "
                              f"{MAX_FILE_BYTES} bytes ({MAX_FILE_BYTES / 1024 ** 3:g} GiB, "
                              "dropvision.io.readers.base.MAX_FILE_BYTES)")


def read_file(path, kind: str, limit: int | None = None) -> bytes:
    """The bytes of an image file (the first ``limit`` bytes when given), after checking its
    size against :data:`MAX_FILE_BYTES`; :class:`UnreadableImage` when it cannot be read."""
    try:
        with open(path, "rb") as fh:
            check_file_size(os.fstat(fh.fileno()).st_size, kind)
            return fh.read() if limit is None else fh.read(limit)
    except OSError as exc:
        raise UnreadableImage(f"cannot read file ({exc.strerror or exc})") from None


@dataclass(frozen=True)
class ImageInfo:
    """What :meth:`Reader.probe` learns about a file without decoding pixels.

    Attributes
    ----------
    n_pages : int
        Number of frames (pages) the file holds; 1 for single-image formats.
    page_delays : dict
        Page index -> delay stored in the file (µs), as stored: a number, or a string such as
        ``"1150us"`` (validated by the sequence layer). Empty when the file stores none.
    complete : bool
        False when the file is cut short or corrupt so that pages past ``n_pages`` may exist
        but cannot be found (a TIFF whose page chain points beyond the end of the file).
    """

    n_pages: int = 1
    page_delays: dict = field(default_factory=dict)
    complete: bool = True


class OpenImage:
    """An image file kept open to decode several of its pages (see :meth:`Reader.open`).

    This default keeps nothing open and decodes the file afresh each time.
    """

    def __init__(self, reader: "Reader", path: Path):
        self.reader = reader
        self.path = Path(path)

    def decode(self, page: int | None) -> np.ndarray:
        """Decode ``page`` (None: the file's only image), as :meth:`Reader.decode`."""
        return self.reader.decode(self.path, page)

    def close(self) -> None:
        """Release the file."""


class Reader:
    """Base class of the image-format readers; subclass it and register an instance.

    Class attributes
    ----------------
    suffixes : tuple of str
        Lower-case file suffixes this reader handles (``(".png",)``).
    paged : bool
        True when one file may hold several frames, addressed by ``page`` (TIFF stacks).
    stores_pixel_size : bool
        True when files of this type may carry the pixel size (:meth:`pixel_size`).
    bgr : bool
        Channel order of colour arrays returned by :meth:`decode`: True for BGR(A) (OpenCV),
        False for RGB(A).
    """

    suffixes: tuple[str, ...] = ()
    paged: bool = False
    stores_pixel_size: bool = False
    bgr: bool = True

    def probe(self, path: Path) -> ImageInfo:
        """Pages and stored delays of ``path`` (no pixel decoding). The default: one page, no
        delays. May raise on unreadable files (the caller then assumes the default)."""
        return ImageInfo()

    def decode(self, path: Path, page: int | None) -> np.ndarray:
        """Decode one frame: ``page`` of a paged file (None: the only or first image).

        Returns the array as stored (2-D grey, or (H, W, C) colour in :attr:`bgr` order, or a
        :class:`ColourLuma` when the reader applied the grey rule itself;
        uint8/uint16 for the supported cameras). Raises :class:`UnreadableImage` for a file that
        cannot be decoded and :class:`InvalidImage` for a page that cannot be used.
        """
        raise NotImplementedError

    def header_size(self, path: Path, page: int | None) -> tuple[int, int] | None:
        """(width, height) of ``page`` as the file's header states it, read without decoding
        pixels, or None (the format's reader does not tell, or the header cannot be read). The
        sequence checks it against the first frame's size before decoding."""
        return None

    def open(self, path: Path) -> OpenImage:
        """Open ``path`` to decode several of its pages cheaply; the caller closes it.

        The default reopens the file for each page; paged readers keep it open. Raises
        :class:`UnreadableImage` when the file cannot be opened.
        """
        return OpenImage(self, path)

    def pixel_size(self, path: Path) -> tuple[float | None, str]:
        """Pixel size (µm) stored in the file and its source (e.g. ``"ome"``), else
        ``(None, "")``. Raises :class:`InvalidImage` for contradictory metadata."""
        return None, ""

    def significant_bits(self, path: Path, page: int | None) -> int | None:
        """Significant bits of a 16-bit frame as the file declares them, else None."""
        return None

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(self.suffixes)})"

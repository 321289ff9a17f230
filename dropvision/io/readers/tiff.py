"""TIFF reader: single images and multi-page stacks, with OME-TIFF, ImageJ and JSON metadata.

Delays of the pages come from OME ``Plane DeltaT`` (+ ``DeltaTUnit``, default s) or from
per-page JSON ImageDescriptions ``{"delay_us": ...}``; the pixel size from OME
``PhysicalSizeX/Y``, ImageJ unit + resolution, or ``"pixel_size_um"`` in a JSON description;
the significant bits of 16-bit pages from ``BitsPerSample`` (9..15) or ``MaxSampleValue``.
Pixels are decoded with tifffile (``TiffFile(...).pages[i].asarray()``), after the page's
width x height (from its tags, no pixel data read) is checked against
:data:`dropvision.io.readers.base.MAX_PIXELS` and its stored byte count against
:data:`~dropvision.io.readers.base.MAX_FILE_BYTES`.

A truncated stack: pages whose data is cut are :class:`UnreadableImage` (skipped and reported);
pages listed in sequence.json (or in OME metadata) that lie past a page chain cut by the end of
the file are :class:`UnreadableImage` too, while a page beyond the last page of an intact file
is an :class:`InvalidImage`. tifffile's own log warnings about broken files are silenced (its
logger is set to ERROR unless the application configured a level): the reader reports those
files itself.
"""

from __future__ import annotations

import contextlib
import logging
import math
import re
import struct
import threading
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import tifffile

import dropvision.io.readers.base as base
from dropvision.io.readers.base import (
    ImageInfo, InvalidImage, OpenImage, Reader, UnreadableImage, check_pixels, is_number,
)
from dvcore.jsonio import loads_strict

__all__ = ["TiffReader", "OpenTiff"]

#: Seconds-based OME time units -> factor to µs.
_TIME_UNIT_TO_US = {"s": 1e6, "ms": 1e3, "us": 1.0, "µs": 1.0, "μs": 1.0, "ns": 1e-3,
                    "min": 6e7, "h": 3.6e9}
_TIFFFILE_LOG = logging.getLogger("tifffile")
if _TIFFFILE_LOG.level == logging.NOTSET:
    _TIFFFILE_LOG.setLevel(logging.ERROR)


class _Captured(logging.Handler):
    """tifffile's log lines (a circular page chain, a bad page offset) kept per thread, never
    printed: the problem is reported in our words, with the file it concerns."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.local = threading.local()

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):
            text = re.sub(r"^<[^>]*>\s*", "", record.getMessage())  # "<tifffile.TiffPages @8> ..."
            self.local.last = " ".join(text.split())[:200]

    def count_pages(self, tif: tifffile.TiffFile) -> int:
        """``len(tif.pages)`` (which walks the page chain), remembering on ``tif`` why the walk
        stopped early when tifffile said so (e.g. a circular page chain)."""
        self.local.last = None
        n = len(tif.pages)
        if getattr(tif, "_dv_chain_note", None) is None:
            tif._dv_chain_note = self.local.last
        return n


_CAPTURED = _Captured()
_TIFFFILE_LOG.addHandler(_CAPTURED)
_TIFFFILE_LOG.propagate = False  # no raw tifffile line on the terminal

_LENGTH_UNIT_TO_UM = {"m": 1e6, "cm": 1e4, "mm": 1e3, "um": 1.0, "µm": 1.0, "μm": 1.0,
                      "micron": 1.0, "microns": 1.0, "nm": 1e-3}


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _ome_pixels(ome_xml: str):
    """Yield (Pixels element, ifd_start) for each OME Image."""
    root = ET.fromstring(ome_xml)
    ifd_start = 0
    for image in (e for e in root.iter() if _local(e.tag) == "Image"):
        pixels = next((e for e in image if _local(e.tag) == "Pixels"), None)
        if pixels is None:
            continue
        tiffdata = [e for e in pixels if _local(e.tag) == "TiffData"]
        if tiffdata and "IFD" in tiffdata[0].attrib:
            ifd_start = int(tiffdata[0].attrib["IFD"])
        yield pixels, ifd_start
        sizes = [int(pixels.attrib.get(k, 1)) for k in ("SizeZ", "SizeC", "SizeT")]
        ifd_start += sizes[0] * sizes[1] * sizes[2]


def _ome_delays_us(ome_xml: str) -> dict[int, float]:
    """Page index -> delay (µs) from OME ``Plane DeltaT`` (+ ``DeltaTUnit``, default s)."""
    out: dict[int, float] = {}
    for pixels, ifd_start in _ome_pixels(ome_xml):
        order = pixels.attrib.get("DimensionOrder", "XYZCT")[2:]
        size = {d: int(pixels.attrib.get(f"Size{d}", 1)) for d in "ZCT"}
        for plane in (e for e in pixels if _local(e.tag) == "Plane"):
            if "DeltaT" not in plane.attrib:
                continue
            unit = plane.attrib.get("DeltaTUnit", "s")
            if unit not in _TIME_UNIT_TO_US:
                raise ValueError(f"unknown OME DeltaTUnit {unit!r}")
            theta = {d: int(plane.attrib.get(f"The{d}", 0)) for d in "ZCT"}
            linear, stride = 0, 1
            for d in order:  # first letter varies fastest
                linear += theta[d] * stride
                stride *= size[d]
            out[ifd_start + linear] = float(plane.attrib["DeltaT"]) * _TIME_UNIT_TO_US[unit]
    return out


def _json_description(page) -> dict | None:
    desc = page.description
    if not desc or not desc.lstrip().startswith("{"):
        return None
    try:
        obj = loads_strict(desc)
    except (ValueError, RecursionError):
        return None
    return obj if isinstance(obj, dict) else None


def _page_delays(tif: tifffile.TiffFile) -> dict[int, float]:
    """Page index -> delay (µs) from OME-XML or per-page JSON descriptions ``{"delay_us": ..}``."""
    if tif.is_ome and tif.ome_metadata:
        delays = _ome_delays_us(tif.ome_metadata)
        if delays:
            return delays
    out = {}
    for i, page in enumerate(tif.pages):
        obj = _json_description(page)
        if obj is not None and "delay_us" in obj:
            out[i] = obj["delay_us"]
    return out


def _bit_depth_hint(page) -> int | None:
    """Significant bits of a 16-bit TIFF page from BitsPerSample (9..15) or MaxSampleValue."""
    bits = int(page.bitspersample)
    if 8 < bits < 16:
        return bits
    tag = page.tags.get(281)  # MaxSampleValue
    if tag is not None:
        value = tag.value
        value = max(value) if isinstance(value, (tuple, list)) else value
        if int(value) > 0:
            return int(value).bit_length()
    return None


def _chain_cut(tif: tifffile.TiffFile) -> bool:
    """True when the last page found points to a next page that cannot be read (the file is
    cut short or corrupt), False for an intact page chain ending with a zero offset."""
    pages = tif.pages
    n_pages = len(pages)
    if n_pages == 0:
        return True
    header = tif.tiff
    fh = tif.filehandle
    with fh.lock:
        pos = fh.tell()
        try:
            offset = pages[n_pages - 1].offset
            fh.seek(offset)
            raw = fh.read(header.tagnosize)
            if len(raw) < header.tagnosize:
                return True
            (tagno,) = struct.unpack(header.tagnoformat, raw)
            fh.seek(offset + header.tagnosize + tagno * header.tagsize)
            raw = fh.read(header.offsetsize)
            if len(raw) < header.offsetsize:
                return True
            (nxt,) = struct.unpack(header.offsetformat, raw)
            return nxt != 0
        except Exception:
            return True
        finally:
            fh.seek(pos)


def _page_array(tif: tifffile.TiffFile, path: Path, page: int | None) -> np.ndarray:
    n_pages = _CAPTURED.count_pages(tif)
    if page is None and n_pages > 1:
        raise InvalidImage(f"{path}: multi-page TIFF ({n_pages} pages) needs a 'page' in its "
                           "sequence.json frames entry")
    page = 0 if page is None else page
    if page >= n_pages:
        if _chain_cut(tif):
            why = getattr(tif, "_dv_chain_note", None)
            raise UnreadableImage(f"cannot decode TIFF (page {page} cannot be found: the page "
                                  f"chain is cut after page {n_pages - 1}"
                                  + (f", {why}" if why and "circular" in why else "")
                                  + "; truncated or corrupt file)")
        raise InvalidImage(f"{path}: page {page} does not exist (the TIFF has {n_pages} pages)")
    pg = tif.pages[page]
    key = getattr(pg, "keyframe", None) or pg
    check_pixels(key.imagewidth, key.imagelength, "TIFF", getattr(key, "imagedepth", 1) or 1)
    stored = sum(int(n) for n in (pg.databytecounts or ()))
    if stored > base.MAX_FILE_BYTES:
        raise UnreadableImage(f"TIFF page of {stored} stored bytes is over the limit of "
                              f"{base.MAX_FILE_BYTES} bytes (dropvision.io.readers.base."
                              "MAX_FILE_BYTES)")
    return pg.asarray()


def _unreadable(exc: Exception) -> UnreadableImage:
    return UnreadableImage(f"cannot decode TIFF ({type(exc).__name__}: {exc}; "
                           "truncated or corrupt file)")


def _squeeze(img: np.ndarray) -> np.ndarray:
    return img[0] if img.ndim > 2 and img.shape[0] == 1 else img


class OpenTiff(OpenImage):
    """A TIFF file kept open (a ``tifffile.TiffFile``) to decode several of its pages."""

    def __init__(self, reader: "TiffReader", path: Path):
        super().__init__(reader, path)
        try:
            self.tif = tifffile.TiffFile(self.path)
        except Exception as exc:  # tifffile raises many types for broken files
            raise _unreadable(exc) from None

    def decode(self, page: int | None) -> np.ndarray:
        """Decode ``page`` of the open file, as :meth:`TiffReader.decode`."""
        try:
            img = _page_array(self.tif, self.path, page)
        except (InvalidImage, UnreadableImage):
            raise
        except Exception as exc:
            raise _unreadable(exc) from None
        return _squeeze(img)

    def close(self) -> None:
        """Close the TIFF file."""
        self.tif.close()


class TiffReader(Reader):
    """TIFF files (``.tif``/``.tiff``), single images or multi-page stacks (OME, ImageJ)."""

    suffixes = (".tif", ".tiff")
    paged = True
    stores_pixel_size = True
    bgr = False

    def probe(self, path: Path) -> ImageInfo:
        """Number of pages and the delays stored in OME-XML or per-page JSON descriptions;
        ``complete`` is False when the page chain is cut (truncated or corrupt file)."""
        with tifffile.TiffFile(path) as tif:
            n_pages = _CAPTURED.count_pages(tif)
            return ImageInfo(n_pages, _page_delays(tif), complete=not _chain_cut(tif))

    def decode(self, path: Path, page: int | None) -> np.ndarray:
        """Decode ``page`` (None: the file must hold a single page); a leading axis of length 1
        is dropped."""
        try:
            with tifffile.TiffFile(path) as tif:
                img = _page_array(tif, path, page)
        except (InvalidImage, UnreadableImage):
            raise
        except Exception as exc:  # tifffile raises many types for broken files
            raise _unreadable(exc) from None
        return _squeeze(img)

    def open(self, path: Path) -> OpenTiff:
        """Keep the TIFF open to decode several pages (see :class:`OpenTiff`)."""
        return OpenTiff(self, path)

    def pixel_size(self, path: Path) -> tuple[float | None, str]:
        """Pixel size (µm) from OME PhysicalSizeX/Y ("ome"), ImageJ unit + resolution
        ("imagej") or a JSON description ("tiff-description"); ``(None, "")`` when absent or
        the file is unreadable. Non-square OME pixels raise :class:`InvalidImage`."""
        try:
            with tifffile.TiffFile(path) as tif:
                if tif.is_ome and tif.ome_metadata:
                    for pixels, _ in _ome_pixels(tif.ome_metadata):
                        sizes = []
                        for ax in "XY":
                            if f"PhysicalSize{ax}" in pixels.attrib:
                                unit = pixels.attrib.get(f"PhysicalSize{ax}Unit", "µm")
                                sizes.append(float(pixels.attrib[f"PhysicalSize{ax}"])
                                             * _LENGTH_UNIT_TO_UM[unit])
                        if sizes:
                            if len(sizes) == 2 and not math.isclose(sizes[0], sizes[1],
                                                                    rel_tol=1e-6):
                                raise InvalidImage(f"{path}: OME pixels are not square "
                                                   f"({sizes[0]} x {sizes[1]} µm)")
                            return sizes[0], "ome"
                page = tif.pages[0]
                ij = tif.imagej_metadata
                if ij and str(ij.get("unit", "")).lower() in _LENGTH_UNIT_TO_UM:
                    num, den = page.tags["XResolution"].value
                    if num > 0:
                        return den / num * _LENGTH_UNIT_TO_UM[str(ij["unit"]).lower()], "imagej"
                obj = _json_description(page)
                if obj is not None and is_number(obj.get("pixel_size_um")):
                    return float(obj["pixel_size_um"]), "tiff-description"
        except InvalidImage:
            raise
        except Exception:  # unreadable TIFF: no pixel size from it
            return None, ""
        return None, ""

    def significant_bits(self, path: Path, page: int | None) -> int | None:
        """Significant bits of the page from BitsPerSample (9..15) or MaxSampleValue."""
        with tifffile.TiffFile(path) as tif:
            return _bit_depth_hint(tif.pages[page or 0])

"""Writers of the strobe-sequence format (docs/FORMAT.md): ``sequence.json``, single images
(PNG, TIFF, BMP) and multi-page TIFF stacks carrying their delays, all written atomically.

Used by the synthesizer (:mod:`dropvision.synth.writer`) and the tests; the reading side is
:mod:`dropvision.io.sequence` and :mod:`dropvision.io.readers`.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import cv2
import numpy as np
import tifffile

from dropvision.io.readers import IMAGE_SUFFIXES
from dropvision.io.readers.tiff import TiffReader
from dropvision.io.sequence import SCHEMA, SEQUENCE_JSON
from dvcore.atomic import write_bytes, write_json

__all__ = ["write_sequence_json", "write_image", "write_multipage_tiff"]

_TIFF_SUFFIXES = TiffReader.suffixes


def write_sequence_json(folder, meta_dict: dict) -> Path:
    """Write ``folder/sequence.json`` atomically (temporary file, then ``os.replace``).

    ``schema`` is set to :data:`SCHEMA` when absent; numpy scalars/arrays and paths are
    converted, NaN is written as null (= absent). The folder is created if needed.
    """
    if not isinstance(meta_dict, dict):
        raise TypeError(f"meta_dict must be a dict, got {type(meta_dict).__name__}")
    doc = {"schema": SCHEMA}
    doc.update(meta_dict)
    return write_json(Path(folder) / SEQUENCE_JSON, doc)


def _check_image_array(array, path: Path) -> np.ndarray:
    arr = np.asarray(array)
    if arr.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{path}: image must be uint8 or uint16, got {arr.dtype}")
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] in (3, 4))):
        raise ValueError(f"{path}: image must be 2-D grey or (H, W, 3|4) RGB(A), got {arr.shape}")
    return np.ascontiguousarray(arr)


def _tiff_bytes(write) -> bytes:
    buf = io.BytesIO()
    write(buf)
    return buf.getvalue()


def write_image(path, array, *, page_description: str | None = None) -> Path:
    """Write one image atomically; the type follows the suffix (.png, .tif/.tiff, .bmp).

    Parameters
    ----------
    path : str or Path
        Target file (unicode allowed; parent folders are created).
    array : ndarray
        uint8 or uint16, 2-D grey or (H, W, 3|4) RGB(A) in RGB order. BMP is 8-bit only.
    page_description : str, optional
        TIFF ImageDescription (e.g. ``json.dumps({"delay_us": 30.0})``); TIFF only.
    """
    path = Path(path)
    arr = _check_image_array(array, path)
    suffix = path.suffix.lower()
    if page_description is not None and suffix not in _TIFF_SUFFIXES:
        raise ValueError(f"{path}: page_description is only stored in TIFF files")
    if suffix in _TIFF_SUFFIXES:
        photometric = "minisblack" if arr.ndim == 2 else "rgb"
        data = _tiff_bytes(lambda fh: tifffile.imwrite(
            fh, arr, photometric=photometric, description=page_description, metadata=None))
    elif suffix in (".png", ".bmp"):
        if suffix == ".bmp" and arr.dtype != np.uint8:
            raise ValueError(f"{path}: BMP stores 8-bit images only, got {arr.dtype}")
        if arr.ndim == 3:
            arr = cv2.cvtColor(arr, cv2.COLOR_RGB2BGR if arr.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
        ok, buf = cv2.imencode(suffix, arr)
        if not ok:  # pragma: no cover - cv2 encodes every checked array
            raise ValueError(f"{path}: cv2 could not encode the image")
        data = buf.tobytes()
    else:
        raise ValueError(f"{path}: unsupported image type (use {', '.join(IMAGE_SUFFIXES)})")
    return write_bytes(path, data)


def write_multipage_tiff(path, pages, delays_us, ome: bool = False, *,
                         pixel_size_um: float | None = None) -> Path:
    """Write a multi-page grey TIFF whose pages carry their delays, atomically.

    Parameters
    ----------
    path : str or Path
        Target ``.tif``/``.tiff`` file.
    pages : ndarray (N, H, W) or sequence of 2-D arrays
        Same shape and dtype (uint8 or uint16).
    delays_us : sequence of float
        One delay (µs) per page; repeats allowed.
    ome : bool
        False: each page's ImageDescription is ``{"delay_us": ...}`` (JSON). True: OME-TIFF
        with ``Plane DeltaT`` in µs (``DeltaTUnit="µs"``).
    pixel_size_um : float, optional
        Stored as OME ``PhysicalSizeX/Y`` (µm), or as ``"pixel_size_um"`` in each JSON
        description.
    """
    path = Path(path)
    if path.suffix.lower() not in _TIFF_SUFFIXES:
        raise ValueError(f"{path}: a multi-page stack must be a .tif/.tiff file")
    stack = [_check_image_array(p, path) for p in pages]
    if not stack:
        raise ValueError(f"{path}: no pages")
    if any(p.ndim != 2 or p.shape != stack[0].shape or p.dtype != stack[0].dtype for p in stack):
        raise ValueError(f"{path}: pages must be 2-D grey with equal shape and dtype")
    delays = [float(d) for d in delays_us]
    if len(delays) != len(stack) or not all(math.isfinite(d) for d in delays):
        raise ValueError(f"{path}: need one finite delay per page ({len(stack)} pages, "
                         f"{len(delays)} delays)")
    if ome:
        metadata = {"axes": "TYX",
                    "Plane": {"DeltaT": delays, "DeltaTUnit": ["µs"] * len(delays)}}
        if pixel_size_um is not None:
            metadata.update(PhysicalSizeX=float(pixel_size_um), PhysicalSizeXUnit="µm",
                            PhysicalSizeY=float(pixel_size_um), PhysicalSizeYUnit="µm")
        data = _tiff_bytes(lambda fh: tifffile.imwrite(
            fh, np.stack(stack), ome=True, photometric="minisblack", metadata=metadata))
    else:
        def write(fh):
            with tifffile.TiffWriter(fh) as tw:
                for page, delay in zip(stack, delays):
                    desc = {"delay_us": delay}
                    if pixel_size_um is not None:
                        desc["pixel_size_um"] = float(pixel_size_um)
                    tw.write(page, photometric="minisblack", description=json.dumps(desc),
                             metadata=None)
        data = _tiff_bytes(write)
    return write_bytes(path, data)

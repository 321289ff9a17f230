"""Strobe sequences: open a folder (`open_sequence`) or arrays (`sequence_from_arrays`) and read
its frames (`Sequence`); the format is specified in docs/FORMAT.md.

A sequence is a folder with a ``sequence.json`` (pixel size, nozzle, waveform, ink, frame list)
and images in any format of the reader registry (:mod:`dropvision.io.readers`: PNG, TIFF, BMP,
PNM, JPEG, video). Delays come from the frames list, the file names or TIFF metadata, or, for
high-speed recordings (a video, a numbered image stack, a multi-page TIFF), from
``frame_rate_hz``.
:func:`open_sequence` reads and validates the metadata and decodes the first frame only (to
learn the image size); :class:`Sequence` then decodes one frame at a time, in ascending delay
order, returned as 2-D grey in the canonical orientation (nozzle at the top, drops travelling
down the image).

Its parts: the metadata and errors (`dropvision.io.sequence_meta`), the frames' orientation
(`dropvision.io.orientation`), the validation of values and overrides (`dropvision.io.overrides`) and
the frame discovery (`dropvision.io.discovery`).  The writers of the same format are in
:mod:`dropvision.io.sequence_writer`.
"""

from __future__ import annotations

import math
import os
import stat
import threading
import warnings
from collections import Counter, OrderedDict
import dataclasses
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from dropvision.io.readers import (
    IMAGE_SUFFIXES, VIDEO_SUFFIXES, ImageInfo, InvalidImage, OpenImage, Reader, UnreadableImage,
    reader_for,
)
from dropvision.io.discovery import (is_regular_file, list_from_folder, list_from_frames, list_from_rate, not_regular,
                                  outside_folder,
                                  parse_delay_from_name, read_frame_rate, refusal_reason)
from dropvision.io.labels import check_one_series
from dropvision.io.orientation import (ORIENTATIONS, orientation_of_stored_frame, original_to_canonical, swaps_axes,
                                    to_canonical)
from dropvision.io.overrides import (OVERRIDE_KEYS, check_in_image, check_overrides, finite_or_none, how_to_give,
                                  merged_keywords,
                                  merge_overrides, ranged_value, validate_diameters, validate_ink, validate_waveform)
import dropvision.io.readers.base as readers_base
from dropvision.io.readers.base import ColourLuma, is_number
from dvcore.jsonio import load_json_hardened
from dvcore.schema import RANGES
from dropvision.io.sequence_meta import (NOZZLE_PIXEL_SIZE_SOURCE, Frame, FrameRef, RGBConvertedWarning, SequenceError,
                                      SequenceMeta)

__all__ = [
    "SCHEMA", "SEQUENCE_JSON", "ORIENTATIONS", "SequenceError", "RGBConvertedWarning",
    "FrameRef", "SequenceMeta", "Frame", "Sequence", "ArraySequence", "open_sequence",
    "sequence_from_arrays", "parse_delay_from_name", "RANGES", "OVERRIDE_KEYS", "check_overrides",
]

#: Value of the ``schema`` key of sequence.json (written by ``dropvision.io.sequence_writer``).
SCHEMA = "dropvision.sequence/1"
#: File name of the metadata file in a sequence folder.
SEQUENCE_JSON = "sequence.json"
#: Keys of sequence.json with a meaning; everything else goes to ``SequenceMeta.extra``.
_KNOWN_KEYS = frozenset({
    "schema", "pixel_size_um", "nozzle_inner_diameter_um", "nozzle_outer_diameter_um",
    "nozzle_tip_row", "axis_col", "orientation", "waveform", "ink", "frames", "bit_depth",
    "video", "frame_rate_hz", "first_frame_delay_us", "trigger_frame",
})
#: Open multi-frame files (e.g. TIFF stacks) kept by a Sequence.
_OPEN_CACHE_SIZE = 4


# ----------------------------------------------------------------------------------------
# Grey conversion
# ----------------------------------------------------------------------------------------

def _note_colour(name: str, channels: int) -> None:
    warnings.warn(f"{name}: {channels}-channel image converted to grey (ITU-R BT.601 "
                  "luminance; noted once per sequence, further colour frames are converted "
                  "alike)", RGBConvertedWarning, stacklevel=5)


def _to_grey(img: np.ndarray, name: str, bgr: bool, warn: bool) -> np.ndarray:
    """Collapse a colour image to grey: the ONE rule for every format (docs/FORMAT.md).

    ITU-R BT.601 luminance ``Y = 0.299 R + 0.587 G + 0.114 B`` (cv2.cvtColor's fixed-point
    weights, rounded); alpha is dropped; grey + alpha keeps the grey channel."""
    if img.ndim == 2:
        return img
    if img.ndim == 3 and img.shape[2] == 1:
        return np.ascontiguousarray(img[:, :, 0])
    if img.ndim != 3 or img.shape[2] not in (2, 3, 4):
        raise SequenceError(f"{name}: not a 2-D grey or RGB image (array shape {img.shape})")
    channels = img.shape[2]
    if warn:
        _note_colour(name, channels)
    if channels == 2:  # grey + alpha
        return np.ascontiguousarray(img[:, :, 0])
    if channels == 3:
        code = cv2.COLOR_BGR2GRAY if bgr else cv2.COLOR_RGB2GRAY
    else:
        code = cv2.COLOR_BGRA2GRAY if bgr else cv2.COLOR_RGBA2GRAY
    return cv2.cvtColor(np.ascontiguousarray(img), code)


# ----------------------------------------------------------------------------------------
# Sequence
# ----------------------------------------------------------------------------------------

#: The frame the last opening of a sequence decoded (its probe), as its reader gave it, with the
#: file's identity (path, page, device, inode, size, modification and change times): the next
#: decode of that unchanged file takes a copy instead of decoding again. One frame per process.
_PROBED: list = [None]
_PROBED_LOCK = threading.Lock()


def _probed_frame(key: tuple) -> np.ndarray | None:
    """A copy of the kept probe frame when ``key`` is its file's identity, else None."""
    with _PROBED_LOCK:
        kept = _PROBED[0]
    return kept[1].copy() if kept is not None and kept[0] == key else None


def _keep_probed_frame(key: tuple, image: np.ndarray) -> None:
    with _PROBED_LOCK:
        _PROBED[0] = (key, image.copy())


class Sequence:
    """An open strobe sequence: metadata in :attr:`meta`, frames decoded lazily.

    Iterating yields :class:`Frame` objects in processing (ascending delay) order, one decoded
    image at a time. Use as a context manager (or call :meth:`close`) to close cached
    multi-page TIFF files.
    """

    def __init__(self, meta: SequenceMeta, dtype: np.dtype, refused: dict | None = None):
        self.meta = meta
        self._dtype = np.dtype(dtype)
        #: file -> why it is not read (a symbolic link resolving outside the folder)
        self._refused = dict(refused or {})
        self._init_cache()

    def _init_cache(self) -> None:
        counts = Counter(f.file for f in self.meta.frames)
        self._shared_files = {f for f, n in counts.items() if n > 1}
        self._open_files: OrderedDict[str, OpenImage] = OrderedDict()
        self._lock = threading.Lock()
        #: True once the colour -> grey note (RGBConvertedWarning) was given for this sequence
        self._colour_noted = False

    # -- container protocol --------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.meta.frames)

    def __iter__(self) -> Iterator[Frame]:
        try:
            for i in range(len(self)):
                yield self.read(i)
        finally:
            self.close()

    def __enter__(self) -> "Sequence":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"Sequence({str(self.meta.path)!r}, {len(self)} frames, "
                f"shape={self.meta.shape}, bit_depth={self.meta.bit_depth})")

    def __getstate__(self):  # picklable for process pools: open files are not carried over
        return {"meta": self.meta, "_dtype": self._dtype, "_refused": self._refused}

    def __setstate__(self, state) -> None:
        self.meta = state["meta"]
        self._dtype = state["_dtype"]
        self._refused = state.get("_refused", {})
        self._init_cache()

    def __del__(self):
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass

    def first_colour_note(self) -> bool:
        """True the first time it is called for this sequence (the colour -> grey note is given
        once per sequence, however many colour frames follow, from whichever thread)."""
        with self._lock:
            first, self._colour_noted = not self._colour_noted, True
        return first

    def after_fork(self) -> None:
        """In a forked child: a lock of its own (the parent's may have been held at the fork) and
        none of the parent's open multi-frame files (their offsets are shared with the parent):
        the child's copies are closed (the parent's stay open) and reopened when read. The
        once-per-sequence colour note keeps its state."""
        inherited, self._open_files = self._open_files, OrderedDict()
        self._lock = threading.Lock()
        for handle in inherited.values():
            try:
                handle.close()
            except Exception:  # noqa: BLE001 - a copy we only drop; the parent's is untouched
                pass

    @property
    def open_files(self) -> tuple[str, ...]:
        """Files (relative paths) of several frames each, kept open right now, oldest first."""
        with self._lock:
            return tuple(self._open_files)

    def close(self) -> None:
        """Close cached multi-frame files (reading again reopens them)."""
        with self._lock:
            while self._open_files:
                _, handle = self._open_files.popitem()
                handle.close()

    # -- reading ---------------------------------------------------------------------------
    def read(self, index: int) -> Frame:
        """Decode frame ``index`` (processing order).

        Returns a :class:`Frame` whose ``error`` is set (and ``image`` None) for an unreadable,
        truncated or zero-byte image. Raises :class:`SequenceError` when the image size or
        type differs from the first frame, or the file has vanished.
        """
        ref = self.meta.frames[index]
        try:
            img = self._decode(ref, warn=True)
        except UnreadableImage as exc:
            return Frame(ref, None, f"{_where(ref)}: {exc}")
        if img.shape != self.meta.shape:
            raise SequenceError(f"{self.meta.path / ref.file}{_page_txt(ref)}: image size "
                                f"{img.shape[1]}x{img.shape[0]} (canonical, WxH) differs from "
                                f"the first frame's {self.meta.shape[1]}x{self.meta.shape[0]}")
        if img.dtype != self._dtype:
            raise SequenceError(f"{self.meta.path / ref.file}{_page_txt(ref)}: pixel type "
                                f"{img.dtype} differs from the first frame's {self._dtype}")
        return Frame(ref, img, None)

    def _decode(self, ref: FrameRef, *, warn: bool, keep: bool = False) -> np.ndarray:
        """Frame ``ref`` decoded, grey, canonical. ``keep``: the opening's probe (`open_sequence`
        decodes the first readable frame): the decoded frame is kept for the next decode of the
        same unchanged file (`_probed_frame`), so that opening a sequence and reading its first
        frame, or opening a folder again (the shot watch's check, then its measurement), decode
        that image once."""
        path = self.meta.path / ref.file
        if ref.file in self._refused:
            raise UnreadableImage(self._refused[ref.file])
        try:
            st = path.stat()
        except FileNotFoundError:
            raise SequenceError(f"{path}: image file is missing") from None
        except (OSError, ValueError) as exc:
            raise UnreadableImage(f"cannot access file ({getattr(exc, 'strerror', None) or exc})"
                                  ) from None
        if not stat.S_ISREG(st.st_mode):  # a FIFO would block the reader, a device read without end
            raise UnreadableImage(f"{not_regular(path) or 'not a regular file'}, not a regular file; not read")
        size = st.st_size
        if size == 0:
            raise UnreadableImage("zero-byte file")
        reader = reader_for(path)
        self._check_header_size(reader, path, ref)
        key = (str(path), ref.page, st.st_dev, st.st_ino, size, st.st_mtime_ns, st.st_ctime_ns)
        try:
            img = _probed_frame(key)
            if img is None:
                img = self._decode_native(reader, path, ref)
                if keep:
                    _keep_probed_frame(key, img)
        except InvalidImage as exc:
            raise SequenceError(str(exc)) from None
        as_grey = isinstance(img, ColourLuma)  # the reader applied the grey rule itself
        if as_grey:
            img = img.view(np.ndarray)
        warn = warn and ((img.ndim == 3 and img.shape[2] > 1) or as_grey) and self.first_colour_note()
        if as_grey and warn:
            _note_colour(_where(ref), 3)
        img = _to_grey(img, _where(ref), reader.bgr, warn and not as_grey)
        if img.dtype not in (np.uint8, np.uint16):
            raise SequenceError(f"{path}{_page_txt(ref)}: unsupported pixel type {img.dtype} "
                                "(8-bit or 16-bit unsigned grey images are read)")
        return to_canonical(img, self.meta.orientation)

    def _check_header_size(self, reader: Reader, path: Path, ref: FrameRef) -> None:
        """Refuse, before decoding, a frame whose header states another size than the first
        frame's (a 9999x9999 RGBA PNG is not decoded to be refused after)."""
        if not all(self.meta.shape):  # the first frame is being looked for: no size yet
            return
        stated = reader.header_size(path, ref.page)
        if stated is None or not 0 < stated[0] * stated[1] <= readers_base.MAX_PIXELS:
            return  # an empty or oversized header: the reader refuses it (a skipped frame)
        rows, cols = self.meta.shape if not swaps_axes(self.meta.orientation) else self.meta.shape[::-1]
        if stated != (cols, rows):
            first = self.meta.shape
            width, height = stated if not swaps_axes(self.meta.orientation) else stated[::-1]
            raise SequenceError(f"{path}{_page_txt(ref)}: image size {width}x{height} (canonical, WxH, from its "
                                f"header) differs from the first frame's {first[1]}x{first[0]}")

    def _decode_native(self, reader: Reader, path: Path, ref: FrameRef) -> np.ndarray:
        """Decode one frame with its reader; files holding several frames stay open in a small
        LRU cache (guarded by a lock, so a Sequence may be read from several threads)."""
        if ref.file not in self._shared_files:
            return reader.decode(path, ref.page)
        with self._lock:
            handle = self._open_files.pop(ref.file, None)
            if handle is None:
                handle = reader.open(path)
            try:
                img = handle.decode(ref.page)
            except BaseException:
                handle.close()
                raise
            self._open_files[ref.file] = handle
            while len(self._open_files) > _OPEN_CACHE_SIZE:
                self._open_files.popitem(last=False)[1].close()
        return img


def _page_txt(ref: FrameRef) -> str:
    return "" if ref.page is None else f" page {ref.page}"


def _where(ref: FrameRef) -> str:
    return f"{ref.file}{_page_txt(ref)}"


# ----------------------------------------------------------------------------------------
# open_sequence, step by step: the folder, its document (sequence.json merged with the
# overrides), the document's keys validated, the frames listed and ordered, the pixel size
# given, the first readable frame probed, its bit depth.
# ----------------------------------------------------------------------------------------


def _sequence_folder(path) -> Path:
    """The sequence folder of ``path`` (a folder or its sequence.json), absolute; SequenceError
    when it is missing or no folder."""
    folder = Path(path)
    if folder.name == SEQUENCE_JSON and folder.is_file():
        folder = folder.parent
    folder = folder.absolute()
    if not folder.exists():
        raise SequenceError(f"{folder}: sequence folder does not exist")
    if not folder.is_dir():
        raise SequenceError(f"{folder}: not a folder (a sequence is a folder with sequence.json "
                            "and images)")
    return folder


@dataclasses.dataclass(frozen=True)
class _Document:
    """A sequence folder's document: sequence.json as read (``file_doc``, None without one) and
    merged with the overrides (``doc``, None when neither gives anything), and where each
    overridden key came from (``wheres``)."""

    folder: Path
    folder_real: str
    json_path: Path
    file_doc: dict | None
    doc: dict | None
    wheres: dict

    def where_of(self, *keys: str) -> str:
        """Where the first of ``keys`` that was overridden came from, else sequence.json's path."""
        return next((self.wheres[k] for k in keys if k in self.wheres), str(self.json_path))

    def source_of(self, key: str) -> str | None:
        """``SequenceMeta.sources`` of a key: the override's label, sequence.json, or None."""
        if key in self.wheres:
            return self.wheres[key]
        return SEQUENCE_JSON if self.file_doc is not None and self.file_doc.get(key) is not None else None


def _read_document(folder: Path, given: dict, labels: dict, ignore_sequence_json: bool,
                   allow_outside_links: bool) -> _Document:
    """Read sequence.json (refused when linked outside the folder) and merge the overrides."""
    json_path = folder / SEQUENCE_JSON
    folder_real = os.path.realpath(folder)
    json_exists = not ignore_sequence_json and is_regular_file(json_path)
    if json_exists and not allow_outside_links:
        target = outside_folder(folder_real, json_path)
        if target is not None:
            raise SequenceError(f"{json_path}: {refusal_reason(target)}")
    file_doc = load_json_hardened(json_path, SequenceError) if json_exists else None
    doc, wheres = merge_overrides(file_doc, given, labels, json_path)
    return _Document(folder, folder_real, json_path, file_doc, doc, wheres)


@dataclasses.dataclass(frozen=True)
class _Keys:
    """The validated keys of a sequence's document (defaults without one)."""

    orientation: str = "down"
    orientation_given: bool = False
    bit_depth: int | None = None
    d_in: float | None = None
    d_out: float | None = None
    tip_row: float | None = None
    axis_col: float | None = None
    waveform: dict | None = None
    ink: dict | None = None
    extra: dict = dataclasses.field(default_factory=dict)


def _document_keys(d: _Document) -> _Keys:
    """Validate the document's schema, orientation, bit depth, diameters, nozzle position,
    waveform and ink (SequenceError naming where each came from)."""
    doc = d.doc
    if doc is None:
        return _Keys()
    schema = doc.get("schema")
    schema = SCHEMA if schema is None else schema  # null means absent
    if schema != SCHEMA:
        raise SequenceError(f"{d.json_path}: unsupported schema {schema!r} (expected {SCHEMA!r})")
    orientation = doc.get("orientation")
    orientation = "down" if orientation is None else orientation  # null means absent
    orientation = orientation.strip().lower() if isinstance(orientation, str) else orientation
    if orientation not in ORIENTATIONS:
        raise SequenceError(f"{d.where_of('orientation')}: orientation must be one of {ORIENTATIONS}, "
                            f"got {doc.get('orientation')!r}")
    bit_depth_key = doc.get("bit_depth")
    if bit_depth_key is not None and (not is_number(bit_depth_key)
                                      or bit_depth_key not in (8, 12, 16)):
        raise SequenceError(f"{d.json_path}: bit_depth must be 8, 12 or 16, got {bit_depth_key!r}")
    d_in, d_out = validate_diameters(doc.get("nozzle_inner_diameter_um"), doc.get("nozzle_outer_diameter_um"),
                                     d.where_of("nozzle_outer_diameter_um", "nozzle_inner_diameter_um"))
    tip_row = finite_or_none(doc.get("nozzle_tip_row"), "nozzle_tip_row", d.where_of("nozzle_tip_row"))
    axis_col = finite_or_none(doc.get("axis_col"), "axis_col", d.where_of("axis_col"))
    waveform = validate_waveform(doc.get("waveform"), d.where_of("waveform"))
    ink = validate_ink(doc.get("ink"), d.where_of("ink"))
    extra = {k: v for k, v in doc.items() if k not in _KNOWN_KEYS}
    return _Keys(orientation, doc.get("orientation") is not None, bit_depth_key, d_in, d_out, tip_row, axis_col,
                 waveform, ink, extra)


def _list_frames(d: _Document, given: dict, refused: dict, allow_outside_links: bool, only_files,
                 labels: dict) -> tuple[list, str, bool]:
    """The listed frames (a recording at frame_rate_hz, sequence.json's frames, or the folder's
    images) with their delays, where the delays come from (``sources["delay"]``), and whether the
    delay of a lone frame was assumed (0 µs: ``SequenceMeta.delay_assumed``)."""
    doc, folder = d.doc, d.folder
    only = None if only_files is None else frozenset(str(f) for f in only_files)
    rate = read_frame_rate(doc, d.where_of("frame_rate_hz")) if doc is not None else None
    if rate is not None:
        listed = list_from_rate(folder, doc.get("video"), rate, d.json_path, d.folder_real,
                                refused, allow_outside_links, only)
        if doc.get("video") is None:  # images of other settings (labels in their names) are no recording
            check_one_series([item.file for item in listed], folder)
        delay_source = f"frame_rate_hz ({d.source_of('frame_rate_hz')})"
    elif doc is not None and doc.get("frames") is not None:
        listed = list_from_frames(folder, doc["frames"], d.json_path, d.folder_real, refused,
                                  allow_outside_links, only)
        delay_source = "sequence.json frames (or the file names they list)"
    else:
        listed = list_from_folder(folder, d.folder_real, refused, allow_outside_links,
                                  lone_ok=True, only=only)
        delay_source = "file names or image metadata"
    if "delay_us" in given:
        if len(listed) != 1:
            raise SequenceError(f"{d.wheres['delay_us']}: the delay of a single frame, but {folder} has "
                                f"{len(listed)} frames (their delays come from the file names, a "
                                "frames list or frame_rate_hz)")
        listed[0].delay_us = given["delay_us"]
        delay_source = d.wheres["delay_us"]
    elif listed and listed[0].delay_us is None:  # one frame, no delay anywhere
        listed[0].delay_us = 0.0
        delay_source = ("assumed 0 us: one frame without a delay in its name or metadata "
                        "(give delay_us: --delay-us on the command line, or sequence.json frames)")
        return listed, delay_source, True
    return listed, delay_source, False


def _given_pixel_size(d: _Document, listed: list, refused: dict, d_out: float | None, require_pixel_size: bool,
                      labels: dict) -> tuple[float | None, str | None]:
    """The pixel size and its source: option, sequence.json, else the metadata of the first
    listed file of a type that may store it (scientific TIFF); None when it is to come from the
    nozzle's outer diameter (after the probe), NaN when not required; else SequenceError."""
    doc, folder = d.doc, d.folder
    if doc is not None and doc.get("pixel_size_um") is not None:
        pixel_size_um = ranged_value(doc["pixel_size_um"], "pixel_size_um", "pixel_size_um",
                                     d.where_of("pixel_size_um"))
        return pixel_size_um, d.wheres.get("pixel_size_um", "sequence.json")
    pixel_size_um, source = None, "sequence.json"
    first_sized = next((item.file for item in listed if item.file not in refused
                        and reader_for(item.file).stores_pixel_size), None)
    if first_sized is not None:
        try:
            pixel_size_um, source = reader_for(first_sized).pixel_size(folder / first_sized)
        except InvalidImage as exc:
            raise SequenceError(str(exc)) from None
    if pixel_size_um is not None:
        pixel_size_um = ranged_value(pixel_size_um, "pixel_size_um",
                                     f"pixel size from the {source} metadata",
                                     str(folder / first_sized))
    elif not require_pixel_size:
        pixel_size_um, source = math.nan, None
    elif d_out is None:
        hint = (f"; give it with {how_to_give('pixel_size_um', labels)}, or the nozzle's outer diameter with "
                f"{how_to_give('nozzle_outer_diameter_um', labels)} (dropvision init writes a sequence.json)")
        if d.file_doc is None:
            raise SequenceError(f"{folder}: sequence.json (pixel_size_um) is missing and "
                                f"the images carry no pixel size{hint}")
        raise SequenceError(f"{d.json_path}: pixel_size_um is missing (required: pixel size in "
                            f"µm, a number > 0){hint}")
    return pixel_size_um, source


def _frame_refs(listed: list) -> tuple[list[FrameRef], bool]:
    """The frames in processing order (ascending delay, stable: listed order, then page), each
    with its repeat number at its delay, and whether that order differs from the listed one."""
    order = sorted(range(len(listed)), key=lambda i: listed[i].delay_us)
    repeats: Counter = Counter()
    refs = []
    for index, i in enumerate(order):
        item = listed[i]
        key = round(item.delay_us, 6)
        refs.append(FrameRef(index, item.file, item.page, item.delay_us, repeats[key], i))
        repeats[key] += 1
    return refs, order != list(range(len(listed)))


def _first_readable(probe: Sequence, refs: list[FrameRef]) -> tuple[np.ndarray, FrameRef]:
    """The first frame (processing order) that decodes, as stored, and its reference (the probe
    is closed); SequenceError naming the first problem when none does."""
    first_error = None
    try:
        for ref in refs:
            try:
                return probe._decode(ref, warn=False, keep=True), ref
            except UnreadableImage as exc:
                first_error = first_error or f"{probe.meta.path / ref.file}{_page_txt(ref)}: {exc}"
    finally:
        probe.close()
    raise SequenceError(f"{probe.meta.path}: no readable image among {len(refs)} frame(s) "
                        f"(first problem: {first_error})")


def _bit_depth(d: _Document, bit_depth_key: int | None, first_img: np.ndarray, first_ref: FrameRef
               ) -> tuple[int, str | None]:
    """The bit depth (8, 12 or 16) and, when the images tell it, what told it (None: the
    document's)."""
    first_path = d.folder / first_ref.file
    if first_img.dtype == np.uint8:
        if bit_depth_key not in (None, 8):
            raise SequenceError(f"{d.where_of('bit_depth')}: bit_depth {bit_depth_key} but {first_path} is 8-bit")
        return 8, "8-bit images"
    if bit_depth_key is not None:
        return int(bit_depth_key), None
    hint = reader_for(first_path).significant_bits(first_path, first_ref.page)
    bit_depth = hint if hint is not None and 8 < hint <= 16 else 16
    bit_depth = 12 if 8 < bit_depth <= 12 else 16  # report 8, 12 or 16
    return bit_depth, ("significant bits in the image header" if hint is not None and 8 < hint <= 16
                       else "16-bit images")


# ----------------------------------------------------------------------------------------
# open_sequence
# ----------------------------------------------------------------------------------------



def open_sequence(path, *, allow_outside_links: bool = False, overrides: dict | None = None,
                  labels: dict | None = None, ignore_sequence_json: bool = False,
                  require_pixel_size: bool = True, only_files=None, **metadata) -> Sequence:
    """Open a strobe-sequence folder: read and validate its metadata, probe the first frame.

    Parameters
    ----------
    path : str or Path
        The sequence folder (or its ``sequence.json``).
    allow_outside_links : bool
        Read frames and a sequence.json that are symbolic links (or lie under linked folders)
        resolving outside the sequence folder. By default such a frame is skipped and reported
        (``Frame.error``) and such a sequence.json is a :class:`SequenceError`.
    overrides : dict, optional
        Values of sequence.json keys (``OVERRIDE_KEYS``) given outside the file (command-line
        options, arguments): they replace the file's (a partial ``waveform`` replaces the keys
        it gives), pass the same validation (`check_overrides`), and are named in
        ``SequenceMeta.sources``. ``delay_us`` is the delay of a sequence of one frame.
        ``nozzle_outer_diameter_um`` without any pixel size gives the pixel size: that
        diameter over the nozzle's outer width in px, the median over up to 7 frames spread
        over the sequence (`dropvision.calibrate.inspection.nozzle_outer_width_px`).
    labels : dict, optional
        key -> how the user gave it (e.g. ``"command line --pixel-size-um"``), for messages
        and sources; default ``"argument <key>"``.
    ignore_sequence_json : bool
        Look at the images alone, as if there were no sequence.json (``dropvision init
        --overwrite``).
    require_pixel_size : bool
        False: a sequence without any pixel size opens with ``pixel_size_um`` NaN (and the
        nozzle is not measured for one): to describe a folder, not to measure it.
    only_files : collection of str, optional
        List only these files (paths relative to the folder): the frames of a folder that a
        writer is still filling (``dropvision watch``). A frames-list entry or an image of the
        folder not among them is left out, not an error. None: every file.
    **metadata
        Keys of sequence.json (``OVERRIDE_KEYS``: ``pixel_size_um=3``, ``orientation="up"``, ...),
        as `dropvision.measure` takes them: the same as ``overrides`` (not both for one key).

    Returns
    -------
    Sequence
        Lazily decoding sequence; frames in ascending delay order.

    Raises
    ------
    SequenceError
        Folder missing or without images, invalid sequence.json or option, missing/invalid
        pixel_size_um, a number outside its accepted range (``RANGES``), unparsable delay,
        listed file missing, sequence.json linked outside the folder, no readable frame.

    Notes
    -----
    Without an ``orientation`` (file or option) the orientation is detected from the first
    frame (`dropvision.io.orientation.detect_orientation`); a frame that does not tell keeps
    ``"down"``, and ``sources["orientation"]`` says what was seen at each edge. A folder of
    ONE image without a delay in its name or metadata gets ``delay_us`` (option) or 0 µs,
    stated in ``sources["delay"]``.
    """
    labels = dict(labels or {})
    overrides = merged_keywords(overrides, metadata, f"open_sequence({str(path)!r})")
    given = check_overrides(overrides, labels)
    d = _read_document(_sequence_folder(path), given, labels, ignore_sequence_json, allow_outside_links)
    keys = _document_keys(d)
    sources = {"pixel_size": None, "orientation": d.source_of("orientation"),
               "nozzle_outer_diameter": d.source_of("nozzle_outer_diameter_um"),
               "nozzle_inner_diameter": d.source_of("nozzle_inner_diameter_um"), "delay": None,
               "waveform": d.source_of("waveform"), "bit_depth": d.source_of("bit_depth"),
               # who opened it (`dropvision.io.overrides.how_to_give`): later messages name its options or arguments
               "caller": labels.get("_caller")}
    refused: dict[str, str] = {}
    listed, sources["delay"], delay_assumed = _list_frames(d, given, refused, allow_outside_links, only_files, labels)
    pixel_size_um, source = _given_pixel_size(d, listed, refused, keys.d_out, require_pixel_size, labels)
    refs, reordered = _frame_refs(listed)

    # probe: first readable frame (processing order) gives shape, type, bit depth; without a
    # given orientation it is probed as stored and the orientation is detected from it
    probe_meta = SequenceMeta(d.folder, pixel_size_um or 1.0, keys.d_in, keys.d_out, None, None,
                              keys.orientation if keys.orientation_given else "down",
                              keys.waveform, keys.ink, tuple(refs), (0, 0), 0, reordered, keys.extra, source)
    first_img, first_ref = _first_readable(Sequence(probe_meta, np.uint8, refused), refs)
    orientation = keys.orientation
    orientation_assumed = False
    if not keys.orientation_given:
        orientation, sources["orientation"], orientation_assumed = orientation_of_stored_frame(
            first_img, first_ref.file, orientation)
        first_img = to_canonical(first_img, orientation)
    canonical_shape = tuple(int(n) for n in first_img.shape)
    original_shape = (canonical_shape if not swaps_axes(orientation)
                      else canonical_shape[::-1])
    bit_depth, bit_depth_source = _bit_depth(d, keys.bit_depth, first_img, first_ref)
    sources["bit_depth"] = sources["bit_depth"] or bit_depth_source
    sources["pixel_size"] = source

    check_in_image(keys.tip_row, keys.axis_col, original_shape, d.where_of("nozzle_tip_row", "axis_col"))
    tip_c, axis_c = original_to_canonical(keys.tip_row, keys.axis_col, orientation, original_shape)
    meta = SequenceMeta(d.folder, pixel_size_um, keys.d_in, keys.d_out,
                        None if tip_c is None else float(tip_c),
                        None if axis_c is None else float(axis_c),
                        orientation, keys.waveform, keys.ink, tuple(refs), canonical_shape, bit_depth,
                        reordered, keys.extra, source, sources, orientation_assumed=orientation_assumed,
                        delay_assumed=delay_assumed)
    seq = Sequence(meta, first_img.dtype, refused)
    if pixel_size_um is None:
        from dropvision.calibrate.inspection import pixel_size_from_nozzle_width  # loaded when needed

        seq.meta = pixel_size_from_nozzle_width(seq.meta, _nozzle_frames(seq, first_img, first_ref), first_ref.file,
                                                d.where_of("nozzle_outer_diameter_um"))
    return seq


def pixel_size_from_nozzle(meta) -> bool:
    """Whether the pixel size was not given and comes from the nozzle's (needle's) outer diameter:
    the calibration measures the width again by the same rule in its first frame and that value is
    the pixel size (`dropvision.calibrate.calibration.calibrate_frames` ``pixel_size_from_nozzle``)."""
    return bool(getattr(meta, "pixel_size_from_nozzle", False))


def _nozzle_frames(seq: Sequence, first_img: np.ndarray, first_ref: FrameRef) -> list[np.ndarray]:
    """The first frame and up to `dropvision.calibrate.inspection.NOZZLE_FRAMES` - 1 more spread over the
    sequence (decoded here, then the sequence's readers are closed), to measure the nozzle in."""
    from dropvision.calibrate.inspection import NOZZLE_FRAMES

    n = len(seq.meta.frames)
    images = [first_img]
    for i in np.unique(np.round(np.linspace(0, n - 1, min(n, NOZZLE_FRAMES))).astype(int)):
        if int(i) != first_ref.index:
            fr = seq.read(int(i))
            if fr.image is not None:
                images.append(fr.image)
    seq.close()
    return images


class ArraySequence(Sequence):
    """A sequence whose frames are arrays in memory (see :func:`sequence_from_arrays`)."""

    def __init__(self, meta: SequenceMeta, images: list[np.ndarray]):
        super().__init__(meta, images[0].dtype)
        self._images = images  # canonical orientation, processing (delay) order

    def __getstate__(self):
        return {"meta": self.meta, "_dtype": self._dtype, "_refused": {},
                "_images": self._images}

    def __setstate__(self, state) -> None:
        super().__setstate__(state)
        self._images = state["_images"]

    def read(self, index: int) -> Frame:
        return Frame(self.meta.frames[index], self._images[index], None)


def sequence_from_arrays(images, delays_us, *, pixel_size_um: float, orientation: str | None = None,
                         nozzle_inner_diameter_um: float | None = None,
                         nozzle_outer_diameter_um: float | None = None,
                         nozzle_tip_row: float | None = None, axis_col: float | None = None,
                         waveform: dict | None = None, ink: dict | None = None, bit_depth: int | None = None,
                         name: str = "in-memory") -> ArraySequence:
    """A sequence from frames already in memory (a camera SDK, a video decoded elsewhere).

    Parameters
    ----------
    images : array_like, shape (n, rows, cols) or (n, rows, cols, 3), or a list of such frames
        8- or 16-bit unsigned frames, as recorded (``orientation`` says where the drops fly);
        colour frames (RGB order) become grey by luminance.
    delays_us : array_like of float, shape (n,)
        Strobe delay of each frame after the firing trigger (µs); any order, repeats allowed.
    pixel_size_um : float
        Pixel size in µm (> 0).
    orientation : str, optional
        As in sequence.json; None: detected from the first frame in delay order
        (`dropvision.io.orientation.detect_orientation`), ``"down"`` when it does not tell.
    nozzle_inner_diameter_um, nozzle_outer_diameter_um, nozzle_tip_row, axis_col, waveform, ink
        As the keys of sequence.json (docs/FORMAT.md); row/column in the frames as given.
    bit_depth : int, optional
        8, 12 or 16 (default: 8 for uint8 frames, 16 for uint16).
    name : str
        Shown as the sequence in results and messages.

    Raises
    ------
    SequenceError
        Frames of different sizes or types, a delay count that does not match, bad metadata.
    """
    where = f"<{name}>"
    if isinstance(images, np.ndarray):
        frames = [images[i] for i in range(images.shape[0])] if images.ndim >= 3 else [images]
    else:
        frames = [np.asarray(f) for f in images]
    delays = np.atleast_1d(np.asarray(delays_us, dtype=float))
    if not frames:
        raise SequenceError(f"{where}: no frames")
    if delays.shape != (len(frames),):
        raise SequenceError(f"{where}: {len(frames)} frame(s) but {delays.size} delay(s)")
    if not np.all(np.isfinite(delays)):
        raise SequenceError(f"{where}: delays_us must be finite numbers")
    lo, hi, unit = RANGES["delay_us"]
    if delays.size and not (lo <= delays.min() and delays.max() <= hi):
        raise SequenceError(f"{where}: delays_us must lie in the accepted range "
                            f"{lo:g}..{hi:g} {unit}")
    if pixel_size_um is None:
        raise SequenceError(f"{where}: pixel_size_um is missing (required, a number > 0)")
    pixel_size_um = ranged_value(pixel_size_um, "pixel_size_um", "pixel_size_um", where)
    orientation = orientation.strip().lower() if isinstance(orientation, str) else orientation
    if orientation is not None and orientation not in ORIENTATIONS:
        raise SequenceError(f"{where}: orientation must be one of {ORIENTATIONS}, got {orientation!r}")
    grey = []
    for i, img in enumerate(frames):
        img = _to_grey(np.asarray(img), f"{where} frame {i}", False, False)
        if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
            raise SequenceError(f"{where} frame {i}: expected a 2-D uint8/uint16 frame (or RGB), "
                                f"got shape {img.shape} {img.dtype}")
        grey.append(img)
    if len({(g.shape, g.dtype) for g in grey}) != 1:
        raise SequenceError(f"{where}: frames differ in size or pixel type "
                            f"({sorted({(g.shape, str(g.dtype)) for g in grey})})")
    bit_depth_given = bit_depth is not None
    if bit_depth is None:
        bit_depth = 8 if grey[0].dtype == np.uint8 else 16
    if bit_depth not in ((8,) if grey[0].dtype == np.uint8 else (12, 16)):
        raise SequenceError(f"{where}: bit_depth {bit_depth!r} does not fit {grey[0].dtype} frames")
    order = sorted(range(len(grey)), key=lambda i: delays[i])
    sources = {"pixel_size": "argument pixel_size_um", "orientation": "argument orientation",
               "nozzle_outer_diameter": None if nozzle_outer_diameter_um is None else "argument nozzle_outer_diameter_um",
               "nozzle_inner_diameter": None if nozzle_inner_diameter_um is None else "argument nozzle_inner_diameter_um",
               "delay": "argument delays_us", "waveform": None if waveform is None else "argument waveform",
               "bit_depth": "argument bit_depth" if bit_depth_given else f"{grey[0].dtype} frames"}
    orientation_assumed = False
    if orientation is None:
        orientation, sources["orientation"], orientation_assumed = orientation_of_stored_frame(
            grey[order[0]], f"frame {order[0]}")
    repeats: Counter = Counter()
    refs, canonical = [], []
    for index, i in enumerate(order):
        key = round(float(delays[i]), 6)
        refs.append(FrameRef(index, f"frame_{i:05d}", None, float(delays[i]), repeats[key], i))
        repeats[key] += 1
        canonical.append(np.ascontiguousarray(to_canonical(grey[i], orientation)))
    tip_row = finite_or_none(nozzle_tip_row, "nozzle_tip_row", where)
    axis_col = finite_or_none(axis_col, "axis_col", where)
    check_in_image(tip_row, axis_col, grey[0].shape, where)
    tip_c, axis_c = original_to_canonical(tip_row, axis_col, orientation, grey[0].shape)
    d_in, d_out = validate_diameters(nozzle_inner_diameter_um, nozzle_outer_diameter_um, where)
    meta = SequenceMeta(Path(where), pixel_size_um, d_in, d_out,
                        None if tip_c is None else float(tip_c), None if axis_c is None else float(axis_c),
                        orientation, validate_waveform(waveform, where), validate_ink(ink, where),
                        tuple(refs), tuple(int(n) for n in canonical[0].shape), int(bit_depth),
                        order != list(range(len(grey))), {}, "arguments", sources,
                        orientation_assumed=orientation_assumed)
    return ArraySequence(meta, canonical)

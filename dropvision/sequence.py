"""Strobe sequences: ``sequence.json`` validation, delays, order and orientation
(the format is specified in docs/FORMAT.md).

A sequence is a folder with a ``sequence.json`` (pixel size, nozzle, waveform, ink, frame list)
and images in any format of the reader registry (:mod:`dropvision.readers`: PNG, TIFF, BMP,
PNM, JPEG, video). Delays come from the frames list, the file names or TIFF metadata, or, for
high-speed recordings (a video, a numbered image stack, a multi-page TIFF), from
``frame_rate_hz``.
:func:`open_sequence` reads and validates the metadata and decodes the first frame only (to
learn the image size); :class:`Sequence` then decodes one frame at a time, in ascending delay
order, returned as 2-D grey in the canonical orientation (nozzle at the top, drops travelling
down the image).

The writers of the same format are in :mod:`dropvision.writers`.
"""

from __future__ import annotations

import math
import os
import posixpath
import re
import threading
import warnings
from collections import Counter, OrderedDict
import dataclasses
from dataclasses import asdict, dataclass, field
from pathlib import Path, PurePath
from typing import Iterator

import cv2
import numpy as np

from dropvision.readers import (
    IMAGE_SUFFIXES, VIDEO_SUFFIXES, ImageInfo, InvalidImage, OpenImage, Reader, UnreadableImage,
    reader_for,
)
from dropvision.readers.base import ColourLuma, is_number
from dvcore.jsonio import load_json_hardened
from dvcore.schema import RANGES
from identify.waveform import DEAD_TIME_US, HOLD_PRESET_US, U3_PRESET_UM_PER_MS, Waveform

__all__ = [
    "SCHEMA", "SEQUENCE_JSON", "ORIENTATIONS", "SequenceError", "RGBConvertedWarning",
    "FrameRef", "SequenceMeta", "Frame", "Sequence", "open_sequence", "parse_delay_from_name",
    "to_canonical", "from_canonical", "original_to_canonical", "canonical_to_original",
    "OVERRIDE_KEYS", "check_overrides",
]

#: Value of the ``schema`` key of sequence.json (written by ``dropvision.writers``).
SCHEMA = "dropvision.sequence/1"
#: File name of the metadata file in a sequence folder.
SEQUENCE_JSON = "sequence.json"
#: Allowed values of ``orientation``: the direction the drops travel in the stored image.
ORIENTATIONS = ("down", "up", "left", "right")
#: ``np.rot90`` turns (counter-clockwise quarter turns) taking a stored image to canonical.
_ROT90_K = {"down": 0, "up": 2, "left": 1, "right": 3}
#: Keys of sequence.json with a meaning; everything else goes to ``SequenceMeta.extra``.
_KNOWN_KEYS = frozenset({
    "schema", "pixel_size_um", "nozzle_inner_diameter_um", "nozzle_outer_diameter_um",
    "nozzle_tip_row", "axis_col", "orientation", "waveform", "ink", "frames", "bit_depth",
    "video", "frame_rate_hz", "first_frame_delay_us", "trigger_frame",
})
#: Keys of sequence.json that options may give or override (`open_sequence` ``overrides``):
#: the same validation and ranges apply. ``delay_us`` is the delay of a sequence of one frame.
OVERRIDE_KEYS = (
    "pixel_size_um", "nozzle_outer_diameter_um", "nozzle_inner_diameter_um", "orientation",
    "delay_us", "frame_rate_hz", "first_frame_delay_us", "trigger_frame", "waveform",
    "bit_depth", "nozzle_tip_row", "axis_col", "ink",
)
#: Delay in a file name: the last number immediately followed by "us" (or "µs").
_DELAY_RE = re.compile(r"(?<![\d.])(\d+(?:\.\d+)?)(?:us|µs|μs)(?![a-z])", re.IGNORECASE)
#: Open multi-frame files (e.g. TIFF stacks) kept by a Sequence.
_OPEN_CACHE_SIZE = 4


class SequenceError(Exception):
    """Invalid sequence: the one-line message names the file and the problem."""


class RGBConvertedWarning(UserWarning):
    """Colour images were converted to grey by ITU-R BT.601 luminance; issued once per
    :class:`Sequence`, at the first colour frame read (the message names that file)."""


@dataclass(frozen=True)
class FrameRef:
    """One frame of a sequence (metadata only).

    Attributes
    ----------
    index : int
        Position in processing (ascending delay) order, 0..n-1.
    file : str
        Path relative to the sequence folder ('/'-separated).
    page : int or None
        Page of a multi-page TIFF, else None.
    delay_us : float
        Strobe delay after the firing trigger (µs).
    repeat : int
        0 for the first frame at this delay, 1 for the next, ...
    listed_index : int
        Position in the listed order (sequence.json ``frames``, else natural file-name order
        then page).
    """

    index: int
    file: str
    page: int | None
    delay_us: float
    repeat: int
    listed_index: int = -1


@dataclass(frozen=True)
class SequenceMeta:
    """Validated metadata of a sequence (see docs/FORMAT.md).

    ``nozzle_tip_row`` and ``axis_col`` are in the CANONICAL frame (drops travel down);
    ``shape`` is the canonical (rows, cols) of every frame; ``frames`` is in processing order.
    """

    path: Path
    pixel_size_um: float
    nozzle_inner_diameter_um: float | None
    nozzle_outer_diameter_um: float | None
    nozzle_tip_row: float | None
    axis_col: float | None
    orientation: str
    waveform: dict | None
    ink: dict | None
    frames: tuple[FrameRef, ...]
    shape: tuple[int, int]
    bit_depth: int
    reordered: bool
    extra: dict = field(default_factory=dict)
    #: Where the pixel size came from: "sequence.json", "ome" or "imagej" (TIFF metadata),
    #: "arguments" (frames in memory), an option (e.g. "command line --pixel-size-um") or
    #: the nozzle ("nozzle outer diameter 360 µm / 76.1 px measured (...)").
    pixel_size_source: str = "sequence.json"
    #: Where each value came from, for summary.json's ``*_source`` keys: ``pixel_size``,
    #: ``orientation`` ("sequence.json", an option, "detected: ..." or "default ..."),
    #: ``nozzle_outer_diameter``, ``nozzle_inner_diameter``, ``delay``, ``waveform``,
    #: ``bit_depth`` (None: not given).
    sources: dict = field(default_factory=dict)

    @property
    def delays_us(self) -> np.ndarray:
        """Delays of the frames in processing order (µs)."""
        return np.array([f.delay_us for f in self.frames], dtype=float)

    def to_dict(self) -> dict:
        """JSON-ready dict (frames as a list of dicts, path as a string)."""
        out = asdict(self)
        out["path"] = str(self.path)
        out["shape"] = list(self.shape)
        out["frames"] = [asdict(f) for f in self.frames]
        return out


@dataclass
class Frame:
    """A decoded frame: ``image`` (2-D, canonical orientation, uint8/uint16) or ``error``."""

    ref: FrameRef
    image: np.ndarray | None
    error: str | None = None


# ----------------------------------------------------------------------------------------
# Orientation
# ----------------------------------------------------------------------------------------

def _check_orientation(orientation: str) -> str:
    if orientation not in _ROT90_K:
        raise ValueError(f"orientation must be one of {ORIENTATIONS}, got {orientation!r}")
    return orientation


def to_canonical(image: np.ndarray, orientation: str) -> np.ndarray:
    """Rotate a stored image into the canonical frame (drops travel down the image).

    ``down``: unchanged; ``up``: rotated 180°; ``left``: rotated 90° counter-clockwise
    (``np.rot90(image, 1)``); ``right``: rotated 90° clockwise (``np.rot90(image, -1)``).
    Only rotations are used (never mirror images), so left/right handedness is preserved.
    The result is C-contiguous.
    """
    k = _ROT90_K[_check_orientation(orientation)]
    if k == 0:
        return image
    return np.ascontiguousarray(np.rot90(image, k))


def from_canonical(image: np.ndarray, orientation: str) -> np.ndarray:
    """Inverse of :func:`to_canonical`: canonical image -> image as stored for ``orientation``."""
    k = _ROT90_K[_check_orientation(orientation)]
    if k == 0:
        return image
    return np.ascontiguousarray(np.rot90(image, -k))


def _flip(v, n):
    """Mirror a pixel coordinate (pixel centres are integers) in an axis of ``n`` pixels."""
    return None if v is None else (n - 1) - v


def original_to_canonical(row, col, orientation: str, original_shape) -> tuple:
    """Map a (row, col) point of the stored image into the canonical frame.

    Pixel centres are integers. With the stored image of shape (H, W):
    down ``(r, c)``; up ``(H-1-r, W-1-c)``; left ``(W-1-c, r)``; right ``(c, H-1-r)``.
    Either coordinate may be None; the canonical coordinate that depends on it is then None.
    """
    h, w = int(original_shape[0]), int(original_shape[1])
    o = _check_orientation(orientation)

    if o == "down":
        return row, col
    if o == "up":
        return _flip(row, h), _flip(col, w)
    if o == "left":
        return _flip(col, w), row
    return col, _flip(row, h)  # right


def canonical_to_original(row, col, orientation: str, canonical_shape) -> tuple:
    """Inverse of :func:`original_to_canonical`, given the CANONICAL image shape (Hc, Wc).

    down ``(R, C)``; up ``(Hc-1-R, Wc-1-C)``; left ``(C, Hc-1-R)``; right ``(Wc-1-C, R)``.
    """
    hc, wc = int(canonical_shape[0]), int(canonical_shape[1])
    o = _check_orientation(orientation)

    if o == "down":
        return row, col
    if o == "up":
        return _flip(row, hc), _flip(col, wc)
    if o == "left":
        return col, _flip(row, hc)
    return _flip(col, wc), row  # right


# ----------------------------------------------------------------------------------------
# Small parsers
# ----------------------------------------------------------------------------------------

def parse_delay_from_name(name: str) -> float | None:
    """Delay (µs) in a file name: the last number immediately followed by ``us``.

    ``f_0003_01150us.png`` -> 1150.0, ``d01150us.tif`` -> 1150.0, ``x_12.5us.png`` -> 12.5;
    None when there is none. Only the final path component (without suffix) is looked at.
    """
    stem = posixpath.basename(str(name).replace("\\", "/"))
    for suffix in IMAGE_SUFFIXES:
        if stem.lower().endswith(suffix):
            stem = stem[: -len(suffix)]
            break
    found = _DELAY_RE.findall(stem)
    return float(found[-1]) if found else None


def _natural_key(name: str):
    return [(0, int(t), "") if t.isdigit() else (1, 0, t.lower())
            for t in re.split(r"(\d+)", name) if t]


def _finite_or_none(value, what: str, where: str) -> float | None:
    if value is None:
        return None
    try:
        ok = is_number(value) and math.isfinite(float(value))
    except OverflowError:
        ok = False
    if not ok:
        raise SequenceError(f"{where}: {what} must be a finite number or null, got {value!r}")
    return float(value)


def _ranged(value, key: str, what: str, where: str, *, positive: bool = True) -> float | None:
    """A number of sequence.json within ``RANGES[key]`` (None stays None)."""
    if value is None:
        return None
    if not is_number(value):
        raise SequenceError(f"{where}: {what} must be a number"
                            f"{' > 0' if positive else ''}, got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        v = math.inf if value > 0 else -math.inf
    if positive and not v > 0:
        raise SequenceError(f"{where}: {what} must be a number > 0, got {value!r}")
    lo, hi, unit = RANGES[key]
    if not (math.isfinite(v) and lo <= v <= hi):
        shown = f"{v:g}" if math.isfinite(v) else "a number too large to use"
        raise SequenceError(f"{where}: {what} {shown} is outside the accepted range "
                            f"{lo:g}..{hi:g} {unit}")
    return v


def _check_in_image(tip_row, axis_col, original_shape, where: str) -> None:
    """nozzle_tip_row / axis_col (stored image) must lie on the stored image."""
    h, w = int(original_shape[0]), int(original_shape[1])
    for key, value, n, axis in (("nozzle_tip_row", tip_row, h, "rows"),
                                ("axis_col", axis_col, w, "columns")):
        if value is not None and not -0.5 <= value <= n - 0.5:
            raise SequenceError(f"{where}: {key} {value:g} is outside the stored image "
                                f"({axis} -0.5..{n - 0.5:g} of a {w}x{h} (WxH) image)")


def _delay_value(value, what: str) -> float:
    """A delay from sequence.json: a finite number, or a string like "1150" or "1150us"."""
    out = None
    if is_number(value):
        out = float(value)
    elif isinstance(value, str):
        text = value.strip()
        try:
            out = float(text)
        except ValueError:
            m = re.fullmatch(r"([-+]?\d+(?:\.\d+)?)\s*(?:us|µs|μs)", text, re.IGNORECASE)
            out = float(m.group(1)) if m else None
    if out is None or not math.isfinite(out):
        raise SequenceError(f"{what}: unparsable delay_us {value!r} (expected a number of µs)")
    lo, hi, unit = RANGES["delay_us"]
    if not lo <= out <= hi:
        raise SequenceError(f"{what}: delay_us {out:g} is outside the accepted range "
                            f"{lo:g}..{hi:g} {unit}")
    return out


def _safe_relpath(file, where: str) -> str:
    """Normalise a frames ``file`` entry; reject absolute paths and escapes from the folder."""
    if not isinstance(file, str) or not file.strip():
        raise SequenceError(f"{where}: 'file' must be a non-empty string, got {file!r}")
    if "\x00" in file:
        raise SequenceError(f"{where}: file {file!r} contains a NUL character")
    rel = file.strip().replace("\\", "/")
    norm = posixpath.normpath(rel)
    if (rel.startswith("/") or re.match(r"^[A-Za-z]:", rel) or norm == ".."
            or norm.startswith("../") or norm == "."):
        raise SequenceError(f"{where}: file {file!r} is outside the sequence folder")
    return norm


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

    def _decode(self, ref: FrameRef, *, warn: bool) -> np.ndarray:
        path = self.meta.path / ref.file
        if ref.file in self._refused:
            raise UnreadableImage(self._refused[ref.file])
        try:
            size = path.stat().st_size
        except FileNotFoundError:
            raise SequenceError(f"{path}: image file is missing") from None
        except (OSError, ValueError) as exc:
            raise UnreadableImage(f"cannot access file ({getattr(exc, 'strerror', None) or exc})"
                                  ) from None
        if size == 0:
            raise UnreadableImage("zero-byte file")
        reader = reader_for(path)
        try:
            img = self._decode_native(reader, path, ref)
        except InvalidImage as exc:
            raise SequenceError(str(exc)) from None
        as_grey = isinstance(img, ColourLuma)  # the reader applied the grey rule itself
        if as_grey:
            img = img.view(np.ndarray)
        if warn and ((img.ndim == 3 and img.shape[2] > 1) or as_grey):
            with self._lock:  # one note per sequence, however many colour frames follow
                warn, self._colour_noted = not self._colour_noted, True
        else:
            warn = False
        if as_grey and warn:
            _note_colour(_where(ref), 3)
        img = _to_grey(img, _where(ref), reader.bgr, warn and not as_grey)
        if img.dtype not in (np.uint8, np.uint16):
            raise SequenceError(f"{path}{_page_txt(ref)}: unsupported pixel type {img.dtype} "
                                "(8-bit or 16-bit unsigned grey images are read)")
        return to_canonical(img, self.meta.orientation)

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
# open_sequence
# ----------------------------------------------------------------------------------------

@dataclass
class _Listed:
    file: str
    page: int | None
    delay_us: float


def _outside(folder_real: str, path: Path) -> str | None:
    """Where ``path`` resolves (symbolic links followed) when that is outside the folder
    ``folder_real`` (already resolved), else None."""
    try:
        real = os.path.realpath(path)
    except (OSError, ValueError):
        return None  # reported when the file is accessed
    if real == folder_real or real.startswith(folder_real.rstrip(os.sep) + os.sep):
        return None
    return real


def _refusal(target: str) -> str:
    return (f"symbolic link resolves outside the sequence folder (to {target}); refused "
            "(open_sequence(..., allow_outside_links=True) allows it)")


def _probe(reader: Reader, path: Path) -> ImageInfo:
    """Pages and stored delays of an image file; an unreadable file counts as one frame
    without stored delays (it is reported when read)."""
    try:
        return reader.probe(path)
    except Exception:
        return ImageInfo()


def _delays_of_file(folder: Path, rel: str, refused: dict, lone_ok: bool = False
                    ) -> list[tuple[int | None, float | None]]:
    """(page, delay) pairs of one image file of a folder without a frames list; with
    ``lone_ok`` (the folder's only image) a single frame without a delay gets None."""
    path = folder / rel
    if rel in refused:  # a link outside the folder: never opened, listed to be reported
        from_name = parse_delay_from_name(rel)
        if from_name is None and not lone_ok:
            raise SequenceError(f"{path}: {refused[rel]}")
        return [(None, from_name)]
    info = _probe(reader_for(path), path)
    n_pages, page_delays = info.n_pages, info.page_delays
    cut = "" if info.complete else " (the file is cut short or corrupt)"
    # a cut page chain: pages whose delays the file's metadata (OME) lists are still listed,
    # and reported as unreadable when read
    n_total = n_pages if info.complete else max(n_pages, max(
        (k + 1 for k in page_delays if isinstance(k, int)), default=0))
    if n_total > 1:
        missing = [i for i in range(n_total) if i not in page_delays]
        if missing:
            raise SequenceError(
                f"{path}: multi-frame file without a delay for page {missing[0]}{cut} (give "
                "frame_rate_hz in sequence.json, OME Plane DeltaT, per-page JSON descriptions "
                "{\"delay_us\": ...} or a sequence.json frames list)")
        return [(i, _delay_value(page_delays[i], f"{path} page {i}"))
                for i in range(n_total)]
    from_name = parse_delay_from_name(rel)
    if from_name is not None:
        return [(None, from_name)]
    if 0 in page_delays:
        return [(None, _delay_value(page_delays[0], str(path)))]
    if lone_ok:
        return [(None, None)]
    raise SequenceError(f"{path}: no delay in the file name (expected e.g. "
                        f"'frame_01150us.png'){cut} and no frames list in sequence.json")


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):
        return True  # listed; the problem is reported when the frame is read


def _frame_rate(doc: dict, where: str) -> tuple[float, float, int] | None:
    """(frame_rate_hz, first_frame_delay_us, trigger_frame) of a high-speed recording, or None
    when sequence.json gives no ``frame_rate_hz``."""
    fps = doc.get("frame_rate_hz")
    if fps is None:
        for key in ("video", "first_frame_delay_us", "trigger_frame"):
            if doc.get(key) is not None:
                raise SequenceError(f"{where}: {key} given without frame_rate_hz (the frame "
                                    "rate of the recording in Hz gives the frames' delays)")
        return None
    if doc.get("frames") is not None:
        raise SequenceError(f"{where}: give either frame_rate_hz (delays from the frame rate) "
                            "or a frames list (delays per frame), not both")
    fps = _ranged(fps, "frame_rate_hz", "frame_rate_hz", where)
    first = doc.get("first_frame_delay_us")
    first = 0.0 if first is None else _finite_or_none(first, "first_frame_delay_us", where)
    lo, hi, unit = RANGES["delay_us"]
    if not lo <= first <= hi:
        raise SequenceError(f"{where}: first_frame_delay_us {first:g} is outside the accepted "
                            f"range {lo:g}..{hi:g} {unit}")
    trigger = doc.get("trigger_frame")
    trigger = 0 if trigger is None else trigger
    if not isinstance(trigger, int) or isinstance(trigger, bool) or abs(trigger) > 10 ** 9:
        raise SequenceError(f"{where}: trigger_frame must be an integer frame index "
                            f"(-1e9..1e9), got {doc.get('trigger_frame')!r}")
    return fps, first, trigger


def _scan_folder(folder: Path, folder_real: str, refused: dict, allow_outside: bool,
                 only: frozenset | None = None) -> list[str]:
    """Image files of a folder (natural order), links outside the folder noted in refused;
    with ``only``, those among these names alone."""
    try:
        entries = list(folder.iterdir())
    except OSError as exc:
        raise SequenceError(f"{folder}: cannot list the folder ({exc.strerror or exc})") from None
    names = []
    for p in entries:
        if (p.suffix.lower() not in IMAGE_SUFFIXES or p.name.startswith(".")
                or p.name.lower().startswith("truth") or (only is not None and p.name not in only)):
            continue
        target = None if allow_outside else _outside(folder_real, p)
        if target is not None:
            refused[p.name] = _refusal(target)
        elif not _is_file(p):
            continue
        names.append(p.name)
    names.sort(key=_natural_key)
    if not names:
        raise SequenceError(f"{folder}: no image files ({', '.join(IMAGE_SUFFIXES)}) "
                            "and no frames list")
    return names


def _listed_from_folder(folder: Path, folder_real: str, refused: dict,
                        allow_outside: bool, lone_ok: bool = False, only: frozenset | None = None
                        ) -> list[_Listed]:
    """Frames of a folder without a frames list; with ``lone_ok`` a folder of one single-frame
    image without a delay lists it with delay None (the caller gives it one)."""
    names = _scan_folder(folder, folder_real, refused, allow_outside, only)
    lone_ok = lone_ok and len(names) == 1
    return [_Listed(name, page, delay) for name in names
            for page, delay in _delays_of_file(folder, name, refused, lone_ok)]


def _listed_from_rate(folder: Path, video, rate: tuple[float, float, int], json_path: Path,
                      folder_real: str, refused: dict, allow_outside: bool,
                      only: frozenset | None = None) -> list[_Listed]:
    """Frames of a high-speed recording: the ``video`` file, else every image file of the
    folder in natural name order (each page of a multi-page file in turn); frame i (0-based,
    in that order) gets delay ``first_frame_delay_us + (i - trigger_frame) * 1e6 /
    frame_rate_hz``."""
    fps, first, trigger = rate
    where = str(json_path)
    if video is not None:
        rel = _safe_relpath(video, f"{where} video")
        path = folder / rel
        if reader_for(path) is None:
            raise SequenceError(f"{path}: unsupported image type (use "
                                f"{', '.join(IMAGE_SUFFIXES)})")
        target = None if allow_outside else _outside(folder_real, path)
        if target is not None:
            raise SequenceError(f"{path}: {_refusal(target)}")
        if not _is_file(path):
            raise SequenceError(f"{path}: named by 'video' in sequence.json but missing")
        names = [rel]
    else:
        names = _scan_folder(folder, folder_real, refused, allow_outside, only)
        videos = [n for n in names if PurePath(n).suffix.lower() in VIDEO_SUFFIXES]
        if videos and len(names) > 1:
            raise SequenceError(f"{folder}: {len(names)} files ({', '.join(names[:4])}"
                                f"{', ...' if len(names) > 4 else ''}) besides a video: name "
                                "the recording with \"video\" in sequence.json")
    pages: list[tuple[str, int | None]] = []
    for rel in names:
        path = folder / rel
        if rel in refused:
            pages.append((rel, None))
            continue
        reader = reader_for(path)
        try:
            n_pages = reader.probe(path).n_pages
        except Exception as exc:
            if PurePath(rel).suffix.lower() in VIDEO_SUFFIXES:
                raise SequenceError(f"{path}: {exc}") from None
            n_pages = 1  # reported as unreadable when read
        pages.extend((rel, i if n_pages > 1 else None)
                     for i in range(n_pages))
    lo, hi, unit = RANGES["delay_us"]
    out = []
    for i, (rel, page) in enumerate(pages):
        delay = first + (i - trigger) * 1e6 / fps
        if not lo <= delay <= hi:
            raise SequenceError(f"{where}: frame {i} ({rel}{'' if page is None else f' page {page}'}) "
                                f"gets delay {delay:g} µs from frame_rate_hz {fps:g}, "
                                f"first_frame_delay_us {first:g} and trigger_frame {trigger}, "
                                f"outside the accepted range {lo:g}..{hi:g} {unit}")
        out.append(_Listed(rel, page, delay))
    return out


def _listed_from_frames(folder: Path, frames, json_path: Path, folder_real: str,
                        refused: dict, allow_outside: bool, only: frozenset | None = None
                        ) -> list[_Listed]:
    if not isinstance(frames, list) or not frames:
        raise SequenceError(f"{json_path}: 'frames' must be a non-empty list")
    out, seen, stored_delays = [], set(), {}
    for i, entry in enumerate(frames):
        where = f"{json_path} frames[{i}]"
        if not isinstance(entry, dict):
            raise SequenceError(f"{where}: must be an object with 'file' and 'delay_us'")
        rel = _safe_relpath(entry.get("file"), where)
        if only is not None and rel not in only:  # not (yet) complete: left out
            continue
        path = folder / rel
        where = f"{path}"
        reader = reader_for(path)
        if reader is None:
            raise SequenceError(f"{where}: unsupported image type (use {', '.join(IMAGE_SUFFIXES)})")
        target = None if allow_outside else _outside(folder_real, path)
        if target is not None:
            refused[rel] = _refusal(target)
        else:
            try:
                present = path.is_file()
            except (OSError, ValueError) as exc:
                raise SequenceError(f"{where}: listed in sequence.json frames[{i}] but cannot "
                                    f"be accessed ({getattr(exc, 'strerror', None) or exc})"
                                    ) from None
            if not present:
                raise SequenceError(f"{where}: listed in sequence.json frames[{i}] but missing")
        page = entry.get("page")
        if page is not None:
            if not isinstance(page, int) or isinstance(page, bool) or page < 0:
                raise SequenceError(f"{where}: 'page' must be an integer >= 0, got {page!r}")
            if not reader.paged:
                raise SequenceError(f"{where}: 'page' given but the file is not a TIFF or "
                                    "video (a file of several frames)")
        if (rel, page) in seen:
            raise SequenceError(f"{where}{'' if page is None else f' page {page}'}: listed "
                                "twice in sequence.json frames")
        seen.add((rel, page))
        if entry.get("delay_us") is not None:
            delay = _delay_value(entry["delay_us"], where)
        else:
            delay = parse_delay_from_name(rel)
            if delay is None and rel in refused:
                raise SequenceError(f"{where}: {refused[rel]}; frames[{i}] needs a delay_us")
            if delay is None:
                if rel not in stored_delays:
                    stored_delays[rel] = _probe(reader, path).page_delays
                d = stored_delays[rel].get(0 if page is None else page)
                delay = None if d is None else _delay_value(d, where)
            if delay is None:
                raise SequenceError(f"{where}: frames[{i}] has no delay_us and none can be "
                                    "parsed from the file name or TIFF page")
        out.append(_Listed(rel, page, delay))
    return out


def _validate_waveform(value, where: str) -> dict | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise SequenceError(f"{where}: 'waveform' must be an object")
    out = dict(value)
    out.setdefault("u3_um_per_ms", U3_PRESET_UM_PER_MS)
    out.setdefault("hold_us", HOLD_PRESET_US)
    out.setdefault("dead_time_us", DEAD_TIME_US)
    for key in ("u1_um_per_ms", "u2_um", "u3_um_per_ms", "hold_us", "dead_time_us"):
        if key not in out or not is_number(out[key]):
            raise SequenceError(f"{where}: waveform {key} must be a number, got {out.get(key)!r}")
        if key in ("hold_us", "dead_time_us") and out[key] < 0:
            raise SequenceError(f"{where}: waveform {key} must be >= 0, got {out[key]!r}")
        out[key] = _ranged(out[key], key, f"waveform {key}", where,
                           positive=key not in ("hold_us", "dead_time_us"))
    try:
        Waveform(out["u1_um_per_ms"], out["u2_um"], out["u3_um_per_ms"], out["hold_us"])
    except ValueError as exc:
        raise SequenceError(f"{where}: {exc}") from None
    if out["dead_time_us"] < 0:
        raise SequenceError(f"{where}: waveform dead_time_us must be >= 0")
    return out


def _validate_ink(value, where: str) -> dict | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise SequenceError(f"{where}: 'ink' must be an object")
    out = dict(value)
    for key in ("density_kg_m3", "viscosity_mPa_s", "surface_tension_mN_m"):
        if key in out:
            out[key] = _ranged(out[key], key, f"ink {key}", where)
    return out


def _diameters(d_in, d_out, where: str) -> tuple[float | None, float | None]:
    d_in = _ranged(d_in, "nozzle_diameter_um", "nozzle_inner_diameter_um", where)
    d_out = _ranged(d_out, "nozzle_diameter_um", "nozzle_outer_diameter_um", where)
    if d_in is not None and d_out is not None and not d_out > d_in:
        raise SequenceError(f"{where}: nozzle_outer_diameter_um {d_out:g} must be larger than "
                            f"nozzle_inner_diameter_um {d_in:g}")
    return d_in, d_out


def check_overrides(overrides, labels=None) -> dict:
    """Validate values given for sequence.json keys outside the file (options, arguments).

    The same checks and ranges as the file's keys (docs/FORMAT.md, ``RANGES``); a bad value
    is a :class:`SequenceError` naming the option.

    Parameters
    ----------
    overrides : dict
        sequence.json key (one of ``OVERRIDE_KEYS``) -> value; None values are dropped.
        ``waveform`` may be partial (its keys replace those of the file's waveform).
    labels : dict, optional
        key -> how the user gave it, for messages and sources (default ``"argument <key>"``).

    Returns
    -------
    dict
        The given keys with validated values (orientation lower-case).
    """
    labels = labels or {}
    out = {}
    for key, value in (overrides or {}).items():
        if value is None:
            continue
        where = labels.get(key, f"argument {key}")
        if key not in OVERRIDE_KEYS:
            raise SequenceError(f"{where}: {key} cannot be given as an option (one of {', '.join(OVERRIDE_KEYS)})")
        if key == "pixel_size_um":
            value = _ranged(value, key, key, where)
        elif key in ("nozzle_outer_diameter_um", "nozzle_inner_diameter_um"):
            value = _ranged(value, "nozzle_diameter_um", key, where)
        elif key == "frame_rate_hz":
            value = _ranged(value, key, key, where)
        elif key in ("delay_us", "first_frame_delay_us"):
            value = _delay_value(value, where)
        elif key == "orientation":
            value = value.strip().lower() if isinstance(value, str) else value
            if value not in ORIENTATIONS:
                raise SequenceError(f"{where}: orientation must be one of {ORIENTATIONS}, got {value!r}")
        elif key == "bit_depth":
            if not is_number(value) or value not in (8, 12, 16):
                raise SequenceError(f"{where}: bit_depth must be 8, 12 or 16, got {value!r}")
            value = int(value)
        elif key in ("nozzle_tip_row", "axis_col"):
            value = _finite_or_none(value, key, where)
        elif key == "trigger_frame":
            if not isinstance(value, int) or isinstance(value, bool):
                raise SequenceError(f"{where}: trigger_frame must be an integer frame index, got {value!r}")
        elif key in ("waveform", "ink") and not isinstance(value, dict):
            raise SequenceError(f"{where}: {key} must be an object (a dict)")
        elif key == "ink":
            value = _validate_ink(value, where)
        out[key] = value
    d_in, d_out = out.get("nozzle_inner_diameter_um"), out.get("nozzle_outer_diameter_um")
    if d_in is not None and d_out is not None:
        _diameters(d_in, d_out, labels.get("nozzle_outer_diameter_um", "arguments"))
    return out


def _merge_overrides(doc: dict | None, given: dict, labels: dict, json_path: Path
                     ) -> tuple[dict | None, dict]:
    """sequence.json merged with validated options; returns (doc, key -> where) where
    ``where`` names the option for overridden keys and the file for the others."""
    wheres = {}
    if not given:
        return doc, wheres
    merged = dict(doc or {})
    for key, value in given.items():
        where = labels.get(key, f"argument {key}")
        wheres[key] = where
        if key == "waveform" and isinstance(merged.get("waveform"), dict):
            value = {**merged["waveform"], **value}
        if key == "frame_rate_hz" and merged.get("frames") is not None:
            raise SequenceError(f"{where}: {json_path} has a frames list (delays per frame); "
                                "frame_rate_hz gives the delays of a recording instead: not both")
        if key == "delay_us":
            continue  # applied to the listed frame (one frame only)
        merged[key] = value
    if "waveform" in given:
        _validate_waveform(merged["waveform"], wheres["waveform"])
    return merged, wheres


def open_sequence(path, *, allow_outside_links: bool = False, overrides: dict | None = None,
                  labels: dict | None = None, ignore_sequence_json: bool = False,
                  require_pixel_size: bool = True, only_files=None) -> Sequence:
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
        over the sequence (`dropvision.inspection.nozzle_outer_width_px`).
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
    frame (`dropvision.inspection.detect_orientation`); a frame that does not tell keeps
    ``"down"``, and ``sources["orientation"]`` says what was seen at each edge. A folder of
    ONE image without a delay in its name or metadata gets ``delay_us`` (option) or 0 µs,
    stated in ``sources["delay"]``.
    """
    labels = dict(labels or {})
    given = check_overrides(overrides, labels)
    folder = Path(path)
    if folder.name == SEQUENCE_JSON and folder.is_file():
        folder = folder.parent
    folder = folder.absolute()
    if not folder.exists():
        raise SequenceError(f"{folder}: sequence folder does not exist")
    if not folder.is_dir():
        raise SequenceError(f"{folder}: not a folder (a sequence is a folder with sequence.json "
                            "and images)")
    json_path = folder / SEQUENCE_JSON
    folder_real = os.path.realpath(folder)
    refused: dict[str, str] = {}
    json_exists = not ignore_sequence_json and _is_file(json_path)
    if json_exists and not allow_outside_links:
        target = _outside(folder_real, json_path)
        if target is not None:
            raise SequenceError(f"{json_path}: {_refusal(target)}")
    file_doc = load_json_hardened(json_path, SequenceError) if json_exists else None
    doc, wheres = _merge_overrides(file_doc, given, labels, json_path)
    sources = {"pixel_size": None, "orientation": None, "nozzle_outer_diameter": None,
               "nozzle_inner_diameter": None, "delay": None, "waveform": None, "bit_depth": None}

    def where_of(*keys: str) -> str:
        return next((wheres[k] for k in keys if k in wheres), str(json_path))

    def source_of(key: str) -> str | None:
        if key in wheres:
            return wheres[key]
        return SEQUENCE_JSON if file_doc is not None and file_doc.get(key) is not None else None

    orientation_given = doc is not None and doc.get("orientation") is not None
    if doc is not None:
        schema = doc.get("schema")
        schema = SCHEMA if schema is None else schema  # null means absent
        if schema != SCHEMA:
            raise SequenceError(f"{json_path}: unsupported schema {schema!r} (expected {SCHEMA!r})")
        orientation = doc.get("orientation")
        orientation = "down" if orientation is None else orientation  # null means absent
        orientation = orientation.strip().lower() if isinstance(orientation, str) else orientation
        if orientation not in ORIENTATIONS:
            raise SequenceError(f"{where_of('orientation')}: orientation must be one of {ORIENTATIONS}, "
                                f"got {doc.get('orientation')!r}")
        bit_depth_key = doc.get("bit_depth")
        if bit_depth_key is not None and (not is_number(bit_depth_key)
                                          or bit_depth_key not in (8, 12, 16)):
            raise SequenceError(f"{json_path}: bit_depth must be 8, 12 or 16, got {bit_depth_key!r}")
        d_in, d_out = _diameters(doc.get("nozzle_inner_diameter_um"), doc.get("nozzle_outer_diameter_um"),
                                 where_of("nozzle_outer_diameter_um", "nozzle_inner_diameter_um"))
        tip_row = _finite_or_none(doc.get("nozzle_tip_row"), "nozzle_tip_row", where_of("nozzle_tip_row"))
        axis_col = _finite_or_none(doc.get("axis_col"), "axis_col", where_of("axis_col"))
        waveform = _validate_waveform(doc.get("waveform"), where_of("waveform"))
        ink = _validate_ink(doc.get("ink"), where_of("ink"))
        extra = {k: v for k, v in doc.items() if k not in _KNOWN_KEYS}
    else:
        orientation, bit_depth_key, d_in, d_out = "down", None, None, None
        tip_row = axis_col = waveform = ink = None
        extra = {}
    sources.update(orientation=source_of("orientation"),
                   nozzle_outer_diameter=source_of("nozzle_outer_diameter_um"),
                   nozzle_inner_diameter=source_of("nozzle_inner_diameter_um"),
                   waveform=source_of("waveform"), bit_depth=source_of("bit_depth"))

    only = None if only_files is None else frozenset(str(f) for f in only_files)
    rate = _frame_rate(doc, where_of("frame_rate_hz")) if doc is not None else None
    if rate is not None:
        listed = _listed_from_rate(folder, doc.get("video"), rate, json_path, folder_real,
                                   refused, allow_outside_links, only)
        sources["delay"] = f"frame_rate_hz ({source_of('frame_rate_hz')})"
    elif doc is not None and doc.get("frames") is not None:
        listed = _listed_from_frames(folder, doc["frames"], json_path, folder_real, refused,
                                     allow_outside_links, only)
        sources["delay"] = "sequence.json frames (or the file names they list)"
    else:
        listed = _listed_from_folder(folder, folder_real, refused, allow_outside_links,
                                     lone_ok=True, only=only)
        sources["delay"] = "file names or image metadata"
    if "delay_us" in given:
        if len(listed) != 1:
            raise SequenceError(f"{wheres['delay_us']}: the delay of a single frame, but {folder} has "
                                f"{len(listed)} frames (their delays come from the file names, a "
                                "frames list or frame_rate_hz)")
        listed[0].delay_us = given["delay_us"]
        sources["delay"] = wheres["delay_us"]
    elif listed and listed[0].delay_us is None:  # one frame, no delay anywhere
        listed[0].delay_us = 0.0
        sources["delay"] = ("assumed 0 us: one frame without a delay in its name or metadata "
                            "(give it with --delay-us or sequence.json frames)")

    # pixel size: option, sequence.json, else the metadata of the first listed file of a type
    # that may store it (scientific TIFF), else the nozzle's outer diameter (after the probe)
    pixel_size_um, source = None, "sequence.json"
    if doc is not None and doc.get("pixel_size_um") is not None:
        pixel_size_um = _ranged(doc["pixel_size_um"], "pixel_size_um", "pixel_size_um",
                                where_of("pixel_size_um"))
        source = wheres.get("pixel_size_um", "sequence.json")
    else:
        first_sized = next((item.file for item in listed if item.file not in refused
                            and reader_for(item.file).stores_pixel_size), None)
        if first_sized is not None:
            try:
                pixel_size_um, source = reader_for(first_sized).pixel_size(folder / first_sized)
            except InvalidImage as exc:
                raise SequenceError(str(exc)) from None
        if pixel_size_um is not None:
            pixel_size_um = _ranged(pixel_size_um, "pixel_size_um",
                                    f"pixel size from the {source} metadata",
                                    str(folder / first_sized))
        elif not require_pixel_size:
            pixel_size_um, source = math.nan, None
        elif d_out is None:
            hint = ("; give it with --pixel-size-um, or the nozzle's outer diameter with "
                    "--nozzle-outer-diameter-um (dropvision init writes a sequence.json)")
            if file_doc is None:
                raise SequenceError(f"{folder}: sequence.json (pixel_size_um) is missing and "
                                    f"the images carry no pixel size{hint}")
            raise SequenceError(f"{json_path}: pixel_size_um is missing (required: pixel size in "
                                f"µm, a number > 0){hint}")

    # processing order: ascending delay, stable (listed order, then page)
    order = sorted(range(len(listed)), key=lambda i: listed[i].delay_us)
    reordered = order != list(range(len(listed)))
    repeats: Counter = Counter()
    refs = []
    for index, i in enumerate(order):
        item = listed[i]
        key = round(item.delay_us, 6)
        refs.append(FrameRef(index, item.file, item.page, item.delay_us, repeats[key], i))
        repeats[key] += 1

    # probe: first readable frame (processing order) gives shape, type, bit depth; without a
    # given orientation it is probed as stored and the orientation is detected from it
    probe_meta = SequenceMeta(folder, pixel_size_um or 1.0, d_in, d_out, None, None,
                              orientation if orientation_given else "down",
                              waveform, ink, tuple(refs), (0, 0), 0, reordered, extra, source)
    probe = Sequence(probe_meta, np.uint8, refused)
    first_img, first_ref, first_error = None, None, None
    try:
        for ref in refs:
            try:
                first_img = probe._decode(ref, warn=False)
                first_ref = ref
                break
            except UnreadableImage as exc:
                first_error = first_error or f"{folder / ref.file}{_page_txt(ref)}: {exc}"
    finally:
        probe.close()
    if first_img is None:
        raise SequenceError(f"{folder}: no readable image among {len(refs)} frame(s) "
                            f"(first problem: {first_error})")
    if not orientation_given:
        from dropvision.inspection import detect_orientation  # cv2 work only when needed

        guess = detect_orientation(first_img)
        if guess.orientation is not None:
            orientation = guess.orientation
            sources["orientation"] = f"detected in {first_ref.file}: {guess.reason}"
        else:
            sources["orientation"] = (f"default (down): not detected in {first_ref.file}, {guess.reason}"
                                      + (f" ({guess.edges_text()})" if guess.edges else ""))
        first_img = to_canonical(first_img, orientation)
    canonical_shape = tuple(int(n) for n in first_img.shape)
    original_shape = (canonical_shape if _ROT90_K[orientation] % 2 == 0
                      else canonical_shape[::-1])

    first_path = folder / first_ref.file
    if first_img.dtype == np.uint8:
        if bit_depth_key not in (None, 8):
            raise SequenceError(f"{where_of('bit_depth')}: bit_depth {bit_depth_key} but {first_path} is 8-bit")
        bit_depth = 8
        sources["bit_depth"] = sources["bit_depth"] or "8-bit images"
    elif bit_depth_key is not None:
        bit_depth = int(bit_depth_key)
    else:
        hint = reader_for(first_path).significant_bits(first_path, first_ref.page)
        bit_depth = hint if hint is not None and 8 < hint <= 16 else 16
        bit_depth = 12 if 8 < bit_depth <= 12 else 16  # report 8, 12 or 16
        sources["bit_depth"] = ("significant bits in the image header" if hint is not None and 8 < hint <= 16
                                else "16-bit images")

    sources["pixel_size"] = source

    _check_in_image(tip_row, axis_col, original_shape, where_of("nozzle_tip_row", "axis_col"))
    tip_c, axis_c = original_to_canonical(tip_row, axis_col, orientation, original_shape)
    meta = SequenceMeta(folder, pixel_size_um, d_in, d_out,
                        None if tip_c is None else float(tip_c),
                        None if axis_c is None else float(axis_c),
                        orientation, waveform, ink, tuple(refs), canonical_shape, bit_depth,
                        reordered, extra, source, sources)
    seq = Sequence(meta, first_img.dtype, refused)
    if pixel_size_um is None:
        seq.meta = _pixel_size_from_nozzle(seq, first_img, first_ref, where_of("nozzle_outer_diameter_um"))
    return seq


#: Frames spread over a sequence in which the nozzle's outer width is measured.
_NOZZLE_FRAMES = 7


def _pixel_size_from_nozzle(seq: Sequence, first_img: np.ndarray, first_ref: FrameRef, where: str
                            ) -> SequenceMeta:
    """The metadata with the pixel size = nozzle_outer_diameter_um over the nozzle's outer width
    in px (median over up to 7 frames spread over the sequence)."""
    from dropvision.calibration import CalibrationError
    from dropvision.inspection import nozzle_outer_width_px

    meta = seq.meta
    n = len(meta.frames)
    images = [first_img]
    for i in np.unique(np.round(np.linspace(0, n - 1, min(n, _NOZZLE_FRAMES))).astype(int)):
        if int(i) != first_ref.index:
            fr = seq.read(int(i))
            if fr.image is not None:
                images.append(fr.image)
    seq.close()
    d_out = meta.nozzle_outer_diameter_um
    try:
        width_px, used = nozzle_outer_width_px(images, max_value=2 ** meta.bit_depth - 1)
    except CalibrationError as exc:
        raise SequenceError(f"{meta.path / first_ref.file}: no pixel size given, and the nozzle's outer width "
                            f"cannot be measured to take it from nozzle_outer_diameter_um ({exc})") from None
    pixel_size_um = _ranged(d_out / width_px, "pixel_size_um",
                            f"pixel size from nozzle_outer_diameter_um {d_out:g} µm over {width_px:.2f} px", where)
    source = (f"nozzle outer diameter {d_out:g} um / {width_px:.2f} px (median over {used} frame"
              f"{'s' if used != 1 else ''} from {first_ref.file}; diameter from "
              f"{meta.sources.get('nozzle_outer_diameter')})")
    return dataclasses.replace(meta, pixel_size_um=pixel_size_um, pixel_size_source=source,
                               sources={**meta.sources, "pixel_size": source})



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
        (`dropvision.inspection.detect_orientation`), ``"down"`` when it does not tell.
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
    pixel_size_um = _ranged(pixel_size_um, "pixel_size_um", "pixel_size_um", where)
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
    if orientation is None:
        from dropvision.inspection import detect_orientation  # cv2 work only when needed

        guess = detect_orientation(grey[order[0]])
        orientation = guess.orientation or "down"
        sources["orientation"] = (f"detected in frame {order[0]}: {guess.reason}" if guess.orientation else
                                  f"default (down): not detected in frame {order[0]}, {guess.reason}"
                                  + (f" ({guess.edges_text()})" if guess.edges else ""))
    repeats: Counter = Counter()
    refs, canonical = [], []
    for index, i in enumerate(order):
        key = round(float(delays[i]), 6)
        refs.append(FrameRef(index, f"frame_{i:05d}", None, float(delays[i]), repeats[key], i))
        repeats[key] += 1
        canonical.append(np.ascontiguousarray(to_canonical(grey[i], orientation)))
    tip_row = _finite_or_none(nozzle_tip_row, "nozzle_tip_row", where)
    axis_col = _finite_or_none(axis_col, "axis_col", where)
    _check_in_image(tip_row, axis_col, grey[0].shape, where)
    tip_c, axis_c = original_to_canonical(tip_row, axis_col, orientation, grey[0].shape)
    d_in, d_out = _diameters(nozzle_inner_diameter_um, nozzle_outer_diameter_um, where)
    meta = SequenceMeta(Path(where), pixel_size_um, d_in, d_out,
                        None if tip_c is None else float(tip_c), None if axis_c is None else float(axis_c),
                        orientation, _validate_waveform(waveform, where), _validate_ink(ink, where),
                        tuple(refs), tuple(int(n) for n in canonical[0].shape), int(bit_depth),
                        order != list(range(len(grey))), {}, "arguments", sources)
    return ArraySequence(meta, canonical)

"""Frame discovery: which files (and pages) of a sequence folder are its frames, and their delays.

The frames come from sequence.json's ``frames`` list (`list_from_frames`), from a video or a
numbered image stack at ``frame_rate_hz`` (`list_from_rate`), or from the image files of the
folder with the delay in their names or TIFF metadata (`list_from_folder`,
`parse_delay_from_name`).  Links leading out of the folder are refused unless allowed.
"""

from __future__ import annotations

import os
import posixpath
import re
import stat
from dataclasses import dataclass
from pathlib import Path, PurePath

from dvcore.schema import RANGES
from dropvision.io.overrides import delay_value, finite_or_none, ranged_value
from dropvision.io.readers import (
    IMAGE_SUFFIXES, VIDEO_SUFFIXES, ImageInfo, InvalidImage, OpenImage, Reader, UnreadableImage,
    reader_for,
)
from dropvision.io.sequence_meta import SequenceError


#: Delay in a file name: the last number immediately followed by "us" (or "µs").
_DELAY_RE = re.compile(r"(?<![\d.])(\d+(?:\.\d+)?)(?:us|µs|μs)(?![a-z])", re.IGNORECASE)


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


#: The natural name order of the frames of a folder (``f_2`` before ``f_10``).
natural_key = _natural_key


def safe_relpath(file, where: str) -> str:
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


@dataclass
class ListedFrame:
    file: str
    page: int | None
    delay_us: float


def outside_folder(folder_real: str, path: Path) -> str | None:
    """Where ``path`` resolves (symbolic links followed) when that is outside the folder
    ``folder_real`` (already resolved), else None."""
    try:
        real = os.path.realpath(path)
    except (OSError, ValueError):
        return None  # reported when the file is accessed
    if real == folder_real or real.startswith(folder_real.rstrip(os.sep) + os.sep):
        return None
    return real


def refusal_reason(target: str) -> str:
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
        return [(i, delay_value(page_delays[i], f"{path} page {i}"))
                for i in range(n_total)]
    from_name = parse_delay_from_name(rel)
    if from_name is not None:
        return [(None, from_name)]
    if 0 in page_delays:
        return [(None, delay_value(page_delays[0], str(path)))]
    if lone_ok:
        return [(None, None)]
    raise SequenceError(f"{path}: no delay in the file name (expected e.g. "
                        f"'frame_01150us.png'){cut} and no frames list in sequence.json")


def not_regular(path: Path) -> str | None:
    """What ``path`` is when it exists but is not a regular file (links followed): "a FIFO",
    "a character device", "a block device", "a socket" or "a folder"; None for a regular file
    or one that cannot be looked at (reported when it is read)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    for test, kind in ((stat.S_ISREG, None), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a folder")):
        if test(mode):
            return kind
    return "not a regular file"


def shown_name(name: str) -> str:
    """A file name as it can be printed: bytes that are not UTF-8 (surrogate escapes) as ``\\xNN``."""
    return name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def is_regular_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):
        return True  # listed; the problem is reported when the frame is read


def read_frame_rate(doc: dict, where: str) -> tuple[float, float, int] | None:
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
    fps = ranged_value(fps, "frame_rate_hz", "frame_rate_hz", where)
    first = doc.get("first_frame_delay_us")
    first = 0.0 if first is None else finite_or_none(first, "first_frame_delay_us", where)
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
        try:
            p.name.encode("utf-8")
        except UnicodeEncodeError:  # Parquet and JSON hold UTF-8 text only: refused before any work
            raise SequenceError(f"{folder / shown_name(p.name)}: the file name is not valid UTF-8 text "
                                "(shown with \\x escapes); rename the file") from None
        target = None if allow_outside else outside_folder(folder_real, p)
        kind = not_regular(p) if target is None else None
        if target is not None:
            refused[p.name] = refusal_reason(target)
        elif kind == "a folder" or not (kind is not None or is_regular_file(p)):
            continue
        elif kind is not None:  # a FIFO or device named like a frame: reported, never opened
            refused[p.name] = f"{kind}, not a regular file; not read"
        names.append(p.name)
    names.sort(key=_natural_key)
    if not names:
        raise SequenceError(f"{folder}: no image files ({', '.join(IMAGE_SUFFIXES)}) "
                            "and no frames list")
    return names


def list_from_folder(folder: Path, folder_real: str, refused: dict,
                        allow_outside: bool, lone_ok: bool = False, only: frozenset | None = None
                        ) -> list[ListedFrame]:
    """Frames of a folder without a frames list; with ``lone_ok`` a folder of one single-frame
    image without a delay lists it with delay None (the caller gives it one)."""
    names = _scan_folder(folder, folder_real, refused, allow_outside, only)
    lone_ok = lone_ok and len(names) == 1
    return [ListedFrame(name, page, delay) for name in names
            for page, delay in _delays_of_file(folder, name, refused, lone_ok)]


def images_without_delay(folder: Path, allow_outside: bool = False) -> list[str] | None:
    """The image files of a folder (natural order) when there are two or more and none tells a
    delay (file name, TIFF metadata) nor holds several frames: independent shots
    (`dropvision.analysis.shots`), each measured as a single frame. None otherwise (a sequence, or a folder
    whose frames `list_from_folder` lists or refuses).  Links leading out of the folder are left
    out unless allowed."""
    folder_real = os.path.realpath(folder)
    refused: dict[str, str] = {}
    try:
        names = _scan_folder(folder, folder_real, refused, allow_outside)
    except SequenceError:
        return None
    names = [n for n in names if n not in refused]
    if len(names) < 2:
        return None
    for name in names:
        if PurePath(name).suffix.lower() in VIDEO_SUFFIXES or parse_delay_from_name(name) is not None:
            return None
        info = _probe(reader_for(folder / name), folder / name)
        if info.n_pages > 1 or info.page_delays:
            return None
    return names


def list_from_rate(folder: Path, video, rate: tuple[float, float, int], json_path: Path,
                      folder_real: str, refused: dict, allow_outside: bool,
                      only: frozenset | None = None) -> list[ListedFrame]:
    """Frames of a high-speed recording: the ``video`` file, else every image file of the
    folder in natural name order (each page of a multi-page file in turn); frame i (0-based,
    in that order) gets delay ``first_frame_delay_us + (i - trigger_frame) * 1e6 /
    frame_rate_hz``."""
    fps, first, trigger = rate
    where = str(json_path)
    if video is not None:
        rel = safe_relpath(video, f"{where} video")
        path = folder / rel
        if reader_for(path) is None:
            raise SequenceError(f"{path}: unsupported image type (use "
                                f"{', '.join(IMAGE_SUFFIXES)})")
        target = None if allow_outside else outside_folder(folder_real, path)
        if target is not None:
            raise SequenceError(f"{path}: {refusal_reason(target)}")
        if not is_regular_file(path):
            kind = not_regular(path)
            raise SequenceError(f"{path}: named by 'video' in sequence.json but "
                                + (f"it is {kind}, not a regular file" if kind else "missing"))
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
        out.append(ListedFrame(rel, page, delay))
    return out


def list_from_frames(folder: Path, frames, json_path: Path, folder_real: str,
                        refused: dict, allow_outside: bool, only: frozenset | None = None
                        ) -> list[ListedFrame]:
    if not isinstance(frames, list) or not frames:
        raise SequenceError(f"{json_path}: 'frames' must be a non-empty list")
    out, seen, stored_delays = [], set(), {}
    for i, entry in enumerate(frames):
        where = f"{json_path} frames[{i}]"
        if not isinstance(entry, dict):
            raise SequenceError(f"{where}: must be an object with 'file' and 'delay_us'")
        rel = safe_relpath(entry.get("file"), where)
        if only is not None and rel not in only:  # not (yet) complete: left out
            continue
        path = folder / rel
        where = f"{path}"
        reader = reader_for(path)
        if reader is None:
            raise SequenceError(f"{where}: unsupported image type (use {', '.join(IMAGE_SUFFIXES)})")
        target = None if allow_outside else outside_folder(folder_real, path)
        if target is not None:
            refused[rel] = refusal_reason(target)
        else:
            try:
                present = path.is_file()
            except (OSError, ValueError) as exc:
                raise SequenceError(f"{where}: listed in sequence.json frames[{i}] but cannot "
                                    f"be accessed ({getattr(exc, 'strerror', None) or exc})"
                                    ) from None
            if not present:
                kind = not_regular(path)
                if kind is not None:
                    raise SequenceError(f"{where}: listed in sequence.json frames[{i}] but it is {kind}, "
                                        "not a regular file")
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
            delay = delay_value(entry["delay_us"], where)
        else:
            delay = parse_delay_from_name(rel)
            if delay is None and rel in refused:
                raise SequenceError(f"{where}: {refused[rel]}; frames[{i}] needs a delay_us")
            if delay is None:
                if rel not in stored_delays:
                    stored_delays[rel] = _probe(reader, path).page_delays
                d = stored_delays[rel].get(0 if page is None else page)
                delay = None if d is None else delay_value(d, where)
            if delay is None and len(frames) == 1:  # one frame (dropvision init's null): assumed 0 as in a folder
                out.append(ListedFrame(rel, page, None))
                continue
            if delay is None:
                raise SequenceError(f"{where}: frames[{i}] has no delay_us and none can be "
                                    "parsed from the file name or TIFF page")
        out.append(ListedFrame(rel, page, delay))
    return out

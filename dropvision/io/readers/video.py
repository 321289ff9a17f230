"""Video reader: high-speed camera recordings (``.avi``, ``.mp4``, ``.mov``, ``.mkv``) as
multi-frame files, decoded by OpenCV's FFmpeg backend (``cv2.VideoCapture``).

Why OpenCV: it is already a dependency and, measured with ``tools/bench_decoders.py`` (one
thread, sequential decoding of an MJPG AVI), it decodes frames faster than PyAV.

A video is a paged file: page ``i`` is frame ``i`` (0-based, in stored order). Its frames get
delays from ``frame_rate_hz`` in sequence.json (or from a ``frames`` list with ``page`` and
``delay_us``); a video stores none. Before any frame is decoded, the width x height of the
container header is checked against :data:`dropvision.io.readers.base.MAX_PIXELS`, and the frame
count against :data:`MAX_FRAMES`. A frame the decoder cannot read (a cut or corrupt file) is
an :class:`~dropvision.io.readers.base.UnreadableImage`: skipped and reported, the sequence goes
on. Frames are returned as 8-bit grey when the three decoded channels are equal (grey
recordings, which FFmpeg hands out as BGR), else as 8-bit BGR (made grey by the sequence layer).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from dropvision.io.readers.base import ImageInfo, OpenImage, Reader, UnreadableImage, check_pixels

__all__ = ["VideoReader", "OpenVideo", "MAX_FRAMES"]

#: Most frames listed from one video (a corrupt header may claim billions).
MAX_FRAMES = 1_000_000


def _open_capture(path: Path) -> cv2.VideoCapture:
    """An opened capture whose header passed the pixel and frame-count limits."""
    try:
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    except cv2.error as exc:
        raise UnreadableImage(f"cannot open video ({exc})") from None
    if not cap.isOpened():
        cap.release()
        raise UnreadableImage("cannot open video (unknown container or codec, truncated or "
                              "corrupt file)")
    width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    try:
        check_pixels(width, height, "video")
    except UnreadableImage:
        cap.release()
        raise
    return cap


def _frame_count(cap: cv2.VideoCapture) -> int:
    n = cap.get(cv2.CAP_PROP_FRAME_COUNT)
    return int(n) if np.isfinite(n) and n > 0 else 0


def _grey_or_bgr(img: np.ndarray) -> np.ndarray:
    if img.ndim == 3 and img.shape[2] == 3:
        b = img[:, :, 0]
        if np.array_equal(b, img[:, :, 1]) and np.array_equal(b, img[:, :, 2]):
            return np.ascontiguousarray(b)
    return img


class OpenVideo(OpenImage):
    """A video kept open: frames read in stored order are decoded sequentially (no seeking);
    any other frame is reached by seeking (``CAP_PROP_POS_FRAMES``)."""

    def __init__(self, reader: "VideoReader", path: Path):
        super().__init__(reader, path)
        self.cap = _open_capture(self.path)
        self.n_frames = _frame_count(self.cap)
        self.width = int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        self.next = 0  # index of the frame the next read() returns; -1: unknown

    def decode(self, page: int | None) -> np.ndarray:
        """Decode frame ``page`` (None: the first)."""
        page = 0 if page is None else int(page)
        check_pixels(self.width, self.height, "video")  # the limit is read at each call
        if self.n_frames and page >= self.n_frames:
            raise UnreadableImage(f"cannot decode video frame {page} (the video holds "
                                  f"{self.n_frames} frames)")
        try:
            if page != self.next:
                self.cap.set(cv2.CAP_PROP_POS_FRAMES, page)
            ok, img = self.cap.read()
        except (cv2.error, MemoryError) as exc:
            self.next = -1
            raise UnreadableImage(f"cannot decode video frame {page} ({type(exc).__name__}; "
                                  "truncated or corrupt file)") from None
        if not ok or img is None:
            self.next = -1
            raise UnreadableImage(f"cannot decode video frame {page} (truncated or corrupt "
                                  "file)")
        self.next = page + 1
        return _grey_or_bgr(img)

    def close(self) -> None:
        """Release the capture."""
        self.cap.release()


class VideoReader(Reader):
    """Video files (AVI, MP4, MOV, MKV: any codec of OpenCV's FFmpeg), one page per frame."""

    suffixes = (".avi", ".mp4", ".mov", ".mkv")
    paged = True
    bgr = True

    def probe(self, path: Path) -> ImageInfo:
        """Number of frames from the container header (counted by grabbing when the header
        does not say); no stored delays."""
        cap = _open_capture(Path(path))
        try:
            n = _frame_count(cap)
            if n == 0:
                while n <= MAX_FRAMES and cap.grab():
                    n += 1
        finally:
            cap.release()
        if n > MAX_FRAMES:
            raise UnreadableImage(f"video header claims {n} frames, over the limit of "
                                  f"{MAX_FRAMES} (dropvision.io.readers.video.MAX_FRAMES)")
        return ImageInfo(n_pages=max(n, 1))

    def decode(self, path: Path, page: int | None) -> np.ndarray:
        """Decode frame ``page`` (None: the first) of the video."""
        handle = OpenVideo(self, path)
        try:
            return handle.decode(page)
        finally:
            handle.close()

    def open(self, path: Path) -> OpenVideo:
        """Keep the video open to decode its frames in order (see :class:`OpenVideo`)."""
        return OpenVideo(self, path)

"""Generic OpenCV reader: formats decoded with ``cv2.imread`` (BMP)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from dropvision.readers.base import Reader, UnreadableImage

__all__ = ["OpenCVReader"]


class OpenCVReader(Reader):
    """Single-image files decoded by OpenCV (``cv2.IMREAD_UNCHANGED``; colour in BGR order)."""

    suffixes = (".bmp",)
    bgr = True

    def decode(self, path: Path, page: int | None) -> np.ndarray:
        """Decode the file with ``cv2.imread`` (from its bytes when cv2 cannot open the path,
        e.g. a non-ASCII name on Windows); ``page`` is ignored."""
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:  # e.g. a path cv2 cannot open: decode from bytes
            try:
                data = np.fromfile(path, dtype=np.uint8)
            except OSError as exc:
                raise UnreadableImage(f"cannot read file ({exc.strerror})") from None
            img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        if img is None:
            kind = Path(path).suffix.lstrip(".").upper() or "image"
            raise UnreadableImage(f"cannot decode {kind} (truncated or corrupt file)")
        return img

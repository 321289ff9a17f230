"""Orientation of stored frames: the canonical frame has the nozzle at the top and the drops
travelling down the image; a stored frame's ``orientation`` is the direction the drops travel in it.

`to_canonical` / `from_canonical` turn images, `original_to_canonical` / `canonical_to_original`
map pixel coordinates.
"""

from __future__ import annotations

import numpy as np


#: Allowed values of ``orientation``: the direction the drops travel in the stored image.
ORIENTATIONS = ("down", "up", "left", "right")
#: ``np.rot90`` turns (counter-clockwise quarter turns) taking a stored image to canonical.
_ROT90_K = {"down": 0, "up": 2, "left": 1, "right": 3}


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


def swaps_axes(orientation: str) -> bool:
    """True when the canonical frame is the stored one turned by a quarter turn (left, right)."""
    return _ROT90_K[_check_orientation(orientation)] % 2 == 1

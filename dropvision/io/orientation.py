"""Orientation of stored frames: the canonical frame has the nozzle at the top and the drops
travelling down the image; a stored frame's ``orientation`` is the direction the drops travel in it.

`to_canonical` / `from_canonical` turn images, `original_to_canonical` / `canonical_to_original`
map pixel coordinates; `detect_orientation` reads the orientation from a frame (which image edge
the nozzle or its holder is attached to) and `orientation_of_stored_frame` is what a reader does
when no orientation is given.

Detection: the frame is shrunk to at most 256 px, divided by its own smooth illumination
(`dropvision.calibrate.background.estimate_background`, the same background model as the measurement, so
vignetting is not a dark body) and thresholded half-way to its darkest level. The dark bodies
touching an edge are the candidates; each belongs to the edge it covers the largest fraction of
(a holder in a vignetted corner also touches the next edge a little). The largest candidate
wins; a second candidate of at least half its area on another edge makes the frame ambiguous,
and then the detached bodies decide (drops in front of one candidate only, along the axis it
points to). Otherwise the result says what was seen at each edge and the caller keeps its
default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

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
    return _rot90(image, k)


def from_canonical(image: np.ndarray, orientation: str) -> np.ndarray:
    """Inverse of :func:`to_canonical`: canonical image -> image as stored for ``orientation``."""
    k = _ROT90_K[_check_orientation(orientation)]
    if k == 0:
        return image
    return _rot90(image, -k)


#: OpenCV's rotation of ``np.rot90``'s quarter turns (mod 4): the same pixels, some 5 times faster on a
#: 2048 x 1536 frame than numpy's strided copy.
_CV_ROTATE = {1: 2, 2: 1, 3: 0}  # cv2.ROTATE_90_COUNTERCLOCKWISE, ROTATE_180, ROTATE_90_CLOCKWISE
#: Pixel types `cv2.rotate` takes (any other: numpy).
_CV_DTYPES = ("uint8", "int8", "uint16", "int16", "int32", "float32", "float64")


def _rot90(image: np.ndarray, k: int) -> np.ndarray:
    """``np.ascontiguousarray(np.rot90(image, k))`` (a new C-contiguous array), by `cv2.rotate` where it
    takes the image (2-d, or 3-d of at most 4 channels, of its pixel types)."""
    k %= 4
    a = np.asarray(image)
    if (a.dtype.name in _CV_DTYPES and (a.ndim == 2 or (a.ndim == 3 and 1 <= a.shape[2] <= 4))
            and a.size and type(image) is np.ndarray):
        import cv2

        out = cv2.rotate(np.ascontiguousarray(a), _CV_ROTATE[k])
        if out.shape[:2] == a.shape[:2][::-1 if k % 2 else 1] and out.ndim == a.ndim and out.dtype == a.dtype:
            return out
    return np.ascontiguousarray(np.rot90(image, k))


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


# --- detection ---------------------------------------------------------------------------------

#: Edge the nozzle is attached to -> orientation (direction the drops travel, docs/FORMAT.md).
EDGE_TO_ORIENTATION = {"top": "down", "bottom": "up", "left": "right", "right": "left"}
#: Longest side of the shrunk frame looked at (px).
_WORK_PX = 256
#: Smallest dark body considered (fraction of the frame).
_MIN_AREA_FRACTION = 0.001
#: A second attached body of at least this fraction of the largest one makes the frame ambiguous.
_AMBIGUOUS_RATIO = 0.5


@dataclass(frozen=True)
class OrientationGuess:
    """What `detect_orientation` found.

    Attributes
    ----------
    orientation : str or None
        ``"down"``, ``"up"``, ``"left"`` or ``"right"``; None when it cannot be decided.
    edge : str or None
        Image edge of the nozzle or holder (``top``, ``bottom``, ``left``, ``right``).
    reason : str
        One sentence: what decided it, or why nothing could.
    edges : dict
        Edge -> what was seen there (text), for messages.
    """

    orientation: str | None
    edge: str | None
    reason: str
    edges: dict = field(default_factory=dict)

    def edges_text(self) -> str:
        """``top: ...; bottom: ...; left: ...; right: ...``."""
        return "; ".join(f"{e}: {self.edges.get(e, 'not looked at')}" for e in ("top", "bottom", "left", "right"))


def _grey_small(image: np.ndarray) -> np.ndarray:
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:  # colour in memory: the mean of the channels is enough to find dark bodies
        img = img[..., :3].mean(axis=2)
    img = img.astype(np.float32)
    h, w = img.shape
    step = max(1, math.ceil(max(h, w) / _WORK_PX))
    if step > 1:
        img = cv2.resize(img, (max(1, w // step), max(1, h // step)), interpolation=cv2.INTER_AREA)
    return img


def detect_orientation(image: np.ndarray) -> OrientationGuess:
    """Find the edge the nozzle (or its holder) is attached to in a stored frame.

    Parameters
    ----------
    image : ndarray
        One frame as stored (2-D grey, or colour), backlit: liquid and nozzle dark.

    Returns
    -------
    OrientationGuess
        ``orientation`` None when the frame does not tell (``reason`` and ``edges`` say why).
    """
    import cv2  # cv2 and the background model load only when a frame is looked at

    from dropvision.calibrate.background import CalibrationError, estimate_background
    from dropvision.frame.edges import edge_threshold

    small = _grey_small(image)
    hh, ww = small.shape
    if hh < 8 or ww < 8:
        return OrientationGuess(None, None, f"the frame is too small ({image.shape[1]}x{image.shape[0]} px)")
    try:
        background = estimate_background([small]).background
    except CalibrationError:
        return OrientationGuess(None, None, "too few bright pixels to estimate the backlight")
    t = small / background
    darkest = float(cv2.GaussianBlur(t, (0, 0), 1.0).min())
    if darkest > 0.8:
        return OrientationGuess(None, None, f"nothing dark in the frame (darkest transmission {darkest:.2f})",
                                {e: "nothing dark" for e in EDGE_TO_ORIENTATION})
    mask = (t < edge_threshold(max(darkest, 0.0))).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    min_area = max(4.0, _MIN_AREA_FRACTION * hh * ww)
    border = {"top": lab[0], "bottom": lab[-1], "left": lab[:, 0], "right": lab[:, -1]}
    attached, detached = [], []
    for k in range(1, n):
        area = int(stats[k, cv2.CC_STAT_AREA])
        if area < min_area:
            continue
        cover = {e: float(np.count_nonzero(line == k)) / line.size for e, line in border.items()}
        if max(cover.values()) > 0:
            attached.append((area, max(cover, key=cover.get), k, cover))
        else:
            detached.append(k)
    seen = {}
    for e in EDGE_TO_ORIENTATION:
        here = [(a, c[e]) for a, edge, _, c in attached if edge == e]
        if here:
            a, c = max(here)
            seen[e] = (f"a dark body over {100 * c:.0f} % of the edge ({100 * a / (hh * ww):.1f} % of the frame)"
                       + (f" and {len(here) - 1} smaller" if len(here) > 1 else ""))
        else:
            touching = [c[e] for _, _, _, c in attached if c[e] > 0]
            seen[e] = (f"only the corner of a body attached elsewhere ({100 * max(touching):.0f} % of the edge)"
                       if touching else "nothing dark")
    if not attached:
        return OrientationGuess(None, None, "no dark body touches an edge of the frame", seen)
    attached.sort(key=lambda x: -x[0])
    best = attached[0]
    rivals = [a for a in attached[1:] if a[1] != best[1] and a[0] >= _AMBIGUOUS_RATIO * best[0]]
    if not rivals:
        return OrientationGuess(EDGE_TO_ORIENTATION[best[1]], best[1],
                                f"the largest dark body touching an edge ({100 * best[0] / (hh * ww):.1f} % of "
                                f"the frame) is attached to the {best[1]} edge", seen)
    # several large attached bodies: the drops tell, flying away from the nozzle along its axis
    ahead = {}
    for area, edge, k, _ in [best, *rivals]:
        x, y, bw, bh = (int(v) for v in stats[k, :4])
        count = 0
        for j in detached:
            dx, dy, dw, dh = (int(v) for v in stats[j, :4])
            cx, cy = dx + dw / 2, dy + dh / 2
            if edge in ("left", "right") and y <= cy <= y + bh:
                count += (cx > x + bw) if edge == "left" else (cx < x)
            elif edge in ("top", "bottom") and x <= cx <= x + bw:
                count += (cy > y + bh) if edge == "top" else (cy < y)
        ahead[edge] = ahead.get(edge, 0) + count
    with_drops = [e for e, c in ahead.items() if c > 0]
    if len(with_drops) == 1:
        e = with_drops[0]
        return OrientationGuess(EDGE_TO_ORIENTATION[e], e,
                                f"dark bodies touch several edges; detached bodies lie in front of the one at the "
                                f"{e} edge only", seen)
    return OrientationGuess(None, None, "large dark bodies touch several edges ("
                            + ", ".join(sorted({a[1] for a in [best, *rivals]})) + ") and the drops do not tell "
                            "which one is the nozzle", seen)


def orientation_of_stored_frame(image: np.ndarray, frame_name: str,
                                default: str = "down") -> tuple[str, str, bool]:
    """The orientation of a sequence whose orientation was not given, and where it comes from.

    Parameters
    ----------
    image : ndarray
        The sequence's first frame (processing order), as stored.
    frame_name : str
        Names the frame in the source text (its file, or ``frame <i>``).
    default : str
        The orientation kept when the frame does not tell.

    Returns
    -------
    orientation : str
    source : str
        ``detected in <frame>: <reason>``, or ``default (<default>): not detected in <frame>,
        <reason> (<what was seen at each edge>)`` (``SequenceMeta.sources["orientation"]``).
    assumed : bool
        True where the frame did not tell and ``default`` was kept (``SequenceMeta.orientation_assumed``).
    """
    guess = detect_orientation(image)
    if guess.orientation is not None:
        return guess.orientation, f"detected in {frame_name}: {guess.reason}", False
    return default, (f"default ({default}): not detected in {frame_name}, {guess.reason}"
                     + (f" ({guess.edges_text()})" if guess.edges else "")), True

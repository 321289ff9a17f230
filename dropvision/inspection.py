"""A first look at a frame: where the nozzle is, and how wide it is in pixels.

What a user of a drop watcher does not want to type, read from the frame itself:

- `detect_orientation`: which image edge the nozzle (or its holder) is attached to, hence the
  ``orientation`` of docs/FORMAT.md (the direction the drops travel in the stored image). The
  frame is shrunk to at most 256 px, divided by its own smooth illumination
  (`dropvision.background.estimate_background`, the same background model as the
  measurement, so vignetting is not a dark body) and thresholded half-way to its darkest
  level. The dark bodies touching an edge are the candidates; each belongs to the edge it
  covers the largest fraction of (a holder in a vignetted corner also touches the next edge a
  little). The largest candidate wins; a second candidate of at least half its area on another
  edge makes the frame ambiguous, and then the detached bodies decide (drops in front of one
  candidate only, along the axis it points to). Otherwise the result says what was seen at
  each edge and the caller keeps its default.
- `nozzle_outer_width_px`: the nozzle's outer width in pixels, by the measurement's own
  calibration (`dropvision.calibration.calibrate_frames` on each frame; the median over frames spread
  over the sequence, as a neck hanging from the nozzle can be narrower than its walls), so that
  a pixel size can come from a known outer diameter (as OpenDrop and DropPyTension take it
  from the needle).

This module knows nothing of sequence folders: it looks at arrays (`dropvision.sequence` and
`dropvision.describe` call it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from dropvision.background import estimate_background
from dropvision.calibration import CalibrationError, calibrate_frames
from dropvision.edges import edge_threshold

__all__ = ["EDGE_TO_ORIENTATION", "OrientationGuess", "detect_orientation", "nozzle_outer_width_px"]

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


def nozzle_outer_width_px(images, *, max_value: int | None = None) -> tuple[float, int]:
    """Outer width of the nozzle in pixels, measured as the calibration measures it.

    Each frame is calibrated alone (`dropvision.calibration.calibrate_frames`: without an expected
    width the narrowest straight walls of the top body); a neck or a thread of liquid hanging
    from the nozzle can be narrower than its walls in some frames, so the median over the
    frames is returned (give frames spread over the sequence).

    Parameters
    ----------
    images : ndarray or list of ndarray
        Frames, 2-D grey, in the canonical orientation (nozzle at the top).
    max_value : int, optional
        Sensor maximum (a clipped backlight is then handled as in the measurement).

    Returns
    -------
    width_px : float
        Median outer diameter in px (the walls' horizontal width times the cosine of the tilt).
    n_frames : int
        Frames in which the nozzle was found.

    Raises
    ------
    dropvision.calibration.CalibrationError
        No nozzle found in any frame (the first frame's reason).
    """
    images = [images] if isinstance(images, np.ndarray) else list(images)
    widths, first_error = [], None
    for image in images:
        try:  # the pixel size does not enter the wall positions: 1 µm/px is a placeholder
            widths.append(float(calibrate_frames(image, [image], 1.0, max_value=max_value).nozzle_outer_diameter_px))
        except CalibrationError as exc:
            first_error = first_error or exc
    if not widths:
        raise first_error or CalibrationError("no frame to measure the nozzle in")
    return float(np.median(widths)), len(widths)

"""Quality flags: why a value is not trusted (it is then NaN, never a silent wrong number).

Flags are short stable codes (`dvcore.schema.Quality`, explained in
`dvcore.schema.QUALITY_CODES` and docs/FORMAT.md); a frame's ``quality`` column is ``"ok"``
or its codes joined by ``"; "``.
"""

from __future__ import annotations

import numpy as np

from dvcore.schema import Quality

# The codes and their explanations are declared once, in the schema of our outputs.
OK = Quality.OK
SATURATED = Quality.SATURATED
CLIPPED = Quality.CLIPPED
ILLUMINATION = Quality.ILLUMINATION
LOW_CONTRAST = Quality.LOW_CONTRAST
BLURRED = Quality.BLURRED
NO_NOZZLE = Quality.NO_NOZZLE
ATTACHED_LEAVES = Quality.ATTACHED_LEAVES
DROP_LEAVES = Quality.DROP_LEAVES
OUT_OF_BAND = Quality.OUT_OF_BAND
DUST_OVERLAP = Quality.DUST_OVERLAP
AMBIGUOUS = Quality.AMBIGUOUS
NO_DROP = Quality.NO_DROP
TAIL = Quality.TAIL
NO_REST_MENISCUS = Quality.NO_REST_MENISCUS
PIXEL_SIZE_MISMATCH = Quality.PIXEL_SIZE_MISMATCH
DELAY_INCONSISTENT = Quality.DELAY_INCONSISTENT
PINCHOFF_UNDEFINED = Quality.PINCHOFF_UNDEFINED
NEIGHBOURS = Quality.NEIGHBOURS
IMPLAUSIBLE = Quality.IMPLAUSIBLE
NOZZLE_OUT_OF_FOCUS = Quality.NOZZLE_OUT_OF_FOCUS
UNREADABLE = Quality.UNREADABLE
NOT_DROP_IMAGE = Quality.NOT_DROP_IMAGE

#: Flags of a frame whose intensities are not trusted: no number from it (`dropvision.analysis.sequence_summary`), and
#: its drop's tail does not hold later frames out of flight (`dropvision.analysis.tracking.track_main_drop`).
UNTRUSTED_INTENSITY_FLAGS = (BLURRED, LOW_CONTRAST, SATURATED, ILLUMINATION, NOT_DROP_IMAGE)

#: A backlit drop image is mostly lit background: at least this fraction of it (`background_fraction`), else
#: it is flagged `NOT_DROP_IMAGE`. The nozzle, the holder and the liquid are small dark silhouettes on the
#: light; even a large pendant drop leaves most of its frame lit (a person's first look at an image).
MIN_BACKGROUND_FRACTION = 0.5
#: A pixel is background within this fraction of the local background level.
BACKGROUND_TOLERANCE = 0.15


def join(flags) -> str:
    """The ``quality`` text of a list of flags (unique, in order)."""
    seen = []
    for f in flags:
        if f and f not in seen:
            seen.append(f)
    return "; ".join(seen) if seen else OK


def saturation_fraction(samples: np.ndarray, max_value: int) -> float:
    """Fraction of the samples at the sensor's maximum value."""
    return float(np.mean(samples >= max_value)) if samples.size else 0.0


def frame_gain(samples: np.ndarray, background: np.ndarray) -> float:
    """Illumination of a frame relative to the background model (median ratio of bright samples)."""
    ratio = samples.astype(np.float32) / background
    bright = ratio[ratio > 0.7]
    return float(np.median(bright)) if bright.size >= 10 else float("nan")


def wall_windows(rows, left_px, right_px, width: int, *, n: int = 24, half_px: int = 5):
    """Pixel windows across the nozzle's outer walls for per-frame sharpness and contrast.

    Up to ``n`` rows spread over ``rows`` (the straight wall rows), each with a window of
    ``2 half_px + 1`` pixels centred on the left and on the right sub-pixel wall edge, ordered
    from outside (background) to inside (wall).

    Returns
    -------
    win_rows, win_cols : ndarray of int, shape (m, 2 half_px + 1)
        Full-frame indices (``image[win_rows, win_cols]`` gives the profiles); empty when no
        window fits in the frame.
    """
    rows = np.asarray(rows)
    pick = np.unique(np.round(np.linspace(0, rows.size - 1, min(n, rows.size))).astype(int)) if rows.size else []
    offs = np.arange(-half_px, half_px + 1)
    out_r, out_c = [], []
    for i in pick:
        for edge, sign in ((left_px[i], 1), (right_px[i], -1)):
            cols = int(round(edge)) + sign * offs
            if cols.min() >= 0 and cols.max() < width:
                out_r.append(np.full(offs.size, rows[i]))
                out_c.append(cols)
    if not out_r:
        return np.empty((0, offs.size), int), np.empty((0, offs.size), int)
    return np.array(out_r), np.array(out_c)


def edge_sharpness(profiles: np.ndarray) -> float:
    """Median over profiles of the steepest step between neighbouring pixels (transmission/px).

    For a straight edge blurred by a Gaussian of ``sigma`` px (more than ~0.7 px) this is
    about ``contrast / (sigma sqrt(2 pi))``: a frame's blur relative to a reference frame is
    ``sigma_ref * sharpness_ref / sharpness``.
    """
    if profiles.size == 0:
        return float("nan")
    return float(np.median(np.abs(np.diff(profiles, axis=1)).max(axis=1)))


def wall_contrast(profiles: np.ndarray) -> float:
    """1 - the median over profiles of the darkest wall transmission."""
    if profiles.size == 0:
        return float("nan")
    return float(1.0 - np.median(profiles.min(axis=1)))


def background_fraction(image: np.ndarray) -> float:
    """Fraction of a frame that is bright background: within `BACKGROUND_TOLERANCE` of the local
    background level, the brightest level within a quarter of the frame (smoothed, so that a vignetted
    or unevenly lit background counts whole), judged on the frame reduced to 128 px on its long side.

    A drop image (backlit shadowgraph) is mostly such background; a photograph, a texture or a gradient
    is not (`MIN_BACKGROUND_FRACTION`). A black frame (no light at all) is 0; a uniform one 1.
    """
    import cv2

    img = np.asarray(image)
    if img.ndim != 2 or img.size == 0:
        return float("nan")
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)
    h, w = img.shape
    scale = min(1.0, 128.0 / max(h, w))
    small = cv2.resize(np.ascontiguousarray(img), (max(1, round(w * scale)), max(1, round(h * scale))),
                       interpolation=cv2.INTER_AREA).astype(np.float32)
    k = max(3, (max(small.shape) // 4) | 1)  # a quarter of the frame, odd
    level = cv2.dilate(small, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    level = cv2.GaussianBlur(level, (0, 0), k / 4)
    lit = level > 0
    if not lit.any():
        return 0.0
    return float(np.mean(lit & (small >= (1.0 - BACKGROUND_TOLERANCE) * level)))

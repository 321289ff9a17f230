"""Quality flags: why a value is not trusted (it is then NaN, never a silent wrong number).

Flags are short, fixed phrases (constants below) so they can be grouped; a frame's
``quality`` column is ``"ok"`` or its flags joined by ``"; "``.
"""

from __future__ import annotations

import numpy as np

OK = "ok"
SATURATED = "saturated background"
ILLUMINATION = "illumination differs from the background model"
LOW_CONTRAST = "low contrast"
BLURRED = "blurred"
NO_NOZZLE = "nozzle not found"
ATTACHED_LEAVES = "attached liquid leaves the field of view"
DROP_LEAVES = "drop leaves the field of view"
OUT_OF_BAND = "drop crosses the measurement band"
DUST_OVERLAP = "drop overlaps a static speck"
AMBIGUOUS = "ambiguous separation"
NO_DROP = "no drop in the field of view"
TAIL = "tail still joined to the drop"
NO_REST_MENISCUS = "no frame shows the meniscus at rest (first delay after the dead time): grown volume unknown"


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

"""Robust statistics shared by both packages (the Gaussian scale of a median absolute deviation)."""

from __future__ import annotations

import numpy as np

#: The median absolute deviation of a Gaussian sample times this is its standard deviation.
MAD_TO_SIGMA = 1.4826


def robust_sigma(x) -> float:
    """Robust spread of ``x``: 1.4826 x its median absolute deviation from its median (the standard
    deviation for Gaussian values).  ``x`` must not be empty; a NaN in it is not skipped."""
    x = np.asarray(x, float)
    return float(MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


def quantized_sigma(k) -> float:
    """Robust spread of integer values (raw pixel values or their differences): the interquartile
    range over 1.349 (the standard deviation for Gaussian values), each value spread evenly over its
    unit cell (the quartiles of grouped data, interpolated within the cell that holds them).

    A median absolute deviation of integers is an integer or a half: where the noise is about one
    count (an 8-bit frame, a JPEG coder's flat areas), `robust_sigma` of the differences of two
    pixels sticks at 1.048 counts for true spreads from 0.7 to 1.3 and jumps to 2.1 above; this
    follows the spread, the rounding's own ``1/12`` count^2 included (the error a rounded value
    carries).  ``k`` must not be empty; it is rounded to integers.
    """
    k = np.rint(np.asarray(k, float)).astype(np.int64).ravel()
    lo = int(k.min())
    counts = np.bincount(k - lo)
    cum = np.cumsum(counts)
    n = float(k.size)

    def quantile(p: float) -> float:
        target = p * n
        i = int(np.searchsorted(cum, target))  # the first cell whose cumulative count reaches it
        below = float(cum[i - 1]) if i > 0 else 0.0
        return lo + i - 0.5 + (target - below) / float(counts[i])

    return float((quantile(0.75) - quantile(0.25)) / 1.3490)


#: Pixels this far apart are compared to read a frame's noise: a colour camera's 2x2 Bayer cell
#: and a JPEG coder's 2x2 chroma cells make neighbours' noise correlated (on the real drop
#: watcher's JPEGs neighbours' differences give a spread of 0.008 of the background, pixels two
#: apart 0.014), pixels two apart belong to different cells, and a slow change (a vignette, a mist
#: droplet's shadow) still cancels in their difference.
NOISE_LAG_PX = 2


def pair_noise_sigma(first, second, scale: float = 1.0) -> float:
    """Standard deviation of one value's noise from pairs of values that share their expectation.

    The robust spread of the differences ``first - second`` over sqrt(2), times ``scale``.
    Integer values (raw pixel values: pass ``scale``, the transmission of one count) are read by
    `quantized_sigma`, others by `robust_sigma`.  NaN with fewer than 10 pairs.
    """
    a, b = np.asarray(first), np.asarray(second)
    if a.size < 10:
        return float("nan")
    if np.issubdtype(a.dtype, np.integer) and np.issubdtype(b.dtype, np.integer):
        spread = quantized_sigma(a.astype(np.int64) - b.astype(np.int64))
    else:
        spread = robust_sigma(a.astype(float) - b.astype(float))
    return float(spread / np.sqrt(2.0) * scale)

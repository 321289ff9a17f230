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

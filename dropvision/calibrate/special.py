"""Error-function helpers over arrays, without importing scipy.special.

Importing ``scipy.special`` costs 0.15-0.2 s (its array-API machinery), paid by every
``dropvision measure`` start when only ``erf`` and the normal CDF are needed on small arrays.
These apply ``math.erf`` / ``math.erfc`` per element; they agree with ``scipy.special.erf`` /
``ndtr`` to one unit in the last place.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["erf", "ndtr"]

_ERF = np.frompyfunc(math.erf, 1, 1)
_ERFC = np.frompyfunc(math.erfc, 1, 1)
_SQRT1_2 = math.sqrt(0.5)


def erf(x) -> np.ndarray:
    """The error function, element-wise (float64)."""
    return np.asarray(_ERF(np.asarray(x, np.float64)), np.float64)


def ndtr(x) -> np.ndarray:
    """The standard normal CDF ``(1 + erf(x / sqrt 2)) / 2``, element-wise (float64), computed as
    ``erfc(-x / sqrt 2) / 2`` (accurate in the lower tail, as scipy's)."""
    return 0.5 * np.asarray(_ERFC(-np.asarray(x, np.float64) * _SQRT1_2), np.float64)

"""Goodness-of-fit metrics shared by the models of :mod:`identify`."""

from __future__ import annotations

import numpy as np

__all__ = ["rmse", "fit_percent"]


def rmse(y, y_hat) -> float:
    """Root mean square error.

    Parameters
    ----------
    y, y_hat : array_like
        Data and model output, same shape and unit (e.g. nl for drop volumes).

    Returns
    -------
    float
        ``sqrt(mean((y - y_hat)^2))``, in the unit of ``y``.
    """
    e = np.asarray(y, dtype=float) - np.asarray(y_hat, dtype=float)
    return float(np.sqrt(np.mean(e**2)))


def fit_percent(y, y_hat) -> float:
    """MATLAB's normalised fit, ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``.

    Parameters
    ----------
    y, y_hat : array_like
        Data and model output, same shape and unit.

    Returns
    -------
    float
        Fit in percent (100 = perfect, may be negative; dimensionless).

    Raises
    ------
    ValueError
        If ``y`` is constant (the fit percent is undefined).
    """
    y = np.asarray(y, dtype=float)
    den = np.linalg.norm(y - y.mean())
    if den == 0:
        raise ValueError("fit_percent: y is constant, the fit percent is undefined")
    return float(100.0 * (1.0 - np.linalg.norm(y - np.asarray(y_hat, dtype=float)) / den))

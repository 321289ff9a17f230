"""Grown volume and flow velocity through the nozzle, from the attached liquid's volume.

- grown volume: attached volume minus the initial meniscus (mean attached volume of the frames
  at the first delay, which must show the meniscus at rest: see `dropvision.analysis.sequence_summary`);
- flow velocity: central differences of the per-delay mean grown volume divided by the
  nozzle's inner cross-section (`dvcore.waveform.flow_velocity_m_s`), NaN from the pinch-off on;
  at one instant (maximum stroke) from a local quadratic fit (`flow_velocity_at`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from dvcore.waveform import flow_velocity_m_s

if TYPE_CHECKING:  # pandas loads where a table is made, not at start-up
    import pandas as pd


def grown_and_flow(
    delay_us: np.ndarray,
    attached_volume_nl: np.ndarray,
    attached: np.ndarray,
    nozzle_inner_diameter_um: float | None,
) -> tuple[np.ndarray, np.ndarray, float, pd.Series]:
    """Grown volume per frame, flow velocity per frame, initial meniscus volume, per-delay grown.

    Parameters
    ----------
    delay_us : ndarray
        Delay of every frame (µs).
    attached_volume_nl : ndarray
        Attached volume below the tip plane (nl), NaN where unknown.
    attached : ndarray of bool
        Frames before the pinch-off without a detached drop.
    nozzle_inner_diameter_um : float or None
        Nozzle inner diameter (µm); no flow velocity without it.

    Returns
    -------
    grown_nl : ndarray
        Grown volume (nl).
    flow_m_s : ndarray
        Flow velocity (m/s); NaN for frames not attached or without a nozzle inner diameter.
    meniscus_nl : float
        Initial meniscus volume (nl).
    grown_by_delay : Series
        Mean grown volume (nl) per delay over attached frames (index delay_us, µs).
    """
    import pandas as pd
    delay_us = np.asarray(delay_us, float)
    v = np.asarray(attached_volume_nl, float)
    first = delay_us == np.min(delay_us) if delay_us.size else np.zeros(0, bool)
    base = v[first & np.isfinite(v)]
    meniscus = float(np.mean(base)) if base.size else float("nan")
    grown = v - meniscus
    g = pd.Series(np.where(attached, grown, np.nan)).groupby(delay_us).mean().dropna()
    flow = np.full(v.shape, np.nan)
    if nozzle_inner_diameter_um and g.size >= 2:
        d = g.index.to_numpy(float)
        rate = np.gradient(g.to_numpy(float), d)  # nl/us
        vel = pd.Series(flow_velocity_m_s(rate, nozzle_inner_diameter_um), index=d)
        flow = np.where(attached, vel.reindex(delay_us).to_numpy(float), np.nan)
    return grown, flow, meniscus, g


def flow_velocity_at(
    grown_by_delay: pd.Series, t_us: float, nozzle_inner_diameter_um: float, n_points: int = 5
) -> float:
    """Flow velocity at one instant from a quadratic fit of the grown volume near it.

    Parameters
    ----------
    grown_by_delay : Series
        Mean grown volume (nl) per delay (index, µs), from `grown_and_flow`.
    t_us : float
        The instant (µs after the firing trigger).
    nozzle_inner_diameter_um : float
        Nozzle inner diameter (µm).
    n_points : int
        Delays nearest to ``t_us`` used in the fit (a line below 4).

    Returns
    -------
    float
        Flow velocity (m/s); NaN outside the attached delays or with fewer than 3.
    """
    d = grown_by_delay.index.to_numpy(float)
    v = grown_by_delay.to_numpy(float)
    if d.size < 3 or not (d.min() <= t_us <= d.max()):
        return float("nan")
    sel = np.argsort(np.abs(d - t_us), kind="stable")[:n_points]
    c = np.polyfit(d[sel] - t_us, v[sel], 2 if sel.size >= 4 else 1)
    rate = c[-2]  # derivative at t_us, nl/us
    return float(flow_velocity_m_s(rate, nozzle_inner_diameter_um))

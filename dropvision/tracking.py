"""Sequence-level analysis: pinch-off, grown volume and flow velocity, in-flight drop, velocity.

Works on the per-frame table (one row per frame, ascending delay) produced by
`dropvision.measure`:

- pinch-off: the first delay at which at least half of the frames show a detached drop;
  frames before it are ``attached``;
- grown volume: attached volume minus the initial meniscus (mean attached volume of the frames
  at the first delay); flow velocity: central differences of the per-delay mean grown volume
  divided by the nozzle's inner cross-section, NaN from the pinch-off on;
- in flight: detached frames whose main drop is compact (axial length <= ``compact_ratio``
  equivalent-sphere diameters: the tail has merged or broken up) and trusted;
- jetting velocity: least-squares line of ``drop_z_um`` against ``delay_us`` over in-flight
  frames (slope in µm/µs = m/s, with its standard error); trajectory angle: slope of
  ``drop_x_um`` against ``drop_z_um``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd


def flow_velocity_m_s(flow_nl_per_us, nozzle_inner_diameter_um: float):
    """`identify.ecm.flow_velocity_m_s` (imported on first use: it pulls in scipy)."""
    from identify.ecm import flow_velocity_m_s as f

    return f(flow_nl_per_us, nozzle_inner_diameter_um)


@dataclass(frozen=True)
class LineFit:
    """Least-squares line ``y = intercept + slope x`` with standard errors."""

    slope: float
    intercept: float
    slope_se: float
    n: int


def fit_line(x, y) -> LineFit:
    """Ordinary least squares; NaN when fewer than 3 points (SE NaN below 3)."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n = x.size
    if n < 2 or np.ptp(x) == 0:
        return LineFit(np.nan, np.nan, np.nan, int(n))
    xm, ym = x.mean(), y.mean()
    sxx = np.sum((x - xm) ** 2)
    slope = float(np.sum((x - xm) * (y - ym)) / sxx)
    icpt = float(ym - slope * xm)
    if n < 3:
        return LineFit(slope, icpt, np.nan, n)
    res = y - (icpt + slope * x)
    se = float(np.sqrt(np.sum(res**2) / (n - 2) / sxx))
    return LineFit(slope, icpt, se, n)


def pinchoff_delay(delay_us: np.ndarray, detached: np.ndarray) -> float:
    """First delay at which at least half of the frames show a detached drop (NaN if none)."""
    df = pd.DataFrame({"d": delay_us, "x": detached.astype(float)})
    frac = df.groupby("d")["x"].mean()
    hit = frac.index[frac.to_numpy() >= 0.5]
    return float(hit[0]) if len(hit) else float("nan")


def grown_and_flow(
    delay_us: np.ndarray,
    attached_volume_nl: np.ndarray,
    attached: np.ndarray,
    nozzle_inner_diameter_um: float | None,
) -> tuple[np.ndarray, np.ndarray, float, pd.Series]:
    """Grown volume per frame, flow velocity per frame, initial meniscus volume, per-delay grown.

    Returns
    -------
    grown_nl : ndarray
    flow_m_s : ndarray
        NaN for frames not attached or without a nozzle inner diameter.
    meniscus_nl : float
    grown_by_delay : Series
        Mean grown volume per delay over attached frames (index delay_us).
    """
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
    """Flow velocity (m/s) at ``t_us`` from a quadratic fit of the grown volume at the
    ``n_points`` delays nearest to it (NaN outside the attached delays)."""
    d = grown_by_delay.index.to_numpy(float)
    v = grown_by_delay.to_numpy(float)
    if d.size < 3 or not (d.min() <= t_us <= d.max()):
        return float("nan")
    sel = np.argsort(np.abs(d - t_us), kind="stable")[:n_points]
    c = np.polyfit(d[sel] - t_us, v[sel], 2 if sel.size >= 4 else 1)
    rate = c[-2]  # derivative at t_us, nl/us
    return float(flow_velocity_m_s(rate, nozzle_inner_diameter_um))

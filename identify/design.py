"""Inverse design: control parameters (u1, u2) for a target in-flight volume (and velocity).

The search is restricted to the printable region: the convex hull of the distinct training
controls (the bounding box when the hull is degenerate). These are the model's
``training_controls``: the (u1, u2) where every polynomial of the fit had a usable sequence, so a
control whose sequences an irregular campaign lost (failed, no pinch-off, no velocity; see the
fit's notes) does not widen the region. A dense grid of nominal hybrid
predictions (vectorised) locates the best candidates, which a bounded Nelder-Mead search
refines. Objective: relative squared error of the volume (+ of the velocity when given).

With a volume target only, the solutions form a curve; among the candidates matching the
volume within the tolerance, the one closest to the centre of the training region
(normalised units) is returned: it is the least extrapolating choice. ``near`` replaces the
centre by another point (closed-loop tuning, `identify.tuning`: the last shot, so that a
corrected target moves the proposal as little as possible).

A target that cannot be met within ``tolerance_percent`` inside the region is reported as
infeasible, together with the nearest achievable point and a message.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import Delaunay, QhullError

from dvcore.errors import ParameterError
from identify.montecarlo import check_samples


@dataclass
class DesignResult:
    """Outcome of :func:`design`.

    ``feasible``: the target is met within tolerance inside the region; ``u1_um_per_ms``,
    ``u2_um``: the proposal (the nearest achievable point when infeasible); ``predicted``:
    nominal predictions there; ``spread``: Monte Carlo {"mean", "std", "parameters_only_low", "parameters_only_high"} per output;
    ``error_percent``: {"volume": ..., "velocity": ...} relative errors of the nominal model.
    """

    feasible: bool
    u1_um_per_ms: float
    u2_um: float
    target_volume_nl: float
    target_velocity_m_s: float | None
    predicted: dict
    spread: dict | None
    error_percent: dict
    message: str
    region: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "feasible": self.feasible, "u1_um_per_ms": self.u1_um_per_ms, "u2_um": self.u2_um,
            "target_volume_nl": self.target_volume_nl, "target_velocity_m_s": self.target_velocity_m_s,
            "predicted": self.predicted, "spread": self.spread, "error_percent": self.error_percent,
            "message": self.message, "region": self.region,
        }


class Region:
    """The printable region: convex hull of the training controls (bounding box if degenerate).

    Parameters
    ----------
    controls : ndarray, shape (m, 2)
        Distinct training (u1 µm/ms, u2 µm) pairs.

    Raises
    ------
    ValueError
        If the controls span no area in (u1, u2).
    """

    def __init__(self, controls: np.ndarray):
        c = np.asarray(controls, float)
        self.n_controls = len(c)
        self.lo, self.hi = c.min(axis=0), c.max(axis=0)
        if np.any(self.hi <= self.lo):
            raise ValueError("the training controls span no area in (u1, u2); cannot design")
        self.span = self.hi - self.lo
        try:
            self.tri = Delaunay((c - self.lo) / self.span)
        except (QhullError, ValueError):
            self.tri = None

    def inside(self, u1, u2) -> np.ndarray:
        """Boolean mask: which (u1 µm/ms, u2 µm) points lie in the region (broadcast, flattened)."""
        x = (np.column_stack([np.ravel(u1), np.ravel(u2)]) - self.lo) / self.span
        box = np.all((x >= -1e-9) & (x <= 1 + 1e-9), axis=1)
        if self.tri is None:
            return box
        return box & (self.tri.find_simplex(x, tol=1e-9) >= 0)

    def to_dict(self) -> dict:
        return {"u1_um_per_ms": [float(self.lo[0]), float(self.hi[0])], "u2_um": [float(self.lo[1]), float(self.hi[1])],
                "shape": "convex hull" if self.tri is not None else "bounding box", "n_controls": int(self.n_controls)}


def design(
    model, volume_nl: float, velocity_m_s: float | None = None, *, tolerance_percent: float = 1.0,
    grid_points: int = 81, samples: int = 2000, seed: int | None = 0, near: tuple[float, float] | None = None,
) -> DesignResult:
    """Find (u1, u2) in the printable region whose predicted in-flight volume (and jetting
    velocity) match the targets. See the module docstring.

    ``near``: (u1 µm/ms, u2 µm) to stay closest to along a volume-only solution curve (default:
    the centre of the training region)."""
    if not np.isfinite(volume_nl) or volume_nl <= 0:
        raise ParameterError("volume_nl", f"must be a positive number, got {volume_nl!r}")
    if velocity_m_s is not None and (not np.isfinite(velocity_m_s) or velocity_m_s <= 0):
        raise ParameterError("velocity_m_s", f"must be a positive number, got {velocity_m_s!r}")
    if samples and samples > 1:  # 0 or 1: no spread; more: bounded by memory, checked before the search
        check_samples(samples)
    if model.controls is None or len(model.controls) < 3:
        raise ValueError("the model has no training region (training_controls) to design in")
    region = Region(model.controls)
    g1 = np.linspace(region.lo[0], region.hi[0], grid_points)
    g2 = np.linspace(region.lo[1], region.hi[1], grid_points)
    U1, U2 = (a.ravel() for a in np.meshgrid(g1, g2, indexing="ij"))
    keep = region.inside(U1, U2)
    U1, U2 = U1[keep], U2[keep]
    pred = model.predict_grid(U1, U2)

    def rel_err(v, q):
        ev = (v - volume_nl) / volume_nl
        eq = 0.0 if velocity_m_s is None else (q - velocity_m_s) / velocity_m_s
        return ev, eq

    ev, eq = rel_err(pred["inflight_volume_nl"].to_numpy(), pred["jetting_velocity_m_s"].to_numpy())
    cost = ev**2 + eq**2
    tol = tolerance_percent / 100
    centre = (region.lo + region.hi) / 2 if near is None else np.asarray(near, float)
    dist = np.hypot((U1 - centre[0]) / region.span[0], (U2 - centre[1]) / region.span[1])
    if velocity_m_s is None:
        ok = np.abs(ev) <= tol / 4
        start = np.flatnonzero(ok)[np.argmin(dist[ok])] if ok.any() else int(np.argmin(cost))
    else:
        start = int(np.argmin(cost))

    def f(x):
        if not region.inside(x[0], x[1])[0]:
            return 1e6 + float(np.sum((x - np.clip(x, region.lo, region.hi)) ** 2))
        p = model.predict_grid(x[0], x[1])
        a, b = rel_err(p["inflight_volume_nl"].to_numpy()[0], p["jetting_velocity_m_s"].to_numpy()[0])
        c = a**2 + b**2
        if velocity_m_s is None:  # stay near the chosen point along the solution curve
            c += 1e-8 * float(np.sum(((x - [U1[start], U2[start]]) / region.span) ** 2))
        return c

    x0 = np.array([U1[start], U2[start]])
    res = minimize(f, x0, method="Nelder-Mead", options={"xatol": 1e-6, "fatol": 1e-14, "maxiter": 400})
    x = res.x if (res.fun <= f(x0) and region.inside(*res.x)[0]) else x0
    p = model.predict_grid(x[0], x[1]).iloc[0].to_dict()
    a, b = rel_err(p["inflight_volume_nl"], p["jetting_velocity_m_s"])
    err = {"volume": 100 * float(a), "velocity": None if velocity_m_s is None else 100 * float(b)}
    feasible = abs(a) <= tol and (velocity_m_s is None or abs(b) <= tol)
    predicted = {k: float(v) for k, v in p.items() if k not in ("u1_um_per_ms", "u2_um")}
    if feasible:
        msg = f"u1 = {x[0]:.2f} um/ms, u2 = {x[1]:.2f} um gives {predicted['inflight_volume_nl']:.3f} nl"
        if velocity_m_s is not None:
            msg += f" at {predicted['jetting_velocity_m_s']:.3f} m/s"
    else:
        vmin, vmax = pred["inflight_volume_nl"].min(), pred["inflight_volume_nl"].max()
        msg = (
            f"infeasible: target {volume_nl} nl"
            + ("" if velocity_m_s is None else f" at {velocity_m_s} m/s")
            + f" is not achievable inside the printable region (volumes {vmin:.2f}..{vmax:.2f} nl); "
            f"nearest achievable: u1 = {x[0]:.2f} um/ms, u2 = {x[1]:.2f} um -> "
            f"{predicted['inflight_volume_nl']:.3f} nl, {predicted['jetting_velocity_m_s']:.3f} m/s"
        )
    spread = None
    if samples and samples > 1:
        spread = model.monte_carlo(float(x[0]), float(x[1]), samples=samples, seed=seed).summary()
    return DesignResult(
        feasible=bool(feasible), u1_um_per_ms=float(x[0]), u2_um=float(x[1]), target_volume_nl=float(volume_nl),
        target_velocity_m_s=None if velocity_m_s is None else float(velocity_m_s), predicted=predicted,
        spread=spread, error_percent=err, message=msg, region=region.to_dict(),
    )

"""Synthetic training datasets from the project's default synthetic physics (ECM + pinch-off and
adjuster laws), whose truth is exactly known (:func:`make_synthetic_dataset`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from dvcore.atomic import write_json
from identify.dataset import Dataset, default_physics
from identify.ecm import flow_velocity_m_s, simulate
from identify.montecarlo import ecm_response_at
from identify.physics import SynthPhysics
from identify.waveform import SAMPLE_INTERVAL_US, Waveform


def paper_grid(step_u1: float = 5.0, step_u2: float = 1.25) -> list[tuple[float, float]]:
    """Colour-ink campaign grid of Table 1: u1 50..80 um/ms, u2 20..35 um."""
    u1 = np.arange(50.0, 80.0 + 1e-9, step_u1)
    u2 = np.arange(20.0, 35.0 + 1e-9, step_u2)
    return [(float(a), float(b)) for a in u1 for b in u2]


def ecm_truth(physics: SynthPhysics, u1: float, u2: float, t_us: np.ndarray, t_p: float):
    """Exact ECM response of a synthetic physics for one waveform.

    Parameters
    ----------
    physics : SynthPhysics
    u1, u2 : float
        Stroke velocity (µm/ms) and stroke (µm).
    t_us : ndarray
        Uniform sample times from the trigger (µs).
    t_p : float
        Pinch-off instant from the trigger (µs).

    Returns
    -------
    volume_nl, flow_nl_per_us : ndarray
        Grown volume (nl) and flow (nl/µs) at ``t_us`` (:func:`identify.ecm.simulate`).
    volume_at_pinchoff_nl : float
        Grown volume at ``t_p`` (nl), exact (:func:`identify.montecarlo.ecm_response_at`).
    flow_at_max_stroke_nl_per_us : float
        Flow at the maximum-stroke instant (nl/µs), exact.
    """
    coeffs = physics.ecm_parameters().coefficients()
    w = Waveform(u1, u2, physics.u3_um_per_ms, physics.hold_us)
    u = w.displacement_um(t_us - physics.dead_time_us)
    vol, flow = simulate(coeffs, t_us, u)
    c = coeffs.to_array()[None, :]
    v_p, _ = ecm_response_at(c, w, np.array([t_p - physics.dead_time_us]))
    _, q_max = ecm_response_at(c, w, np.array([w.max_stroke_us]))
    return vol, flow, float(v_p[0]), float(q_max[0])


def make_synthetic_dataset(
    out_dir,
    grid=None,
    noise_percent: float = 1.0,
    seed: int = 0,
    physics=None,
    *,
    repeats: int = 1,
    sample_interval_us: float = SAMPLE_INTERVAL_US,
    tail_samples: int = 3,
    noise_draw=None,
) -> Dataset:
    """Write a synthetic dataset with exactly known truth and return it.

    For each (u1, u2) of ``grid`` (default :func:`paper_grid`) and each repeat, the grown
    volume is the ECM response of ``physics`` to the delayed waveform, sampled every
    ``sample_interval_us`` from the trigger until pinch-off (+ ``tail_samples`` detached
    rows with NaN volume). The summary holds the pinch-off law, the ECM grown volume at the
    pinch-off instant, in-flight volume = that + volume adjuster, and jetting velocity = ECM
    flow velocity at maximum stroke + velocity adjuster (Eq. 8).

    Noise: every volume, velocity and pinch-off value gets independent Gaussian noise of
    ``noise_percent`` % of its own magnitude (time series: of the sequence's peak volume /
    velocity). The truth is written to ``truth.json``.

    ``noise_draw``: another scatter of the same size, a function ``(rng, size)`` returning
    draws of zero mean and unit variance (``size`` None: one float), e.g. a scaled Student t
    for heavier tails (`tools/interval_coverage.py`); default ``rng.standard_normal``.
    """
    physics = physics or default_physics()
    grid = paper_grid() if grid is None else [(float(a), float(b)) for a, b in grid]
    rng = np.random.default_rng(seed)
    sigma = noise_percent / 100.0
    draw = (lambda r, size=None: r.standard_normal(size)) if noise_draw is None else noise_draw
    d_um = physics.nozzle_inner_diameter_um
    h = float(sample_interval_us)
    ts_rows, su_rows, truth_rows = [], [], []
    sid = 0
    for u1, u2 in grid:
        t_p = float(physics.pinchoff_instant_us(u1, u2))
        n = int(np.floor(t_p / h)) + 1 + tail_samples
        t = np.arange(n) * h
        vol, flow, v_p, q_max = ecm_truth(physics, u1, u2, t, t_p)
        vel = flow_velocity_m_s(flow, d_um)
        v_max = flow_velocity_m_s(q_max, d_um)
        inflight = v_p + float(physics.volume_adjuster_nl_at(u1, u2))
        jet = v_max + float(physics.velocity_adjuster_m_s_at(u1, u2))
        truth_rows.append({"u1_um_per_ms": u1, "u2_um": u2, "pinchoff_us": t_p, "grown_volume_at_pinchoff_nl": v_p,
                           "inflight_volume_nl": inflight, "jetting_velocity_m_s": jet,
                           "flow_velocity_at_max_stroke_m_s": v_max})
        for _ in range(repeats):
            tp_meas = t_p * (1 + sigma * draw(rng))
            attached = t < tp_meas
            vn = vol + sigma * np.abs(vol).max() * draw(rng, n)
            fn = vel + sigma * np.abs(vel).max() * draw(rng, n)
            vn[~attached] = np.nan
            fn[~attached] = np.nan
            ts_rows.append(pd.DataFrame({
                "sequence_id": sid, "u1_um_per_ms": u1, "u2_um": u2, "delay_us": t,
                "grown_volume_nl": vn, "flow_velocity_m_s": fn, "attached": attached,
            }))
            su_rows.append({
                "sequence_id": sid, "u1_um_per_ms": u1, "u2_um": u2, "pinchoff_us": tp_meas,
                "grown_volume_at_pinchoff_nl": v_p * (1 + sigma * draw(rng)),
                "inflight_volume_nl": inflight * (1 + sigma * draw(rng)),
                "jetting_velocity_m_s": jet * (1 + sigma * draw(rng)),
                "flow_velocity_at_max_stroke_m_s": v_max * (1 + sigma * draw(rng)),
            })
            sid += 1
    ts = pd.concat(ts_rows, ignore_index=True)
    ts["sequence_id"] = ts["sequence_id"].astype("int64")
    su = pd.DataFrame(su_rows)
    ds = Dataset(
        timeseries=ts, summary=su, nozzle_inner_diameter_um=d_um, sample_interval_us=h,
        dead_time_us=physics.dead_time_us, u3_um_per_ms=physics.u3_um_per_ms, hold_us=physics.hold_us,
        ink={"name": "synthetic colour ink", "density_kg_m3": physics.density_kg_m3,
             "viscosity_mPa_s": physics.viscosity_mpa_s, "surface_tension_mN_m": physics.surface_tension_mn_m},
        nozzle={"length_mm": physics.nozzle_length_mm, "outer_diameter_um": physics.nozzle_outer_diameter_um,
                "reservoir_channel_radius_um": physics.reservoir_channel_radius_um,
                "reservoir_channel_length_mm": physics.reservoir_channel_length_mm},
        extra={"synthetic": {"noise_percent": noise_percent, "seed": seed, "repeats": repeats},
               "measurement_uncertainty": {
                   "volume_rel": 0.0, "velocity_rel": 0.0, "pinchoff_std_us": 0.0,
                   "source": "make_synthetic_dataset: exact truth plus independent noise per sequence, no "
                             "systematic error"}},
    )
    out_dir = Path(out_dir)
    ds.save(out_dir)
    p = physics.ecm_parameters()
    write_json(out_dir / "truth.json", {
        "schema": "identify.truth/1",
        "physics": physics.to_dict(),
        "ecm_parameters": p.to_dict(),
        "ecm_coefficients": p.coefficients().to_dict(),
        "per_control": truth_rows,
    })
    ds.path = out_dir
    return ds

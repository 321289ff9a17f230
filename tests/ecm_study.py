"""Synthetic noise study of the ECM estimators (used by tests/identify/test_ecm_fit.py).

Noisy synthetic growing-volume sequences over the colour-ink campaign grid from the exact
(closed-form) ECM response of the default synthetic physics, and the accuracy of
:func:`identify.ecm_fit.fit_ecm` on them at several output-noise levels (the figures quoted in
the docstring of :mod:`identify.ecm_fit`). Moved out of the library: only the tests use it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from identify.ecm import EcmParameters, pwl_response, waveform_knots
from identify.ecm_fit import RATIO_NAMES, EcmData, fit_ecm
from identify.hydraulics import Hydraulics
from identify.physics import SynthPhysics
from identify.waveform import DEAD_TIME_US, SAMPLE_INTERVAL_US, Waveform


def default_synthetic_parameters() -> EcmParameters:
    """ECM parameters (SI) of the team's default synthetic physics (``identify.physics.SynthPhysics``)."""
    return SynthPhysics().ecm_parameters()



def synthetic_pinchoff_us(u1_um_per_ms: float, u2_um: float) -> float:
    """The synthetic pinch-off law (``SynthPhysics.pinchoff_instant_us``), µs from the trigger."""
    return float(SynthPhysics().pinchoff_instant_us(u1_um_per_ms, u2_um))


#: Campaign grid of the colour ink (Table 1).
CAMPAIGN_U1_UM_PER_MS = np.arange(50.0, 80.0 + 1e-9, 5.0)
CAMPAIGN_U2_UM = np.arange(20.0, 35.0 + 1e-9, 1.25)


def synthetic_sequences(
    params: EcmParameters | None = None,
    u1_grid=CAMPAIGN_U1_UM_PER_MS,
    u2_grid=CAMPAIGN_U2_UM,
    noise_fraction: float = 0.0,
    seed: int = 0,
    interval_us: float = SAMPLE_INTERVAL_US,
    dead_time_us: float = DEAD_TIME_US,
    noise_model: str = "peak",
) -> list[EcmData]:
    """Noisy synthetic sequences over a (u1, u2) grid from the exact (closed-form) response.

    Volumes are sampled every ``interval_us`` from the trigger up to the synthetic
    pinch-off law; the noise is white Gaussian with standard deviation
    ``noise_fraction * max(volume)`` of each sequence (``noise_model="peak"``, 1 % -> ~0.18
    nl at (70, 25)) or ``noise_fraction * |volume(t)|`` (``"relative"``).
    ``y_ss``/``K_ss`` are the (noisy) last volume and its displacement.
    """
    params = default_synthetic_parameters() if params is None else params
    theta = params.coefficients().ratios()
    rng = np.random.default_rng(seed)
    out = []
    for u1 in np.atleast_1d(u1_grid):
        for u2 in np.atleast_1d(u2_grid):
            w = Waveform(float(u1), float(u2))
            tp = synthetic_pinchoff_us(u1, u2)
            t = np.arange(0.0, tp + 1e-9, interval_us)
            knots, jumps = waveform_knots(w, dead_time_us)
            vol, _ = pwl_response(theta, knots, jumps, t)
            if noise_model == "peak":
                sd = noise_fraction * np.max(np.abs(vol))
            elif noise_model == "relative":
                sd = noise_fraction * np.abs(vol)
            else:
                raise ValueError(f"noise_model must be 'peak' or 'relative', got {noise_model!r}")
            vol = vol + sd * rng.standard_normal(vol.size)
            out.append(EcmData.from_waveform(w, t, vol, dead_time_us=dead_time_us))
    return out


def noise_study(
    noise_fractions=(0.0, 0.01, 0.02),
    methods=("oe", "delta"),
    params: EcmParameters | None = None,
    u1_grid=CAMPAIGN_U1_UM_PER_MS,
    u2_grid=CAMPAIGN_U2_UM,
    seed: int = 0,
    noise_model: str = "peak",
) -> pd.DataFrame:
    """Accuracy of the estimators on synthetic data at several output-noise levels.

    The dataset is :func:`synthetic_sequences` (default physics, campaign grid of 91
    waveforms, noise per ``noise_model``).

    Returns
    -------
    DataFrame
        One row per (method, noise): columns ``method, noise_pct``, the relative errors (%)
        of the five ratios ``err_A2/A3_pct .. err_B0/A3_pct`` and their maximum
        ``max_ratio_err_pct``, of ``err_Ra_pct, err_CN_pct, err_Kc_pct`` (La fixed at its
        true value), ``rmse_nl`` and ``ci_covers_truth`` (oe: all three 95 % intervals
        contain the truth; delta: the interval of the mean).
    """
    params = default_synthetic_parameters() if params is None else params
    truth = params.coefficients().ratios()
    hyd = Hydraulics(params.LN, params.RN, params.LR, params.RR)
    rows = []
    for noise in noise_fractions:
        data = synthetic_sequences(params, u1_grid, u2_grid, noise_fraction=noise, seed=seed, noise_model=noise_model)
        for method in methods:
            fit = fit_ecm(data, hyd, method=method, la=params.La)
            err = 100 * (fit.ratios() / truth - 1)
            row = {"method": method, "noise_pct": 100 * noise}
            row.update({f"err_{n}_pct": e for n, e in zip(RATIO_NAMES, err)})
            row["max_ratio_err_pct"] = float(np.max(np.abs(err)))
            covers = True
            for n in ("Ra", "CN", "Kc"):
                est, tru = getattr(fit.parameters, n), getattr(params, n)
                row[f"err_{n}_pct"] = 100 * (est / tru - 1)
                lo, hi = fit.param_ci95[n]
                covers &= bool(lo <= tru <= hi)
            sd = np.sqrt(np.diag(fit.ratio_cov)) / np.abs(truth)
            row["max_ratio_z"] = float(np.max(np.abs(err / 100) / sd)) if np.all(sd > 0) else float("inf")
            row["rmse_nl"] = fit.rmse_nl
            row["ci_covers_truth"] = covers
            rows.append(row)
    return pd.DataFrame(rows)

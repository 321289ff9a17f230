"""A synthetic printhead driven by a waveform template, identified end to end from its images
(issue 31): render a small campaign of sequences over a few settings of the template's parameters
(the synthesizer's flow comes from the template's drive through the ECM,
`identify.physics.drive_history`), measure every sequence with `dropvision.measure`, fit the hybrid
model on the template (`identify.template_fit.fit_template_model`) and compare it with the
synthesizer's truth: the ECM parameters, and the in-flight volume and jetting velocity of held-out
settings.

`tools/template_identification.py` runs it for the figures (three-pulse and the paper's trapezoid
side by side); `tests/identify/test_template_identification.py` on a small campaign.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from dropvision.synth.config import SynthConfig
from dropvision.synth.writer import write_synthetic_sequence
from identify.hydraulics import hydraulics_from_dimensions
from identify.template_fit import fit_template_model, holdout_errors, sequence_tables

__all__ = ["render_campaign", "measure_campaign", "identify_campaign"]


def render_campaign(base: SynthConfig, settings: Sequence[Mapping], out_dir, *, template: Mapping) -> list[Path]:
    """One synthetic sequence per setting (``template``: ``{"template": name, <constants>}``), seeds
    ``base.seed + i``, written to ``out_dir/seq_<i>``."""
    out = Path(out_dir)
    paths = []
    for i, values in enumerate(settings):
        cfg = replace(base, seed=base.seed + i, waveform={**dict(template), "parameters": dict(values)})
        paths.append(write_synthetic_sequence(cfg, out / f"seq_{i:03d}", progress=False, overwrite=True))
    return paths


def measure_campaign(paths: Sequence[Path]) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Measure each sequence (`dropvision.measure`): the training table (one row per sequence:
    its parameters from sequence.json's ``waveform``, the measured pinch-off, in-flight volume,
    jetting velocity), the time series, and the truth of each sequence (truth.json)."""
    from dropvision.api import measure

    rows, series, truths = [], [], []
    for p in paths:
        res = measure(p)
        meta = json.loads((Path(p) / "sequence.json").read_text())
        row, ts = sequence_tables(Path(p).name, meta["waveform"], res.frames, res.summary)
        rows.append(row)
        series.append(ts)
        truth = json.loads((Path(p) / "truth.json").read_text())
        truths.append({"sequence_id": Path(p).name, **{k: truth[k] for k in (
            "pinchoff_instant_us", "pinchoff_us", "inflight_volume_nl", "jetting_velocity_m_s")}})
    return pd.DataFrame(rows), pd.concat(series, ignore_index=True), pd.DataFrame(truths)


def identify_campaign(base: SynthConfig, train: Sequence[Mapping], test: Sequence[Mapping], out_dir, *,
                      template: Mapping) -> dict:
    """Render, measure and identify; the figures against the synthesizer's truth.

    Returns
    -------
    dict
        ``ecm``: per physical parameter (Ra, CN, Kc; La fixed at the truth's value) the estimate,
        the truth, the relative error (%) and whether the 95 % interval covers the truth, and the
        ECM's output-error rmse (nl); ``holdout``: per held-out setting the predicted and measured
        in-flight volume and jetting velocity, their errors (%) and the error against the truth;
        ``summary``: the largest absolute held-out errors (%), ``model``: the model's dict.
    """
    out = Path(out_dir)
    paths = render_campaign(base, list(train) + list(test), out, template=template)
    table, series, truth = measure_campaign(paths)
    n = len(train)
    ph = base.physics
    hyd = hydraulics_from_dimensions(ph.density_kg_m3, ph.viscosity_mpa_s, ph.nozzle_inner_diameter_um,
                                     ph.nozzle_length_mm, ph.reservoir_channel_radius_um,
                                     ph.reservoir_channel_length_mm)
    true = ph.ecm_parameters()
    model = fit_template_model(template, table.iloc[:n], series[series["sequence_id"].isin(table["sequence_id"][:n])],
                               dead_time_us=ph.dead_time_us, nozzle_inner_diameter_um=ph.nozzle_inner_diameter_um,
                               hydraulics=hyd, la=true.La)
    ecm = {}
    for k in ("Ra", "CN", "Kc"):
        est = model.ecm["parameters"][k]
        lo, hi = est["ci95"]
        t = float(getattr(true, k))
        ecm[k] = {"estimate": est["value"], "truth": t, "error_percent": 100.0 * (est["value"] / t - 1.0),
                  "ci95": [lo, hi], "covers": bool(min(lo, hi) <= t <= max(lo, hi))}
    ecm["rmse_nl"] = model.ecm["rmse_nl"]
    held = holdout_errors(model, table.iloc[n:])
    tr = truth.iloc[n:].reset_index(drop=True)
    for k in ("inflight_volume_nl", "jetting_velocity_m_s"):
        held[f"{k}_truth"] = tr[k].to_numpy(float)
        held[f"{k}_error_vs_truth_percent"] = 100.0 * (held[f"{k}_predicted"] / held[f"{k}_truth"] - 1.0)
    summary = {f"max_abs_{k}_error_percent": float(np.max(np.abs(held[f"{k}_error_percent"])))
               for k in ("inflight_volume_nl", "jetting_velocity_m_s")}
    summary.update({f"max_abs_{k}_error_vs_truth_percent": float(np.max(np.abs(held[f"{k}_error_vs_truth_percent"])))
                    for k in ("inflight_volume_nl", "jetting_velocity_m_s")})
    summary["max_abs_pinchoff_error_us"] = float(np.max(np.abs(held["pinchoff_us_error"])))
    summary["max_abs_ecm_error_percent"] = float(max(abs(ecm[k]["error_percent"]) for k in ("Ra", "CN", "Kc")))
    return {"ecm": ecm, "holdout": held, "summary": summary, "model": model.to_dict(), "training": table.iloc[:n]}

"""Sequence-level analysis of the per-frame records: the frames table and the summary.

`assemble` runs, in order: pinch-off and attached frames (`dropvision.pinchoff`), grown volume
and flow velocity relative to the meniscus at rest (`dropvision.flow`), the main drop in every
frame (`dropvision.tracking`), then drops every number of a frame whose intensities are not
trusted, and builds the ``frames`` table (`FRAME_COLUMNS`) and the ``summary`` dict.
`per_delay` gives the per-delay statistics of the table.

Columns of ``frames`` (fixed): file, page, delay_us, repeat, attached, attached_volume_nl,
grown_volume_nl, drop_volume_nl, detached_volume_nl, drop_z_um, drop_x_um, n_satellites,
flow_velocity_m_s, quality, then extra columns: drop_length_um (main body's extent along the
image rows), drop_diameter_um (widest chord), inflight (bool: main drop compact, trusted),
neck_px (narrowest chord of the attached liquid), gain (frame illumination / background model),
blur_px (the frame's edge blur, Gaussian sigma, from its nozzle walls' steepness relative to the
calibration frame), wall_contrast (1 - the nozzle wall's transmission in the frame).
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pandas as pd

from dropvision import quality as q
from dropvision.calibration import Calibration
from dropvision.config import MeasureConfig
from dropvision.flow import flow_velocity_at, grown_and_flow
from dropvision.frame import FrameRecord
from dropvision.pinchoff import pinchoff_delay
from dropvision.tracking import fit_line, track_main_drop
from identify import schema
from identify.versions import software_versions
from identify.waveform import Waveform

SCHEMA_VERSION = schema.SUMMARY.schema
#: Columns of frames.parquet, in order (declared with dtype, unit and meaning in `identify.schema.FRAMES`).
FRAME_COLUMNS = schema.FRAMES.column_names
PER_DELAY_COLUMNS = [name for name, _ in schema.PER_DELAY_SOURCES]
#: Flags of a frame whose intensities are not trusted: no number from it.
UNTRUSTED_INTENSITY_FLAGS = (q.BLURRED, q.LOW_CONTRAST, q.SATURATED, q.ILLUMINATION)
#: Flags that only keep a frame out of the in-flight set (not shown in ``quality``).
INFLIGHT_ONLY_FLAGS = frozenset({q.TAIL})


def dead_time_us(meta, config: MeasureConfig) -> float:
    """Firing-trigger-to-piston delay (µs): the waveform's ``dead_time_us``, else the config's."""
    return float((meta.waveform or {}).get("dead_time_us", config.dead_time_us))


def max_stroke_instant_us(meta, config: MeasureConfig) -> float:
    """Instant of maximum stroke after the firing trigger (µs), NaN without ``u1``/``u2``.

    Dead time plus the stroke ramp ``u2 / u1`` (`identify.waveform.Waveform.max_stroke_us`).
    """
    wf = meta.waveform or {}
    if "u1_um_per_ms" not in wf or "u2_um" not in wf:
        return float("nan")
    return dead_time_us(meta, config) + Waveform(float(wf["u1_um_per_ms"]), float(wf["u2_um"])).max_stroke_us


def assemble(records: list[FrameRecord], cal: Calibration, sigma_px: float, meta, config: MeasureConfig,
             errors: list[dict]) -> tuple[pd.DataFrame, dict]:
    """Sequence-level analysis of the per-frame records.

    Parameters
    ----------
    records : list of FrameRecord
        Measured frames (unreadable ones left out), sequence flags first in their flags.
    cal : Calibration
    sigma_px : float
        Calibrated edge blur (Gaussian sigma, px).
    meta : sequence metadata
        ``path``, ``frames``, ``waveform``, ``nozzle_inner_diameter_um`` (µm), ``orientation``.
    config : MeasureConfig
    errors : list of dict
        Unreadable frames (copied into the summary).

    Returns
    -------
    frames : DataFrame
        One row per record, columns `FRAME_COLUMNS` (volumes nl, lengths µm, delays µs, m/s).
    summary : dict
        Per-sequence results (``schema_version`` `SCHEMA_VERSION`; see docs/FORMAT.md).
    """
    m = len(records)
    delay = np.array([r.delay_us for r in records], float)
    flags = [list(r.flags) for r in records]
    att_vol = np.array([r.attached_volume_nl for r in records], float)
    has_det = np.array([bool(r.bodies) for r in records], bool)
    pinch = pinchoff_delay(delay, has_det) if m else float("nan")
    attached = ~has_det & ((delay < pinch) if np.isfinite(pinch) else True)
    grown, flow, meniscus, grown_by_delay = grown_and_flow(delay, att_vol, attached, meta.nozzle_inner_diameter_um)
    # The grown volume is relative to the initial meniscus (Section 4.1.1): that needs a frame
    # taken before the piston moves (delay <= dead time). Without one, no grown volume or flow.
    dead_time = dead_time_us(meta, config)
    meniscus_at_rest = bool(m) and float(np.min(delay)) <= dead_time
    if not meniscus_at_rest:
        grown[:] = np.nan
        flow[:] = np.nan
        grown_by_delay = grown_by_delay.iloc[0:0]
        meniscus = float("nan")
        for k in range(m):
            if attached[k]:
                flags[k].append(q.NO_REST_MENISCUS)
    drop = track_main_drop(records, attached, config, flags)
    for k in range(m):
        if any(f in UNTRUSTED_INTENSITY_FLAGS for f in flags[k]):
            # untrusted intensities: no number from this frame
            att_vol[k] = grown[k] = drop.drop_volume_nl[k] = drop.detached_volume_nl[k] = np.nan
            drop.z_um[k] = drop.x_um[k] = np.nan
            flow[k] = np.nan
            drop.inflight[k] = False
    frames = pd.DataFrame({
        "file": [r.file for r in records],
        "page": pd.array([r.page for r in records], dtype="Int64"),
        "delay_us": delay,
        "repeat": np.array([r.repeat for r in records], int),
        "attached": attached.astype(bool),
        "attached_volume_nl": att_vol,
        "grown_volume_nl": grown,
        "drop_volume_nl": drop.drop_volume_nl,
        "detached_volume_nl": drop.detached_volume_nl,
        "drop_z_um": drop.z_um,
        "drop_x_um": drop.x_um,
        "n_satellites": pd.array([None if not np.isfinite(v) else int(v) for v in drop.n_satellites], dtype="Int64"),
        "flow_velocity_m_s": flow,
        "quality": [q.join([f for f in fl if f not in INFLIGHT_ONLY_FLAGS]) for fl in flags],
        "drop_length_um": drop.length_um,
        "drop_diameter_um": drop.diameter_um,
        "inflight": drop.inflight,
        "neck_px": np.array([r.neck_px for r in records], float),
        "blur_px": np.array([r.blur_px for r in records], float),
        "wall_contrast": np.array([r.wall_contrast for r in records], float),
        "gain": np.array([r.gain for r in records], float),
    }, columns=FRAME_COLUMNS)
    # --- summary -------------------------------------------------------------------------
    last_att = delay[attached & (delay < pinch)] if np.isfinite(pinch) else delay[attached]
    g_pinch = float("nan")
    if np.isfinite(pinch) and last_att.size:
        at_last = grown[(delay == last_att.max()) & attached]
        at_last = at_last[np.isfinite(at_last)]
        g_pinch = float(np.mean(at_last)) if at_last.size else float("nan")
    inflight = drop.inflight
    inf_vol = drop.drop_volume_nl[inflight]
    line = fit_line(delay[inflight], drop.z_um[inflight])
    traj = fit_line(drop.z_um[inflight], drop.x_um[inflight])
    sats = drop.n_satellites[inflight & np.isfinite(drop.n_satellites)]
    max_stroke_us = max_stroke_instant_us(meta, config)
    flow_at_max_stroke_m_s = float("nan")
    if np.isfinite(max_stroke_us) and meta.nozzle_inner_diameter_um:
        flow_at_max_stroke_m_s = flow_velocity_at(grown_by_delay, max_stroke_us, meta.nozzle_inner_diameter_um)
    calib = cal.to_dict()
    calib["edge_blur_sigma_px"] = sigma_px
    calib["orientation"] = meta.orientation
    summary = {
        "schema_version": SCHEMA_VERSION,
        "sequence": str(meta.path),
        "n_frames": int(len(meta.frames)),
        "n_measured": int(m),
        "pinchoff_us": pinch,
        "grown_volume_at_pinchoff_nl": g_pinch,
        "initial_meniscus_volume_nl": meniscus,
        "initial_meniscus_source": (f"attached volume of the first frame(s), delay {float(np.min(delay)):g} us <= dead time "
                                    f"{dead_time:g} us" if meniscus_at_rest else schema.QUALITY_CODES[q.NO_REST_MENISCUS]),
        "inflight_volume_nl": float(np.mean(inf_vol)) if inf_vol.size else float("nan"),
        "inflight_volume_std_nl": float(np.std(inf_vol, ddof=1)) if inf_vol.size >= 2 else float("nan"),
        "inflight_frames": int(inf_vol.size),
        "jetting_velocity_m_s": line.slope,
        "jetting_velocity_se_m_s": line.slope_se,
        "trajectory_angle_mrad": float(1000.0 * np.arctan(traj.slope)) if np.isfinite(traj.slope) else float("nan"),
        "satellites": int(np.median(sats)) if sats.size else None,
        "max_stroke_us": max_stroke_us,
        "flow_velocity_at_max_stroke_m_s": flow_at_max_stroke_m_s,
        "calibration": calib,
        "errors": errors,
        "quality_counts": frames["quality"].value_counts().to_dict(),
        "software": software_versions(),
        "config": asdict(config),
    }
    return frames, summary


def per_delay(frames: pd.DataFrame) -> pd.DataFrame:
    """Per-delay statistics of the measured columns.

    Parameters
    ----------
    frames : DataFrame
        The frames table (`FRAME_COLUMNS`).

    Returns
    -------
    DataFrame
        One row per delay: ``delay_us`` (µs), ``n_frames``, ``<name>_mean``, ``<name>_std``
        (ddof 1) and ``<name>_count`` (finite values) of every `PER_DELAY_COLUMNS` column (its
        units), and ``attached_fraction``.
    """
    if frames.empty:
        return pd.DataFrame({"delay_us": []})
    g = frames.groupby("delay_us", sort=True)
    out = pd.DataFrame({"delay_us": g.size().index.to_numpy(float), "n_frames": g.size().to_numpy()})
    for col in PER_DELAY_COLUMNS:
        s = frames[col].astype(float)
        gg = s.groupby(frames["delay_us"])
        out[f"{col}_mean"] = gg.mean().to_numpy()
        out[f"{col}_std"] = gg.std(ddof=1).to_numpy()
        out[f"{col}_count"] = gg.count().to_numpy()
    out["attached_fraction"] = g["attached"].mean().to_numpy(float)
    return out

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
from typing import TYPE_CHECKING

import numpy as np

import dropvision.quality as q
from dropvision.calibration import Calibration
from dropvision.config import MeasureConfig
from dropvision.flow import flow_velocity_at, grown_and_flow
from dropvision.frame import FrameRecord
from dropvision.pinchoff import isolated_detached, pinchoff_bracket_problem, pinchoff_delay
from dropvision.plausibility import (attached_volume_outliers, check_nozzle, check_pixel_size, check_track, delays_text,
                                     growth_short_at_max_stroke, implausible_velocity, pinchoff_before_dead_time,
                                     pinchoff_before_stroke_end)
from dropvision.tracking import fit_line, track_main_drop
from dvcore import schema
from dvcore.versions import software_versions
from dvcore.waveform import Waveform

if TYPE_CHECKING:  # pandas loads where a table is made, not at start-up
    import pandas as pd

SCHEMA_VERSION = schema.SUMMARY.schema
#: Columns of frames.parquet, in order (declared with dtype, unit and meaning in `dvcore.schema.FRAMES`).
FRAME_COLUMNS = schema.FRAMES.column_names
PER_DELAY_COLUMNS = [name for name, _ in schema.PER_DELAY_SOURCES]
#: Flags of a frame whose intensities are not trusted: no number from it.
UNTRUSTED_INTENSITY_FLAGS = (q.BLURRED, q.LOW_CONTRAST, q.SATURATED, q.ILLUMINATION, q.NOT_DROP_IMAGE)
#: Flags that only keep a frame out of the in-flight set (not shown in ``quality``).
INFLIGHT_ONLY_FLAGS = frozenset({q.TAIL})


def dead_time_us(meta, config: MeasureConfig) -> float:
    """Firing-trigger-to-piston delay (µs): the waveform's ``dead_time_us``, else the config's."""
    return float((meta.waveform or {}).get("dead_time_us", config.dead_time_us))


def max_stroke_instant_us(meta, config: MeasureConfig) -> float:
    """Instant of maximum stroke after the firing trigger (µs), NaN without ``u1``/``u2``.

    Dead time plus the stroke ramp ``u2 / u1`` (`dvcore.waveform.Waveform.max_stroke_us`).
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
    import pandas as pd
    m = len(records)
    delay = np.array([r.delay_us for r in records], float)
    flags = [list(r.flags) for r in records]
    notes: list[str] = []
    not_drop = [r.file for r in records if q.NOT_DROP_IMAGE in r.flags]
    if not_drop:
        notes.append(f"{len(not_drop)} frame(s) look like no backlit drop image ({', '.join(not_drop[:3])}"
                     f"{', ...' if len(not_drop) > 3 else ''}): less than half of each is bright background "
                     f"(within {q.BACKGROUND_TOLERANCE:.0%} of the local background level); nothing measured in them")
    att_vol = np.array([r.attached_volume_nl for r in records], float)
    att_u = np.array([r.attached_volume_uncertainty_nl for r in records], float)
    att_common = np.array([r.attached_common_uncertainty_nl for r in records], float)
    att_plane = np.array([r.attached_plane_uncertainty_nl for r in records], float)
    has_det = np.array([bool(r.bodies) for r in records], bool)
    dead_time = dead_time_us(meta, config)
    # --- plausibility of the pixel size (issue "hostile and lying input", lie 1) ----------
    length_lie = check_pixel_size(cal, meta, config, flags, notes,
                                  dead_time_us(meta, config) if getattr(meta, "waveform", None) else None)
    # --- pinch-off: an isolated detached delay is a foreign frame, not the pinch-off -----
    isolated = isolated_detached(delay, has_det)
    for k in np.nonzero(isolated)[0]:
        flags[k].append(q.NEIGHBOURS)
    if isolated.any():
        notes.append(f"{int(isolated.sum())} frame(s) show a detached drop between attached delays "
                     f"({delays_text(delay[isolated])} us): inconsistent with their neighbours, left out")
    pinch = pinchoff_delay(delay[~isolated], has_det[~isolated]) if (~isolated).any() else float("nan")
    delay_lie = False
    has_waveform = bool(getattr(meta, "waveform", None))
    if not has_waveform:
        notes.append("no waveform in sequence.json: no waveform-based check (dead time, end of the stroke) is run "
                     "and the first delay's frames are taken as the meniscus at rest")
    if has_waveform and pinchoff_before_dead_time(pinch, dead_time, flags, notes):
        delay_lie = True
        pinch = float("nan")
    problem = pinchoff_bracket_problem(delay[~isolated], pinch, config.min_pinchoff_frames)
    if problem is not None and np.unique(delay).size == 1:
        # one delay (single frames of a drop watcher, a pendant drop): no series, nothing to flag
        notes.append("one delay only: no pinch-off (it needs a delay series)")
        pinch = float("nan")
    elif problem is not None:
        d_u = np.unique(delay[~isolated])
        before = d_u[d_u < pinch]
        involved = (delay == pinch) | ((delay == before.max()) if before.size else False)
        if m < config.min_pinchoff_frames:
            involved = np.ones(m, bool)
        for k in np.nonzero(involved & ~isolated)[0]:
            flags[k].append(q.PINCHOFF_UNDEFINED)
        notes.append(problem)
        pinch = float("nan")
    attached = ~has_det & ((delay < pinch) if np.isfinite(pinch) else True)
    if cal.nozzle_out_of_focus:
        for k in np.nonzero(attached)[0]:
            flags[k].append(q.NOZZLE_OUT_OF_FOCUS)
    # --- attached volumes that disagree with their neighbours (frames of another sequence) ---
    vol_used = att_vol.copy()
    vol_used[attached_volume_outliers(delay, att_vol, attached, config, flags, notes)] = np.nan
    grown, flow, meniscus, grown_by_delay = grown_and_flow(delay, vol_used, attached, meta.nozzle_inner_diameter_um)
    # The grown volume is relative to the initial meniscus (Section 4.1.1): that needs a frame
    # taken before the piston moves (delay <= dead time). Without one, no grown volume or flow.
    meniscus_at_rest = bool(m) and (float(np.min(delay)) <= dead_time if has_waveform
                                    else bool(attached[delay == np.min(delay)].all()))
    if not meniscus_at_rest:
        grown[:] = np.nan
        flow[:] = np.nan
        grown_by_delay = grown_by_delay.iloc[0:0]
        meniscus = float("nan")
        for k in range(m):
            if attached[k]:
                flags[k].append(q.NO_REST_MENISCUS)
    drop = track_main_drop(records, attached, config, flags)
    drop.inflight[isolated] = False
    for k in range(m):
        if any(f in UNTRUSTED_INTENSITY_FLAGS for f in flags[k]):
            # untrusted intensities: no number from this frame
            att_vol[k] = grown[k] = drop.drop_volume_nl[k] = drop.detached_volume_nl[k] = np.nan
            att_u[k] = drop.drop_volume_uncertainty_nl[k] = drop.detached_volume_uncertainty_nl[k] = np.nan
            drop.z_um[k] = drop.x_um[k] = np.nan
            flow[k] = np.nan
            drop.inflight[k] = False
    # --- main-drop track: position and volume consistent with the neighbouring delays -------
    check_track(delay, drop, config, flags, notes)
    # --- the stroke must grow the meniscus by the maximum stroke (delays stretched?) ------
    max_stroke_us = max_stroke_instant_us(meta, config)
    if not delay_lie and pinchoff_before_stroke_end(pinch, max_stroke_us, flags, notes):
        delay_lie = True
        pinch = float("nan")
    if (meniscus_at_rest and not delay_lie
            and growth_short_at_max_stroke(grown, delay, attached, grown_by_delay, pinch, max_stroke_us, config,
                                           flags, notes)):
        delay_lie = True
        pinch = float("nan")
    if delay_lie:
        flow[:] = np.nan
    # --- flow needs a plausible inner diameter -------------------------------------------
    inner_lie = check_nozzle(meta, drop, config, flags, notes)
    if inner_lie:
        flow[:] = np.nan
        for k in np.nonzero(attached)[0]:
            if q.IMPLAUSIBLE not in flags[k]:
                flags[k].append(q.IMPLAUSIBLE)
    inflight = drop.inflight
    line = fit_line(delay[inflight], drop.z_um[inflight])
    velocity, velocity_se = line.slope, line.slope_se
    if implausible_velocity(velocity, inflight, config, flags, notes):
        velocity = velocity_se = float("nan")
    if delay_lie:
        velocity = velocity_se = float("nan")
    # a pixel size measured off the needle: lengths and velocities scale with it
    velocity_se = float(np.hypot(velocity_se, float(getattr(cal, "pixel_size_relative_uncertainty", 0.0)) * velocity))
    floor_share = 0.0  # volumes carry no fixed floor: their sub-pixel error is in each frame's random part
    # the frames' own scatter, relative to their modelled random part (a scatter in nl read off the
    # large volumes would swamp the small meniscus's)
    model_rand = np.sqrt(np.maximum(att_u ** 2 - att_common ** 2 - att_plane ** 2, 0.0))
    ratio = frame_scatter_ratio(delay, vol_used, model_rand, attached)
    meniscus_u, grown_u, att_u = grown_uncertainty(delay, vol_used, att_u, att_common, att_plane, grown,
                                                   floor_share, scatter_ratio=ratio)
    # a pixel size measured off the needle (none given): its uncertainty scales every volume by its cube
    rel3 = 3.0 * float(getattr(cal, "pixel_size_relative_uncertainty", 0.0))
    if rel3 > 0:
        att_u, grown_u = np.hypot(att_u, rel3 * np.abs(att_vol)), np.hypot(grown_u, rel3 * np.abs(grown))
        meniscus_u = float(np.hypot(meniscus_u, rel3 * abs(meniscus)))
        drop.drop_volume_uncertainty_nl = np.hypot(drop.drop_volume_uncertainty_nl, rel3 * np.abs(drop.drop_volume_nl))
        drop.detached_volume_uncertainty_nl = np.hypot(drop.detached_volume_uncertainty_nl,
                                                       rel3 * np.abs(drop.detached_volume_nl))
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
        "attached_volume_uncertainty_nl": np.where(np.isfinite(att_vol), att_u, np.nan),
        "grown_volume_uncertainty_nl": grown_u,
        "drop_volume_uncertainty_nl": np.where(np.isfinite(drop.drop_volume_nl), drop.drop_volume_uncertainty_nl,
                                               np.nan),
        "detached_volume_uncertainty_nl": np.where(np.isfinite(drop.detached_volume_nl),
                                                   drop.detached_volume_uncertainty_nl, np.nan),
        "volume_uncertainty_source": [volume_uncertainty_source(cal)] * m,
    })
    frames = frames[sorted(frames.columns, key=_declared_order)]
    check_frames_table(frames, "the frames table built by dropvision.summary.assemble")
    # --- summary -------------------------------------------------------------------------
    last_att = delay[attached & (delay < pinch)] if np.isfinite(pinch) else delay[attached]
    g_pinch = float("nan")
    if np.isfinite(pinch) and last_att.size:
        at_last = grown[(delay == last_att.max()) & attached]
        at_last = at_last[np.isfinite(at_last)]
        g_pinch = float(np.mean(at_last)) if at_last.size else float("nan")
    inflight = drop.inflight
    inf_vol = drop.drop_volume_nl[inflight]
    inf_u = drop.drop_volume_uncertainty_nl[inflight]
    traj = fit_line(drop.z_um[inflight], drop.x_um[inflight])
    sats = drop.n_satellites[inflight & np.isfinite(drop.n_satellites)]
    flow_at_max_stroke_m_s = float("nan")
    if np.isfinite(max_stroke_us) and meta.nozzle_inner_diameter_um and not (delay_lie or inner_lie):
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
        "initial_meniscus_source": (schema.QUALITY_CODES[q.NO_REST_MENISCUS] if not meniscus_at_rest else
                                    f"attached volume of the first frame(s), delay {float(np.min(delay)):g} us <= dead time "
                                    f"{dead_time:g} us" if has_waveform else
                                    f"attached volume of the first delay's frame(s), {float(np.min(delay)):g} us (no "
                                    "waveform: assumed at rest)"),
        "inflight_volume_nl": float(np.mean(inf_vol)) if inf_vol.size else float("nan"),
        "inflight_volume_std_nl": float(np.std(inf_vol, ddof=1)) if inf_vol.size >= 2 else float("nan"),
        "inflight_frames": int(inf_vol.size),
        "inflight_volume_uncertainty_nl": inflight_uncertainty(inf_vol, inf_u),
        "grown_volume_at_pinchoff_uncertainty_nl": _grown_u_before(grown_u, delay, attached, pinch, g_pinch),
        "initial_meniscus_volume_uncertainty_nl": meniscus_u if meniscus_at_rest else float("nan"),
        "jetting_velocity_m_s": velocity,
        "jetting_velocity_se_m_s": velocity_se,
        "trajectory_angle_mrad": float(1000.0 * np.arctan(traj.slope)) if np.isfinite(traj.slope) else float("nan"),
        "satellites": int(np.median(sats)) if sats.size else None,
        "max_stroke_us": max_stroke_us,
        "flow_velocity_at_max_stroke_m_s": flow_at_max_stroke_m_s,
        "calibration": calib,
        "errors": errors,
        "quality_counts": frames["quality"].value_counts().to_dict(),
        "software": software_versions(),
        "config": asdict(config),
        "notes": notes,
    }
    if length_lie:
        for key in ("grown_volume_at_pinchoff_nl", "initial_meniscus_volume_nl", "inflight_volume_nl",
                    "inflight_volume_std_nl", "inflight_volume_uncertainty_nl",
                    "grown_volume_at_pinchoff_uncertainty_nl", "initial_meniscus_volume_uncertainty_nl",
                    "jetting_velocity_m_s", "jetting_velocity_se_m_s", "flow_velocity_at_max_stroke_m_s"):
            summary[key] = float("nan")
    return frames, summary


def frame_scatter_nl(delay, volume_nl, use) -> float:
    """The frames' own random scatter (nl), read off the sequence: the robust spread of the second
    differences of the volumes in delay order (``v_k - (v_(k-1) + v_(k+1)) / 2``, over
    sqrt(3/2)), 0 with fewer than 5 frames.  The smooth growth between neighbouring delays
    hardly enters at the paper's 10 µs steps; repeats at one delay give pure scatter.  A Type A
    estimate of what no edge model foresees (noise, compression, a strobe's flicker)."""
    delay = np.asarray(delay, float)
    ok = np.asarray(use, bool) & np.isfinite(volume_nl)
    if ok.sum() < 5:
        return 0.0
    order = np.argsort(delay[ok], kind="stable")
    v = np.asarray(volume_nl, float)[ok][order]
    d2 = v[1:-1] - 0.5 * (v[:-2] + v[2:])
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(1.5))


def volume_uncertainty_source(cal) -> str:
    """The largest measured part of the edge-position error a volume carries
    (`dropvision.bodies.common_edge_sigma_px`): the calibration's terms less its fixed "edge floor",
    which only the nozzle's diameter uses ("background level" when no other term is known)."""
    terms = {k: v for k, v in cal.edge_position_terms_px.items() if k != "edge floor"}
    return max(terms, key=terms.get) if terms else "background level"


def frame_scatter_ratio(delay, volume_nl, random_nl, use) -> float:
    """The frames' own random scatter over what their edge model foresees, read off the sequence.

    Like `frame_scatter_nl`, from the second differences of the volumes in delay order, but each
    over its expected spread from the frames' modelled random uncertainties ``random_nl``
    (``sqrt(r_k^2 + (r_(k-1)^2 + r_(k+1)^2) / 4)``): a body's random error grows with its edges,
    so a scatter in nl read off large volumes would be many times too wide for a small meniscus.
    The robust spread of these ratios (1 where the model holds); 0 with fewer than 5 frames
    whose modelled random uncertainty is positive.  The growth's curvature between neighbouring
    delays stays in (as in `frame_scatter_nl`); with third differences, which cancel it, the grown
    volumes' coverage fell to 0.53 on the synthetic sweep: their errors change smoothly with the
    shape (the attached volume +0.1 % during growth on the u70 sweep case, from its blur
    correction), and the curvature term, not noise, is what holds them: the ratio is 12-26 on the
    synthetic sweep's 20 us steps."""
    delay = np.asarray(delay, float)
    r = np.asarray(random_nl, float)
    ok = np.asarray(use, bool) & np.isfinite(volume_nl) & np.isfinite(r) & (r > 0)
    if ok.sum() < 5:
        return 0.0
    order = np.argsort(delay[ok], kind="stable")
    v = np.asarray(volume_nl, float)[ok][order]
    r = r[ok][order]
    d2 = v[1:-1] - 0.5 * (v[:-2] + v[2:])
    z = d2 / np.sqrt(r[1:-1] ** 2 + 0.25 * (r[:-2] ** 2 + r[2:] ** 2))
    return float(1.4826 * np.median(np.abs(z - np.median(z))))


def grown_uncertainty(delay, attached_nl, attached_u_nl, common_u_nl, plane_u_nl,
                      grown_nl, floor_share: float = 0.0,
                      scatter_nl: float = 0.0, scatter_ratio: float = 0.0) -> tuple[float, np.ndarray, np.ndarray]:
    """Standard uncertainties (nl) of the initial meniscus, of every frame's grown volume and of
    its attached volume.

    The meniscus is the mean attached volume at the first delay: its uncertainty is its frames'
    mean uncertainty and the standard error of their scatter in quadrature.  A grown volume is
    the difference of two volumes measured with the same edge error and tip plane: of the common
    edge error only the difference ``|common - common_meniscus|`` is left, of the plane nothing;
    the edges' own noise of both and the meniscus' scatter add in quadrature.  The edge floor's
    share of the common error (``floor_share``: sub-pixel interpolation, which changes with the
    silhouette's shape) is taken as independent between the two frames.  A frame's random part is
    at least the sequence's own scatter ``scatter_nl`` (`frame_scatter_nl`) and at least its
    modelled random part times ``scatter_ratio`` (`frame_scatter_ratio`); the attached volumes'
    uncertainties are returned with it.
    """
    delay = np.asarray(delay, float)
    first = (delay == np.min(delay)) & np.isfinite(attached_nl) if delay.size else np.zeros(0, bool)
    model_rand = np.sqrt(np.maximum(attached_u_nl ** 2 - common_u_nl ** 2 - plane_u_nl ** 2, 0.0))
    rand = np.maximum(model_rand * max(float(scatter_ratio), 1.0), scatter_nl)
    attached_u_nl = np.sqrt(np.maximum(attached_u_nl ** 2 - model_rand ** 2, 0.0) + rand ** 2)
    if not first.any():
        return float("nan"), np.full(delay.size, np.nan), attached_u_nl
    n0 = int(first.sum())
    u0 = float(np.mean(attached_u_nl[first]))
    se = float(np.std(attached_nl[first], ddof=1) / np.sqrt(n0)) if n0 >= 2 else 0.0
    c0, r0 = float(np.mean(common_u_nl[first])), float(np.mean(rand[first]))
    f2 = floor_share ** 2
    u_grown = np.sqrt((1.0 - f2) * (common_u_nl - c0) ** 2 + f2 * (common_u_nl ** 2 + c0 ** 2)
                      + rand ** 2 + r0 ** 2 / n0 + se ** 2)
    return float(np.hypot(u0, se)), np.where(np.isfinite(grown_nl), u_grown, np.nan), attached_u_nl


def inflight_uncertainty(volumes_nl: np.ndarray, uncertainties_nl: np.ndarray) -> float:
    """Standard uncertainty (nl) of the mean in-flight volume: the frames' common edge
    uncertainty (it does not average out) and the standard error of their scatter, in quadrature."""
    ok = np.isfinite(volumes_nl) & np.isfinite(uncertainties_nl)
    if not ok.any():
        return float("nan")
    se = float(np.std(volumes_nl[ok], ddof=1) / np.sqrt(ok.sum())) if ok.sum() >= 2 else 0.0
    return float(np.hypot(np.mean(uncertainties_nl[ok]), se))


def _grown_u_before(grown_u, delay, attached, pinch, g_pinch) -> float:
    """Uncertainty of the grown volume at the last attached delay before the pinch-off (nl)."""
    if not np.isfinite(g_pinch):
        return float("nan")
    last = delay[attached & (delay < pinch) & np.isfinite(grown_u)]
    if not last.size:
        return float("nan")
    return float(np.mean(grown_u[attached & (delay == last.max()) & np.isfinite(grown_u)]))


def _declared_order(column: str) -> int:
    """Position of ``column`` in `FRAME_COLUMNS` (undeclared columns last, for the check to name)."""
    return FRAME_COLUMNS.index(column) if column in FRAME_COLUMNS else len(FRAME_COLUMNS)


def check_frames_table(frames: pd.DataFrame, source) -> None:
    """Check the frames table against its schema (`dvcore.schema.FRAMES`) before it is used or written.

    Parameters
    ----------
    frames : DataFrame
        The frames table.
    source : str or Path
        What it is (a file being written, or where it was built), named in the error.

    Raises
    ------
    dvcore.schema.SchemaError
        Naming ``source`` and the first offending column: one missing, one not declared in the
        schema, columns out of the declared order, a wrong dtype, a missing value where the
        schema allows none, or an infinite value (what `dvcore.schema.check_table` refuses when
        the file is read back).
    """
    missing = [c for c in FRAME_COLUMNS if c not in frames.columns]
    if missing:
        raise schema.SchemaError(f"{source}: missing column {missing[0]!r} of {schema.FRAMES.schema} "
                                 f"(declared in dvcore/schema.py FRAMES)"
                                 + (f"; also missing: {', '.join(missing[1:])}" if missing[1:] else ""))
    extra = [c for c in frames.columns if c not in FRAME_COLUMNS]
    if extra:
        raise schema.SchemaError(f"{source}: column {extra[0]!r} is not declared in {schema.FRAMES.schema} "
                                 "(dvcore/schema.py FRAMES): declare it there or do not write it")
    if list(frames.columns) != FRAME_COLUMNS:
        raise schema.SchemaError(f"{source}: columns not in the order declared by {schema.FRAMES.schema} "
                                 "(dvcore/schema.py FRAMES)")
    # the same check a reader applies (dropvision.app.campaign reads shards back with it): dtypes,
    # missing values where not allowed, no infinities (an unmeasurable value is NaN and flagged)
    schema.check_table(frames, schema.FRAMES, source)


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
    import pandas as pd
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

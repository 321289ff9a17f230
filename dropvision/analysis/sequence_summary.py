"""Sequence-level analysis of the per-frame records: the frames table and the summary.

`assemble` is a pipeline of named steps over the sequence's values (`SequenceValues`): the
pinch-off and attached frames (`find_pinchoff`, `dropvision.analysis.pinchoff`), grown volume and flow
velocity relative to the meniscus at rest (`grow_from_rest`, `dropvision.analysis.flow`), the main drop in
every frame (`dropvision.analysis.tracking`), the plausibility checks (`dropvision.analysis.plausibility`), the
uncertainties (`volume_uncertainties`), then the ``frames`` table (`frames_table`,
`FRAME_COLUMNS`) and the ``summary`` dict (`summary_dict`).  Every check returns findings
(`dropvision.analysis.findings.Finding`: quality code, frames, note, outputs withheld); `apply_findings`
is the one place that applies them, and `withhold` blanks the withheld outputs at the end.
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

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

import dropvision.quality as q
from dropvision.calibrate.calibration import EDGE_FLOOR_TERM, Calibration
from dropvision.config import MeasureConfig
from dropvision.analysis.findings import WITHHELD_FRAME_COLUMNS, WITHHELD_SUMMARY_KEYS, Finding, Withheld, frames_of
from dropvision.analysis.flow import flow_velocity_at, grown_and_flow
from dropvision.frame.measure_frame import FrameRecord
from dropvision.analysis.pinchoff import isolated_detached, pinchoff_bracket_problem, pinchoff_delay
from dropvision.analysis.plausibility import (attached_volume_outliers, check_nozzle, check_pixel_size, check_track, delays_text,
                                     growth_short_at_max_stroke, implausible_velocity, mean_at_last_attached_delay,
                                     pinchoff_before_dead_time, pinchoff_before_stroke_end)
from dropvision.quality import UNTRUSTED_INTENSITY_FLAGS
from dvcore.robust import robust_sigma
from dropvision.analysis.tracking import DropTrack, LineFit, fit_line, track_main_drop
from dvcore import schema
from dvcore.versions import software_versions
from dvcore.waveform import Waveform

if TYPE_CHECKING:  # pandas loads where a table is made, not at start-up
    import pandas as pd

SCHEMA_VERSION = schema.SUMMARY.schema
#: Columns of frames.parquet, in order (declared with dtype, unit and meaning in `dvcore.schema.FRAMES`).
FRAME_COLUMNS = schema.FRAMES.column_names
PER_DELAY_COLUMNS = [name for name, _ in schema.PER_DELAY_SOURCES]
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


@dataclass
class SequenceValues:
    """The sequence-level values while `assemble` works them out (arrays: one entry per record).

    The steps compute them; the checks' findings change them only through `apply_findings`.
    """

    delay_us: np.ndarray
    flags: list[list[str]]
    notes: list[str]
    attached_nl: np.ndarray  # attached volume per frame (NaN where its numbers are withheld)
    attached_u_nl: np.ndarray
    attached_common_u_nl: np.ndarray
    attached_plane_u_nl: np.ndarray
    detached: np.ndarray  # bool: the frame shows a detached body
    used_nl: np.ndarray  # attached volumes used for the meniscus, the growth and the flow
    pinch_us: float = float("nan")
    attached: np.ndarray | None = None  # bool: before the pinch-off without a detached drop
    grown_nl: np.ndarray | None = None
    flow_m_s: np.ndarray | None = None
    meniscus_nl: float = float("nan")
    grown_by_delay: pd.Series | None = None
    meniscus_at_rest: bool = False
    drop: DropTrack | None = None
    not_inflight: np.ndarray | None = None  # frames a finding holds out of flight
    unmeasured: np.ndarray | None = None  # frames a finding takes every number from
    out_of_growth: np.ndarray | None = None  # attached volumes a finding leaves out of the growth
    withheld: set = field(default_factory=set)
    attached_halo_nl: np.ndarray | None = None  # the walls' halo below their face (AttachedLiquid.face_halo_nl)
    attached_plane_position_u_nl: np.ndarray | None = None  # AttachedLiquid.plane_position_uncertainty_nl
    attached_halo_band_nl: np.ndarray | None = None  # AttachedLiquid.halo_band_nl

    @classmethod
    def of(cls, records: list[FrameRecord]) -> SequenceValues:
        """The values read off the records, nothing decided yet."""
        att = np.array([r.attached_volume_nl for r in records], float)
        m = len(records)
        return cls(delay_us=np.array([r.delay_us for r in records], float), flags=[list(r.flags) for r in records],
                   notes=[], attached_nl=att,
                   attached_u_nl=np.array([r.attached_volume_uncertainty_nl for r in records], float),
                   attached_common_u_nl=np.array([r.attached_common_uncertainty_nl for r in records], float),
                   attached_plane_u_nl=np.array([r.attached_plane_uncertainty_nl for r in records], float),
                   detached=np.array([bool(r.bodies) for r in records], bool), used_nl=att.copy(),
                   not_inflight=np.zeros(m, bool), unmeasured=np.zeros(m, bool), out_of_growth=np.zeros(m, bool),
                   attached_halo_nl=np.array([r.attached_face_halo_nl for r in records], float),
                   attached_plane_position_u_nl=np.array([r.attached_plane_position_uncertainty_nl for r in records],
                                                         float),
                   attached_halo_band_nl=np.array([r.attached_halo_band_nl for r in records], float))


def apply_findings(s: SequenceValues, findings: list[Finding]) -> None:
    """The one place where what the checks found changes the sequence: each finding's quality
    code goes to its frames (once), its note to the notes, and its withheld outputs are recorded;
    then every withheld value the later steps use is made NaN (`_enforce_withheld`).  What is
    withheld only in the outputs (flow, jetting velocity, length-scaled values) is blanked at the
    end by `withhold`."""
    for f in findings:
        if f.flag is not None:
            for k in f.frames:
                if f.flag not in s.flags[k]:
                    s.flags[k].append(f.flag)
        if f.note:
            s.notes.append(f.note)
        frames = list(f.frames)
        if Withheld.INFLIGHT in f.withheld:
            s.not_inflight[frames] = True
        if Withheld.FRAME_NUMBERS in f.withheld:
            s.unmeasured[frames] = True
        if Withheld.ATTACHED_IN_GROWTH in f.withheld:
            s.out_of_growth[frames] = True
        s.withheld |= f.withheld
    _enforce_withheld(s)


def _enforce_withheld(s: SequenceValues) -> None:
    """Make NaN what is withheld so far, in the values computed so far (repeatable)."""
    if Withheld.PINCHOFF in s.withheld:
        s.pinch_us = float("nan")
    s.used_nl[s.out_of_growth] = np.nan
    bad = s.unmeasured
    if s.grown_nl is not None:
        if Withheld.GROWN in s.withheld:
            s.grown_nl[:] = np.nan
            s.flow_m_s[:] = np.nan
            s.grown_by_delay = s.grown_by_delay.iloc[0:0]
            s.meniscus_nl = float("nan")
        s.grown_nl[bad] = np.nan
        s.flow_m_s[bad] = np.nan
    s.attached_nl[bad] = np.nan
    s.attached_u_nl[bad] = np.nan
    if s.drop is not None:
        d = s.drop
        for values in (d.drop_volume_nl, d.detached_volume_nl, d.drop_volume_uncertainty_nl,
                       d.detached_volume_uncertainty_nl, d.drop_volume_random_uncertainty_nl, d.z_um, d.x_um):
            if values is not None:
                values[bad] = np.nan
        d.inflight[s.not_inflight | bad] = False


def withhold(frames: pd.DataFrame, summary: dict, withheld) -> tuple[pd.DataFrame, dict]:
    """Blank the frame columns and summary keys of the ``withheld`` outputs (declared in
    `dropvision.analysis.findings.WITHHELD_FRAME_COLUMNS` and `WITHHELD_SUMMARY_KEYS`)."""
    for out in withheld:
        for col in WITHHELD_FRAME_COLUMNS.get(out, ()):
            frames[col] = np.nan
        for key in WITHHELD_SUMMARY_KEYS.get(out, ()):
            summary[key] = float("nan")
    return frames, summary


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
    s = SequenceValues.of(records)
    m = len(records)
    has_waveform = bool(getattr(meta, "waveform", None))
    dead_time = dead_time_us(meta, config)
    apply_findings(s, not_drop_images(records))
    apply_findings(s, check_pixel_size(cal, meta, config, m, dead_time if has_waveform else None))
    find_pinchoff(s, has_waveform, dead_time, config)
    s.attached = ~s.detached & ((s.delay_us < s.pinch_us) if np.isfinite(s.pinch_us) else True)
    if cal.nozzle_out_of_focus:
        apply_findings(s, [Finding(q.NOZZLE_OUT_OF_FOCUS, frames_of(s.attached))])
    apply_findings(s, attached_volume_outliers(s.delay_us, s.attached_nl, s.attached, config))
    grow_from_rest(s, meta.nozzle_inner_diameter_um, has_waveform, dead_time)
    s.drop, found = track_main_drop(records, s.attached, config, s.flags)
    apply_findings(s, found)
    apply_findings(s, untrusted_frames(s.flags))
    apply_findings(s, check_track(s.delay_us, s.drop, config))
    max_stroke_us = max_stroke_instant_us(meta, config)
    apply_findings(s, pinchoff_before_stroke_end(s.pinch_us, max_stroke_us, m))
    apply_findings(s, growth_short_at_max_stroke(s.grown_nl, s.delay_us, s.attached, s.grown_by_delay, s.pinch_us,
                                                 max_stroke_us, config))
    apply_findings(s, check_nozzle(meta, s.drop, s.attached, config))
    velocity = fit_line(s.delay_us[s.drop.inflight], s.drop.z_um[s.drop.inflight])
    apply_findings(s, implausible_velocity(velocity.slope, s.drop.inflight, config))
    unc = volume_uncertainties(s, cal)
    frames = frames_table(records, s, unc, volume_uncertainty_source(cal))
    summary = summary_dict(s, unc, frames, velocity, max_stroke_us, cal, sigma_px, meta, config, errors,
                           meniscus_source(s, has_waveform, dead_time))
    frames, summary = withhold(frames, summary, s.withheld)
    check_frames_table(frames, "the frames table built by dropvision.analysis.sequence_summary.assemble")
    return frames, summary


def not_drop_images(records: list[FrameRecord]) -> list[Finding]:
    """A note naming the frames that look like no backlit drop image (flagged by the frame step)."""
    not_drop = [r.file for r in records if q.NOT_DROP_IMAGE in r.flags]
    if not not_drop:
        return []
    return [Finding(note=f"{len(not_drop)} frame(s) look like no backlit drop image ({', '.join(not_drop[:3])}"
                         f"{', ...' if len(not_drop) > 3 else ''}): less than half of each is bright background "
                         f"(within {q.BACKGROUND_TOLERANCE:.0%} of the local background level); nothing measured "
                         "in them")]


def find_pinchoff(s: SequenceValues, has_waveform: bool, dead_time: float, config: MeasureConfig) -> None:
    """The pinch-off delay (``s.pinch_us``): a detached delay between attached ones is a foreign
    frame, left out (and out of flight); a pinch-off before the dead time is a delay lie; one not
    bracketed by consecutive delays is undefined (`dropvision.analysis.pinchoff`)."""
    delay, m = s.delay_us, s.delay_us.size
    isolated = isolated_detached(delay, s.detached)
    if isolated.any():
        apply_findings(s, [Finding(q.NEIGHBOURS, frames_of(isolated),
                                   f"{int(isolated.sum())} frame(s) show a detached drop between attached delays "
                                   f"({delays_text(delay[isolated])} us): inconsistent with their neighbours, left out",
                                   frozenset({Withheld.INFLIGHT}))])
    s.pinch_us = pinchoff_delay(delay[~isolated], s.detached[~isolated]) if (~isolated).any() else float("nan")
    if not has_waveform:
        apply_findings(s, [Finding(note="no waveform in sequence.json: no waveform-based check (dead time, end of "
                                        "the stroke) is run and the first delay's frames are taken as the meniscus "
                                        "at rest")])
    else:
        apply_findings(s, pinchoff_before_dead_time(s.pinch_us, dead_time, m))
    problem = pinchoff_bracket_problem(delay[~isolated], s.pinch_us, config.min_pinchoff_frames)
    if problem is not None and np.unique(delay).size == 1:
        # one delay (single frames of a drop watcher, a pendant drop): no series, nothing to flag
        apply_findings(s, [Finding(note="one delay only: no pinch-off (it needs a delay series)",
                                   withheld=frozenset({Withheld.PINCHOFF}))])
    elif problem is not None:
        d_u = np.unique(delay[~isolated])
        before = d_u[d_u < s.pinch_us]
        involved = (delay == s.pinch_us) | ((delay == before.max()) if before.size else False)
        if m < config.min_pinchoff_frames:
            involved = np.ones(m, bool)
        apply_findings(s, [Finding(q.PINCHOFF_UNDEFINED, frames_of(involved & ~isolated), problem,
                                   frozenset({Withheld.PINCHOFF}))])


def grow_from_rest(s: SequenceValues, inner_diameter_um, has_waveform: bool, dead_time: float) -> None:
    """Grown volume and flow velocity relative to the meniscus at rest (`dropvision.analysis.flow`).

    The grown volume is relative to the initial meniscus (Section 4.1.1): that needs a frame
    taken before the piston moves (delay <= dead time; without a waveform, the first delay's
    frames all attached).  Without one, no grown volume or flow (``no_rest_meniscus``)."""
    s.grown_nl, s.flow_m_s, s.meniscus_nl, s.grown_by_delay = grown_and_flow(s.delay_us, s.used_nl, s.attached,
                                                                           inner_diameter_um)
    first = float(np.min(s.delay_us)) if s.delay_us.size else float("nan")
    s.meniscus_at_rest = bool(s.delay_us.size) and (first <= dead_time if has_waveform
                                                 else bool(s.attached[s.delay_us == first].all()))
    apply_findings(s, [] if s.meniscus_at_rest else
                   [Finding(q.NO_REST_MENISCUS, frames_of(s.attached), withheld=frozenset({Withheld.GROWN}))])


def untrusted_frames(flags: list[list[str]]) -> list[Finding]:
    """Frames whose intensities are not trusted (`dropvision.quality.UNTRUSTED_INTENSITY_FLAGS`): no number
    from them."""
    bad = [any(f in UNTRUSTED_INTENSITY_FLAGS for f in fl) for fl in flags]
    return [Finding(frames=frames_of(bad), withheld=frozenset({Withheld.FRAME_NUMBERS}))] if any(bad) else []


def meniscus_source(s: SequenceValues, has_waveform: bool, dead_time: float) -> str:
    """Where the initial meniscus volume comes from (the summary's ``initial_meniscus_source``)."""
    if not s.meniscus_at_rest:
        return schema.QUALITY_CODES[q.NO_REST_MENISCUS]
    first = float(np.min(s.delay_us))
    if has_waveform:
        return f"attached volume of the first frame(s), delay {first:g} us <= dead time {dead_time:g} us"
    return f"attached volume of the first delay's frame(s), {first:g} us (no waveform: assumed at rest)"


@dataclass(frozen=True)
class VolumeUncertainties:
    """Standard uncertainties (nl) of the volumes: per frame, and of the initial meniscus."""

    attached_u_nl: np.ndarray
    grown_u_nl: np.ndarray
    meniscus_u_nl: float
    drop_u_nl: np.ndarray
    detached_u_nl: np.ndarray


def volume_uncertainties(s: SequenceValues, cal: Calibration) -> VolumeUncertainties:
    """The volumes' uncertainties: each frame's own (random part widened to the sequence's own
    scatter, `frame_scatter_ratio`; grown volumes `grown_uncertainty`), and a pixel size measured
    off the needle, which scales every volume by its cube."""
    delay, attached = s.delay_us, s.attached
    att_vol, attached_u_nl = s.attached_nl, s.attached_u_nl
    att_common, att_plane = s.attached_common_u_nl, s.attached_plane_u_nl
    grown, meniscus = s.grown_nl, s.meniscus_nl
    drop_u, det_u = s.drop.drop_volume_uncertainty_nl, s.drop.detached_volume_uncertainty_nl
    floor_share = 0.0  # volumes carry no fixed floor: their sub-pixel error is in each frame's random part
    # the frames' own scatter, relative to their modelled random part (a scatter in nl read off the
    # large volumes would swamp the small meniscus's)
    model_rand = np.sqrt(np.maximum(attached_u_nl ** 2 - att_common ** 2 - att_plane ** 2, 0.0))
    z, _ = _scatter_z(delay, s.used_nl, model_rand, attached)
    ratio = np.maximum(robust_sigma(z) * student_factor(z.size) if z.size else 0.0,
                       local_scatter_ratio(delay, s.used_nl, model_rand, attached))
    meniscus_u, grown_u, attached_u_nl = grown_uncertainty(delay, s.used_nl, attached_u_nl, att_common, att_plane,
                                                           grown, floor_share, scatter_ratio=ratio,
                                                           halo_nl=s.attached_halo_nl,
                                                           plane_position_u_nl=s.attached_plane_position_u_nl,
                                                           halo_band_nl=s.attached_halo_band_nl)
    # the main drop's random part at least the in-flight drops' own scatter (`drop_scatter_ratio`)
    drop_u = widened_drop_uncertainty(drop_u, s.drop.drop_volume_random_uncertainty_nl,
                                      drop_scatter_ratio(s.drop.drop_volume_nl, s.drop.drop_volume_random_uncertainty_nl,
                                                         s.drop.inflight, delay))
    # a pixel size measured off the needle (none given): its uncertainty scales every volume by its cube
    rel3 = 3.0 * float(getattr(cal, "pixel_size_relative_uncertainty", 0.0))
    if rel3 > 0:
        attached_u_nl = np.hypot(attached_u_nl, rel3 * np.abs(att_vol))
        grown_u = np.hypot(grown_u, rel3 * np.abs(grown))
        meniscus_u = float(np.hypot(meniscus_u, rel3 * abs(meniscus)))
        drop_u = np.hypot(drop_u, rel3 * np.abs(s.drop.drop_volume_nl))
        det_u = np.hypot(det_u, rel3 * np.abs(s.drop.detached_volume_nl))
    return VolumeUncertainties(attached_u_nl, grown_u, meniscus_u, drop_u, det_u)


def jetting_velocity_se(line: LineFit, cal: Calibration) -> float:
    """Standard error of the jetting velocity (m/s): the line fit's, and a pixel size measured off
    the needle (lengths and velocities scale with it), in quadrature."""
    return float(np.hypot(line.slope_se, float(getattr(cal, "pixel_size_relative_uncertainty", 0.0)) * line.slope))


def frames_table(records: list[FrameRecord], s: SequenceValues, unc: VolumeUncertainties,
                 uncertainty_source: str) -> pd.DataFrame:
    """The frames table (`FRAME_COLUMNS`, in their declared order) of the worked-out values."""
    import pandas as pd
    drop = s.drop
    frames = pd.DataFrame({
        "file": [r.file for r in records],
        "page": pd.array([r.page for r in records], dtype="Int64"),
        "delay_us": s.delay_us,
        "repeat": np.array([r.repeat for r in records], int),
        "attached": s.attached.astype(bool),
        "attached_volume_nl": s.attached_nl,
        "grown_volume_nl": s.grown_nl,
        "drop_volume_nl": drop.drop_volume_nl,
        "detached_volume_nl": drop.detached_volume_nl,
        "drop_z_um": drop.z_um,
        "drop_x_um": drop.x_um,
        "n_satellites": pd.array([None if not np.isfinite(v) else int(v) for v in drop.n_satellites], dtype="Int64"),
        "flow_velocity_m_s": s.flow_m_s,
        "quality": [q.join([f for f in fl if f not in INFLIGHT_ONLY_FLAGS]) for fl in s.flags],
        "drop_length_um": drop.length_um,
        "drop_diameter_um": drop.diameter_um,
        "inflight": drop.inflight,
        "neck_px": np.array([r.neck_px for r in records], float),
        "blur_px": np.array([r.blur_px for r in records], float),
        "wall_contrast": np.array([r.wall_contrast for r in records], float),
        "gain": np.array([r.gain for r in records], float),
        "attached_volume_uncertainty_nl": np.where(np.isfinite(s.attached_nl), unc.attached_u_nl, np.nan),
        "grown_volume_uncertainty_nl": unc.grown_u_nl,
        "drop_volume_uncertainty_nl": np.where(np.isfinite(drop.drop_volume_nl), unc.drop_u_nl, np.nan),
        "detached_volume_uncertainty_nl": np.where(np.isfinite(drop.detached_volume_nl), unc.detached_u_nl, np.nan),
        "volume_uncertainty_source": [uncertainty_source] * len(records),
    })
    return frames[sorted(frames.columns, key=_declared_order)]


def summary_dict(s: SequenceValues, unc: VolumeUncertainties, frames: pd.DataFrame, velocity: LineFit,
                 max_stroke_us: float, cal: Calibration, sigma_px: float, meta, config: MeasureConfig,
                 errors: list[dict], meniscus_from: str) -> dict:
    """The summary (``schema_version`` `SCHEMA_VERSION`) of the worked-out values, before `withhold`."""
    drop, inflight, pinch = s.drop, s.drop.inflight, s.pinch_us
    grown_at_pinchoff_nl = mean_at_last_attached_delay(s.grown_nl, s.delay_us, s.attached, pinch, skip_unmeasured=False)
    inf_vol = drop.drop_volume_nl[inflight]
    traj = fit_line(drop.z_um[inflight], drop.x_um[inflight])
    sats = drop.n_satellites[inflight & np.isfinite(drop.n_satellites)]
    flow_at_max_stroke_m_s = float("nan")
    if np.isfinite(max_stroke_us) and meta.nozzle_inner_diameter_um:
        flow_at_max_stroke_m_s = flow_velocity_at(s.grown_by_delay, max_stroke_us, meta.nozzle_inner_diameter_um)
    calib = cal.to_dict()
    calib["edge_blur_sigma_px"] = sigma_px
    calib["orientation"] = meta.orientation
    return {
        "schema_version": SCHEMA_VERSION,
        "sequence": str(meta.path),
        "n_frames": int(len(meta.frames)),
        "n_measured": int(s.delay_us.size),
        "pinchoff_us": pinch,
        "grown_volume_at_pinchoff_nl": grown_at_pinchoff_nl,
        "initial_meniscus_volume_nl": s.meniscus_nl,
        "initial_meniscus_source": meniscus_from,
        "inflight_volume_nl": float(np.mean(inf_vol)) if inf_vol.size else float("nan"),
        "inflight_volume_std_nl": float(np.std(inf_vol, ddof=1)) if inf_vol.size >= 2 else float("nan"),
        "inflight_frames": int(inf_vol.size),
        "inflight_volume_uncertainty_nl": inflight_uncertainty(inf_vol, unc.drop_u_nl[inflight]),
        "grown_volume_at_pinchoff_uncertainty_nl": (mean_at_last_attached_delay(unc.grown_u_nl, s.delay_us, s.attached,
                                                                                pinch)
                                                    if np.isfinite(grown_at_pinchoff_nl) else float("nan")),
        "initial_meniscus_volume_uncertainty_nl": unc.meniscus_u_nl if s.meniscus_at_rest else float("nan"),
        "jetting_velocity_m_s": velocity.slope,
        "jetting_velocity_se_m_s": jetting_velocity_se(velocity, cal),
        "trajectory_angle_mrad": float(1000.0 * np.arctan(traj.slope)) if np.isfinite(traj.slope) else float("nan"),
        "satellites": int(np.median(sats)) if sats.size else None,
        "max_stroke_us": max_stroke_us,
        "flow_velocity_at_max_stroke_m_s": flow_at_max_stroke_m_s,
        "calibration": calib,
        "errors": errors,
        "quality_counts": frames["quality"].value_counts().to_dict(),
        "software": software_versions(),
        "config": asdict(config),
        "notes": s.notes,
    }


def volume_uncertainty_source(cal) -> str:
    """The largest measured part of the edge-position error a volume carries
    (`dropvision.frame.bodies.common_edge_sigma_px`): the calibration's terms less its fixed "edge floor",
    which only the nozzle's diameter uses ("background level" when no other term is known)."""
    terms = {k: v for k, v in cal.edge_position_terms_px.items() if k != EDGE_FLOOR_TERM}
    return max(terms, key=terms.get) if terms else "background level"


def frame_scatter_ratio(delay, volume_nl, random_nl, use) -> float:
    """The frames' own random scatter over what their edge model foresees, read off the sequence.

    Two kinds of differences that a smooth growth does not enter, each over its expected spread
    from the frames' modelled random uncertainties ``random_nl`` (a body's random error grows with
    its edges, so a scatter in nl read off large volumes would be many times too wide for a small
    meniscus): repeats at one delay, each frame's deviation from their mean (expected spread
    ``sqrt(r_i^2 (1 - 2/n) + sum(r^2) / n^2)``); and the third divided differences of the
    per-delay means over four neighbouring delays (``sum_i w_i m_i``, ``w_i = 1 / prod_(j != i)
    (t_i - t_j)``: zero for any quadratic, whatever the spacing; expected spread
    ``sqrt(sum_i w_i^2 s_i^2)`` with ``s_i`` the means' modelled spread).  The robust spread of
    these ratios (1 where the model holds); 0 with fewer than 5 frames whose modelled random
    uncertainty is positive, or nothing to difference.  Second differences left the growth's
    curvature between delays in, read as scatter: the ratio was 11-34 on the synthetic tiers'
    20 µs steps (every random part that many times too wide)."""
    z, _ = _scatter_z(delay, volume_nl, random_nl, use)
    return robust_sigma(z) if z.size else 0.0


#: How many of the differences nearest in delay `local_scatter_ratio` reads.
LOCAL_SCATTER_DIFFERENCES = 21
#: Neighbouring third differences share three of their four values (correlations -3/4, 3/10, -1/20
#: at lags 1 to 3): a spread read off ``k`` of them is as sure as one off ``k / (1 + 2 sum rho^2)
#: = k / 2.31`` independent values.
THIRD_DIFFERENCE_SHARE = 1.0 + 2.0 * (0.75 ** 2 + 0.3 ** 2 + 0.05 ** 2)
#: Asymptotic efficiency of the median absolute deviation against the standard deviation for
#: Gaussian values (`dvcore.robust.robust_sigma`): a spread read off ``k`` values by it is as
#: sure as a standard deviation of ``0.37 k``.
MAD_EFFICIENCY = 0.3675


def student_factor(k: int) -> float:
    """How much wider than 1.96 a 95 % interval must be when its scale is a robust spread of ``k``
    values: Student's ``t(0.975, nu) / 1.96`` with ``nu = MAD_EFFICIENCY k / THIRD_DIFFERENCE_SHARE``
    degrees of freedom (at least 1), by its Cornish-Fisher expansion (``nu`` 4: 1.41, the exact 1.42; 1 for ``k``
    large).  A ratio read off few differences is itself uncertain: used as if exact, the ±2u
    interval would hold less than 95 % of the frames."""
    nu = max(MAD_EFFICIENCY * float(k) / THIRD_DIFFERENCE_SHARE, 1.0)
    z = 1.959964
    t = (z + (z ** 3 + z) / (4.0 * nu) + (5.0 * z ** 5 + 16.0 * z ** 3 + 3.0 * z) / (96.0 * nu ** 2)
         + (3.0 * z ** 7 + 19.0 * z ** 5 + 17.0 * z ** 3 - 15.0 * z) / (384.0 * nu ** 3))
    return t / z


def drop_scatter_ratio(volume_nl, random_nl, inflight, delay_us=None) -> float:
    """The in-flight main drops' own scatter over what their edges' noise foresees, read off the sequence.

    A drop in flight keeps its volume: the differences between consecutive in-flight frames (in
    the order of their delays ``delay_us``; the frames' order without them) at different delays are
    the frames' random errors, each over its expected spread ``sqrt(r_i^2 + r_(i+1)^2)`` from the
    frames' modelled random parts ``random_nl``.  Repeats at one delay put the drop at the same
    place: their differences miss its sampling (below).  On the synthetic sweep with three repeats
    a delay (12 delays in flight, 11 steps between them: a coarse reading) the frames' order read
    0.89-1.33 over 6 seeds, the steps 0.59-1.89.  Their robust spread: 1
    where the model holds, a satellite merging into the drop one outlying difference; 0 with
    fewer than 5 differences (a single frame, a short flight).

    What the model misses is the silhouette's sampling: where the rows cut a drop's poles and
    where its near-vertical sides fall between pixel centres change as it flies, the same error
    for every edge of a stretch, not independent noise.  A noise-free drawn sphere of 35 px radius
    at random sub-pixel places scatters 21-33 px^3 (blur 1.5-0.8 px); the synthetic 8-bit sweep
    case's drops 0.004-0.0075 nl from frame to frame, noise-free 0.003-0.005 nl, against
    0.0031 nl modelled (the differences read 0.0033-0.0097 nl).  The spread itself is used, not
    its `student_factor` reach as for the attached volumes' (whose scatter is their random part's
    only measure): on 8-20 differences the factor (2.2-1.3) made the drops' uncertainty 2-3 times
    their errors where their scatter agrees with the model (the 1.5 px blur case: median
    |error| / u 0.26 against 0.33)."""
    v = np.asarray(volume_nl, float)
    r = np.asarray(random_nl, float) if random_nl is not None else np.full(v.size, np.nan)
    ok = np.asarray(inflight, bool) & np.isfinite(v) & np.isfinite(r) & (r > 0)
    d = np.arange(v.size, dtype=float) if delay_us is None else np.asarray(delay_us, float)
    ok &= np.isfinite(d)
    order = np.argsort(d[ok], kind="stable")
    v, r, d = v[ok][order], r[ok][order], d[ok][order]
    # repeats at one delay put the drop at the same place: their differences miss its sampling
    step = np.diff(d) != 0
    if np.count_nonzero(step) < 5:
        return 0.0
    z = (np.diff(v) / np.sqrt(r[1:] ** 2 + r[:-1] ** 2))[step]
    return robust_sigma(z)


def widened_drop_uncertainty(drop_u_nl, random_nl, ratio: float) -> np.ndarray:
    """The main drop's uncertainties with their random part ``random_nl`` times ``ratio`` where that is
    more than 1 (`drop_scatter_ratio`), the rest kept: ``sqrt(u^2 + (ratio^2 - 1) r^2)``."""
    u = np.asarray(drop_u_nl, float)
    if random_nl is None or not ratio > 1.0:
        return u
    r = np.nan_to_num(np.asarray(random_nl, float))
    return np.sqrt(u * u + (ratio * ratio - 1.0) * r * r)


def local_scatter_ratio(delay, volume_nl, random_nl, use) -> np.ndarray:
    """`frame_scatter_ratio` read near each frame: the robust spread of the `LOCAL_SCATTER_DIFFERENCES`
    differences nearest to its delay, times `student_factor` of their count (0 where there are fewer,
    or fewer than 5 frames).  The model's random part can be off by a different factor for a small
    resting meniscus (a few rows at the plane) than for a large drop: on the synthetic out-of-focus
    holder the resting frames scattered about 0.006 nl against 0.0002 nl modelled, the sequence as a
    whole 11 times its model."""
    delay = np.asarray(delay, float)
    z, at = _scatter_z(delay, volume_nl, random_nl, use)
    out = np.zeros(delay.size)
    if z.size < LOCAL_SCATTER_DIFFERENCES:
        return out
    for i, t in enumerate(delay):
        if np.isfinite(t):
            near = np.argsort(np.abs(at - t), kind="stable")[:LOCAL_SCATTER_DIFFERENCES]
            out[i] = robust_sigma(z[near]) * student_factor(LOCAL_SCATTER_DIFFERENCES)
    return out


def _scatter_z(delay, volume_nl, random_nl, use) -> tuple[np.ndarray, np.ndarray]:
    """The differences of `frame_scatter_ratio`, each over its expected spread, and the delay each
    belongs to (a repeat's own; the middle of a third difference's four delays)."""
    delay = np.asarray(delay, float)
    r = np.asarray(random_nl, float)
    ok = np.asarray(use, bool) & np.isfinite(volume_nl) & np.isfinite(r) & (r > 0)
    if ok.sum() < 5:
        return np.zeros(0), np.zeros(0)
    d, v, r = delay[ok], np.asarray(volume_nl, float)[ok], r[ok]
    times, inverse = np.unique(d, return_inverse=True)
    n = np.bincount(inverse).astype(float)
    mean = np.bincount(inverse, v) / n
    r2 = np.bincount(inverse, r * r)
    spread = np.sqrt(r2) / n
    z, at = [], []
    rep = n[inverse] >= 2
    if rep.any():
        ni = n[inverse][rep]
        expected = np.sqrt(r[rep] ** 2 * (1.0 - 2.0 / ni) + r2[inverse][rep] / ni ** 2)
        z.append((v[rep] - mean[inverse][rep]) / expected)
        at.append(d[rep])
    if times.size >= 4:
        t = np.lib.stride_tricks.sliding_window_view(times, 4)
        w = 1.0 / np.stack([np.prod([t[:, i] - t[:, j] for j in range(4) if j != i], axis=0) for i in range(4)],
                           axis=1)
        m = np.lib.stride_tricks.sliding_window_view(mean, 4)
        s = np.lib.stride_tricks.sliding_window_view(spread, 4)
        z.append(np.sum(w * m, axis=1) / np.sqrt(np.sum(w * w * s * s, axis=1)))
        at.append(0.5 * (t[:, 1] + t[:, 2]))
    if not z:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(z), np.concatenate(at)


def grown_uncertainty(delay, attached_nl, attached_u_nl, common_u_nl, plane_u_nl,
                      grown_nl, floor_share: float = 0.0,
                      scatter_nl: float = 0.0, scatter_ratio: float = 0.0,
                      halo_nl=None, plane_position_u_nl=None,
                      halo_band_nl=None) -> tuple[float, np.ndarray, np.ndarray]:
    """Standard uncertainties (nl) of the initial meniscus, of every frame's grown volume and of
    its attached volume.

    The meniscus is the mean attached volume at the first delay: its uncertainty is its frames'
    mean uncertainty and the standard error of their scatter in quadrature.  A grown volume is
    the difference of two volumes measured with the same edge error and tip plane: of the common
    edge error only the difference ``|common - common_meniscus|`` is left, of the plane only the
    difference of its position part (``plane_position_u_nl``, `dropvision.frame.bodies.AttachedLiquid`:
    the slice at the plane times the plane's uncertainty, which cancels only as far as a frame's
    liquid is as wide there as the rest's; on the synthetic out-of-focus holder, whose face line
    places the plane to its whole rows, grown errors of 0.03-0.04 nl against 0.007-0.019 nl stated);
    the edges' own noise of both and the meniscus' scatter add in quadrature.  The edge floor's
    share of the common error (``floor_share``: sub-pixel interpolation, which changes with the
    silhouette's shape) is taken as independent between the two frames.  A frame's random part is
    at least the sequence's own scatter ``scatter_nl`` (nl) and at least its
    modelled random part times ``scatter_ratio`` (`frame_scatter_ratio`); the attached volumes'
    uncertainties are returned with it.  The in-focus walls' halo below their face
    (``halo_nl``, `dropvision.frame.bodies.face_halo_px3`) is cancelled by the rest's as far as a
    frame's liquid spreads no wider under the face than the first delay's: its excess over their
    mean is added to the attached and the grown volumes.  A liquid lying wholly within the nozzle's
    halo reads its band of edge levels against the halo (``halo_band_nl``,
    `dropvision.frame.bodies.AttachedLiquid.halo_band_nl`); every later frame holds those rows
    under the same halo, so a grown volume keeps none of it: it leaves the common error (in
    quadrature, as it was added) before the difference is taken.  On the synthetic sweep the rest
    meniscus's band stated 0.025-0.057 nl against its errors of 0.003-0.010 nl, and the difference
    of common errors carried it into every grown volume.
    """
    delay = np.asarray(delay, float)
    first = (delay == np.min(delay)) & np.isfinite(attached_nl) if delay.size else np.zeros(0, bool)
    model_rand = np.sqrt(np.maximum(attached_u_nl ** 2 - common_u_nl ** 2 - plane_u_nl ** 2, 0.0))
    rand = np.maximum(model_rand * np.maximum(np.asarray(scatter_ratio, float), 1.0), scatter_nl)
    attached_u_nl = np.sqrt(np.maximum(attached_u_nl ** 2 - model_rand ** 2, 0.0) + rand ** 2)
    if not first.any():
        return float("nan"), np.full(delay.size, np.nan), attached_u_nl
    halo = np.zeros(delay.size) if halo_nl is None else np.nan_to_num(np.asarray(halo_nl, float))
    wider = np.maximum(halo - float(np.mean(halo[first])), 0.0)
    attached_u_nl = np.hypot(attached_u_nl, wider)
    n0 = int(first.sum())
    u0 = float(np.mean(attached_u_nl[first]))
    se = float(np.std(attached_nl[first], ddof=1) / np.sqrt(n0)) if n0 >= 2 else 0.0
    r0 = float(np.mean(rand[first]))
    position = (np.zeros(delay.size) if plane_position_u_nl is None
                else np.nan_to_num(np.asarray(plane_position_u_nl, float)))
    p0 = float(np.mean(position[first]))
    band = np.zeros(delay.size) if halo_band_nl is None else np.nan_to_num(np.asarray(halo_band_nl, float))
    common_u_nl = np.sqrt(np.maximum(np.asarray(common_u_nl, float) ** 2 - band ** 2, 0.0))
    c0 = float(np.mean(common_u_nl[first]))
    f2 = floor_share ** 2
    u_grown = np.sqrt((1.0 - f2) * (common_u_nl - c0) ** 2 + f2 * (common_u_nl ** 2 + c0 ** 2)
                      + (position - p0) ** 2 + rand ** 2 + r0 ** 2 / n0 + se ** 2 + wider ** 2)
    return float(np.hypot(u0, se)), np.where(np.isfinite(grown_nl), u_grown, np.nan), attached_u_nl


def inflight_uncertainty(volumes_nl: np.ndarray, uncertainties_nl: np.ndarray) -> float:
    """Standard uncertainty (nl) of the mean in-flight volume: the frames' common edge
    uncertainty (it does not average out) and the standard error of their scatter, in quadrature."""
    ok = np.isfinite(volumes_nl) & np.isfinite(uncertainties_nl)
    if not ok.any():
        return float("nan")
    se = float(np.std(volumes_nl[ok], ddof=1) / np.sqrt(ok.sum())) if ok.sum() >= 2 else 0.0
    return float(np.hypot(np.mean(uncertainties_nl[ok]), se))


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

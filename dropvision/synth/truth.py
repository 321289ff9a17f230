"""Ground truth of a synthetic sequence: per frame (`FrameTruth`, truth_frames.csv), per body
(`BodyTruth`, truth_bodies.csv) and per sequence (`sequence_truth`, truth.json).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

from dropvision.io.orientation import canonical_to_original
from dropvision.synth.config import colour_gains
from dropvision.synth.planning import SynthPlan, renderer_for
from dropvision.synth.profiles import bead_segment, cap_volume_um3
from dvcore.versions import software_versions


#: Columns of truth_frames.csv, in order (interfaces.md), plus ``drop_in_view`` and the
#: realism tier's ``n_satellites_visible``, ``clipped_fraction``.
TRUTH_COLUMNS = ("file", "page", "delay_us", "repeat", "attached", "attached_volume_nl",
                 "grown_volume_nl", "drop_volume_nl", "detached_volume_nl", "drop_z_um",
                 "drop_x_um", "n_satellites", "flow_velocity_m_s", "tail_attached", "inflight",
                 "drop_in_view", "n_satellites_visible", "clipped_fraction")
#: Columns of truth_bodies.csv (one row per frame and body; docs/SYNTH_REALISM.md).
BODY_COLUMNS = ("file", "delay_us", "repeat", "body_class", "row_px", "col_px", "volume_nl",
                "in_focus", "countable", "detail")
#: body_class values of truth_bodies.csv.
BODY_CLASSES = ("nozzle", "holder", "attached", "main_drop", "satellite", "tail", "mist", "dust")


@dataclass(frozen=True)
class FrameTruth:
    """One row of truth_frames.csv (see interfaces.md); volumes in nl, lengths in µm."""

    file: str
    page: int | None
    delay_us: float
    repeat: int
    attached: bool
    attached_volume_nl: float
    grown_volume_nl: float
    drop_volume_nl: float
    detached_volume_nl: float
    drop_z_um: float
    drop_x_um: float
    n_satellites: int
    flow_velocity_m_s: float
    tail_attached: bool
    inflight: bool
    drop_in_view: bool
    n_satellites_visible: int = 0
    clipped_fraction: float = 0.0
    bodies: tuple = field(default=(), compare=False, repr=False)

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("bodies")
        return d


@dataclass(frozen=True)
class BodyTruth:
    """One row of truth_bodies.csv (docs/SYNTH_REALISM.md): canonical pixel coordinates."""

    file: str
    delay_us: float
    repeat: int
    body_class: str
    row_px: float
    col_px: float
    volume_nl: float
    in_focus: bool
    countable: bool
    detail: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


def truth_frames_table(rows) -> pd.DataFrame:
    """truth_frames.csv content as a DataFrame with :data:`TRUTH_COLUMNS`."""
    df = pd.DataFrame([r.to_dict() for r in rows], columns=list(TRUTH_COLUMNS))
    df["page"] = df["page"].astype("Int64")
    return df


def truth_bodies_table(rows) -> pd.DataFrame:
    """truth_bodies.csv content (:data:`BODY_COLUMNS`) from the frames' :class:`FrameTruth`."""
    return pd.DataFrame([b.to_dict() for r in rows for b in r.bodies], columns=list(BODY_COLUMNS))


def sequence_truth(synth_plan: SynthPlan) -> dict:
    """truth.json content (interfaces.md) for a plan."""


    p = synth_plan
    cfg, h, m = p.config, p.history, p.model
    if p.exposure is None or p.background_clipped_fraction is None:
        renderer_for(p)
    delays = np.array(sorted(set(f[3] for f in p.frames)))
    tp = h.pinchoff_instant_us if cfg.scene == "jetting" else float("inf")
    detached = delays[delays >= tp]
    attached = delays[delays < tp]
    ecm = cfg.physics.ecm_parameters()
    coeffs = ecm.coefficients()
    doc = _jetting_truth(p, delays, tp, attached, detached, ecm, coeffs)
    stored_r, stored_c = canonical_to_original(float(cfg.tip_row), float(cfg.axis_col), cfg.orientation,
                                               (int(cfg.height_px), int(cfg.width_px)))
    doc["calibration"].update(orientation=cfg.orientation, stored_tip_row=float(stored_r),
                              stored_axis_col=float(stored_c))
    doc["realism"] = {
        "orientation": cfg.orientation,
        "stored_shape": list(cfg.stored_shape),
        "holder_width_um": cfg.holder_width_um,
        "holder_face_z_um": -float(cfg.nozzle_protrusion_um) if cfg.holder_width_um > 0 else None,
        "structures": [{"name": st.name, "kind": st.kind, "body_class": st.body_class,
                        "transmission": st.transmission, "polygon_px": [list(v) for v in st.polygon]}
                       for st in p.structures],
        "vignetting": float(cfg.vignetting),
        "exposure": float(p.exposure),
        "clip_fraction_requested": cfg.clip_fraction,
        "clipped_fraction_background": float(p.background_clipped_fraction),
        "colour_gains_normalised": list(colour_gains(cfg.colour_gains)) if cfg.colour else None,
        "format": cfg.format,
        "jpeg_quality": int(cfg.jpeg_quality) if cfg.format == "jpeg" else None,
        "psf": cfg.psf,
        "psf_radius_px": float(cfg.psf_radius_px) if cfg.psf != "gaussian" else None,
        "path_dust": [list(d) for d in p.path_dust],
        "mist_per_frame": int(cfg.mist),
        "satellite_mode": cfg.shape.satellite_mode,
        "tail_bulb": bool(cfg.shape.tail_bulb),
        "bead_um": float(cfg.shape.bead_um),
        "bead_volume_nl": (cap_volume_um3(*_bead_dims(cfg.shape.bead_um)) / 1e6 if cfg.shape.bead_um > 0 else 0.0),
        "scene": cfg.scene,
        "nozzle_diameters_written": bool(cfg.write_nozzle_diameters),
    }
    doc["conventions"].update({
        "truth_positions": "canonical frame; sequence.json orientation rotates the stored frames "
                           "(dropvision.io.orientation.from_canonical); stored_tip_row/stored_axis_col "
                           "give the tip centre in the stored image",
        "n_satellites": "detached bodies other than the main drop",
        "n_satellites_visible": "drops other than the main drop as a person counts them: satellites "
                                "touching each other are one (silhouettes = pixels with any "
                                "coverage, touching in the 8-neighbourhood), a satellite touching "
                                "the main drop is one, a dumbbell is one",
        "drop_volume_nl": "the main drop's silhouette: satellites touching it included",
        "clipped_fraction": "fraction of the pixels of the stored frame (grey, or BT.601 luma of "
                            "the colour pixels; before JPEG compression) at full scale",
    })
    if cfg.scene == "pendant":
        for k in ("pinchoff_us", "pinchoff_instant_us", "grown_volume_at_pinchoff_nl",
                  "grown_volume_at_pinchoff_instant_nl", "inflight_volume_nl", "jetting_velocity_m_s",
                  "flow_velocity_at_max_stroke_m_s", "satellite_volume_nl"):
            doc[k] = float("nan")
        doc["satellites"] = 0
        doc["pendant"] = m.describe()
    return doc


def _laws(cfg) -> dict:
    """The truth's ``laws``: the (u1, u2) laws of the physics, or a waveform template's."""
    if cfg.waveform is not None:
        return {"template": cfg.drive().to_dict(), **cfg.laws().to_dict(),
                "law": "constant + sum_k slopes[k] (x_k - centre[k]) over the template's parameters",
                "inflight_volume": "grown volume at the pinch-off instant + volume adjuster",
                "jetting_velocity": "flow velocity at the template's velocity instant + velocity adjuster"}
    return {
        "pinchoff_us": "c0 + c_u1 (u1 - 70) + c_u2 (u2 - 25)",
        "pinchoff_coefficients": list(cfg.physics.pinchoff_law_us),
        "volume_adjuster_nl": "p00 + p10 u1 + p01 u2",
        "volume_adjuster_coefficients": list(cfg.physics.volume_adjuster_nl),
        "velocity_adjuster_m_s": "p00 + p10 u1 + p01 u2",
        "velocity_adjuster_coefficients": list(cfg.physics.velocity_adjuster_m_s),
        "inflight_volume": "grown volume at the pinch-off instant + volume adjuster",
        "jetting_velocity": "flow velocity at maximum stroke + velocity adjuster",
    }


def _bead_dims(bead_um: float) -> tuple[float, float]:
    """(base radius, height) of the bead segment (see `dropvision.synth.profiles.bead_segment`)."""
    b = bead_segment(0.0, bead_um)
    return b.base_radius_um, b.height_um


def _jetting_truth(p: SynthPlan, delays, tp, attached, detached, ecm, coeffs) -> dict:
    cfg, h, m = p.config, p.history, p.model
    return {
        "schema": "dropvision.truth/1",
        "pinchoff_us": float(detached[0]) if detached.size else float("nan"),
        "pinchoff_instant_us": tp,
        "grown_volume_at_pinchoff_nl": float(h.grown_volume_nl_at(attached[-1])) if attached.size else float("nan"),
        "grown_volume_at_pinchoff_instant_nl": h.grown_volume_at_pinchoff_instant_nl,
        "inflight_volume_nl": h.inflight_volume_nl,
        "jetting_velocity_m_s": h.jetting_velocity_m_s,
        "trajectory_angle_mrad": float(cfg.drift_mrad),
        "trajectory_angle_image_mrad": float(cfg.drift_mrad + np.deg2rad(cfg.tilt_deg) * 1e3),
        "satellites": int(cfg.satellites),
        "satellite_volume_nl": m.v_sat_um3 / 1e6,
        "flow_velocity_at_max_stroke_m_s": h.flow_velocity_at_max_stroke_m_s,
        "max_stroke_instant_us": h.max_stroke_instant_us,
        "initial_meniscus_volume_nl": m.initial_meniscus_volume_nl(),
        "calibration": {"tip_row": float(cfg.tip_row), "axis_col": float(cfg.axis_col),
                        "tilt_deg": float(cfg.tilt_deg), "pixel_size_um": float(cfg.pixel_size_um)},
        "conventions": {
            "frame": "canonical (nozzle at the top, drops travel down); pixel centres are integers",
            "drop_z_um": "main detached body centroid along the nozzle axis from the tip plane",
            "drop_x_um": "main detached body centroid across the nozzle axis, + to the right",
            "trajectory_angle_mrad": "drop trajectory relative to the nozzle axis, + to the right",
            "tilt_deg": "nozzle axis from the image downward direction, + leaning right going down",
            "grown_volume_nl": "ECM grown volume while attached; attached volume minus initial "
                               "meniscus volume after pinch-off",
            "detached_volume_nl": "all detached liquid (main body + satellites); 0 while attached",
            "volumes": "integrals of the analytic profiles, never of rendered pixels",
        },
        "parameters": {
            "config": cfg.to_dict(),
            "seed": int(cfg.seed),
            "ecm_parameters": ecm.to_dict(),
            "ecm_coefficients": coeffs.to_dict(),
            "ecm_natural_frequency_hz": ecm.natural_frequency_hz(),
            "ecm_damping_ratio": ecm.damping_ratio(),
            "laws": _laws(cfg),
            "history": h.summary(),
            "shape_model": m.describe(),
            "dust": [list(d) for d in p.dust],
            "position_jitter_um": cfg.jitter_um,
        },
        "versions": software_versions(),
    }

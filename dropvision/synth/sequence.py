"""Synthetic strobe sequences: configuration, frame-by-frame synthesis and ground truth.

:func:`synthesize` is pure (no file I/O): it yields ``(image, FrameTruth)`` per frame in
sequence order. :func:`sequence_truth` gives the truth.json content for a configuration.
Writing to disk is :func:`dropvision.synth.writer.write_synthetic_sequence`.
"""

from __future__ import annotations

import sys
from dataclasses import asdict, dataclass, field, fields
from typing import Iterator

import numpy as np
import pandas as pd

from identify.physics import DropHistory, SynthPhysics, drop_history
from identify.versions import software_versions
from dropvision.synth.render import CameraGeometry, Optics, Renderer
from dropvision.synth.shapes import DropShapeModel, ShapeParams, ShapeState

__all__ = ["FORMATS", "TRUTH_COLUMNS", "SynthConfig", "FrameTruth", "SynthPlan", "plan",
           "synthesize", "sequence_truth", "parse_delays", "frames_table"]

#: Output containers: one PNG per frame, one TIFF per frame, one multi-page TIFF.
FORMATS = ("png", "tiff", "tiff-stack")
#: Columns of truth_frames.csv, in order (interfaces.md), plus ``drop_in_view``.
TRUTH_COLUMNS = ("file", "page", "delay_us", "repeat", "attached", "attached_volume_nl",
                 "grown_volume_nl", "drop_volume_nl", "detached_volume_nl", "drop_z_um",
                 "drop_x_um", "n_satellites", "flow_velocity_m_s", "tail_attached", "inflight",
                 "drop_in_view")
STACK_FILE = "stack.tif"


def parse_delays(text: str) -> tuple[float, ...]:
    """Delays from ``start:stop:step`` (stop inclusive, µs) or a comma-separated list."""
    text = str(text).strip()
    try:
        if ":" in text:
            parts = [float(p) for p in text.split(":")]
            if len(parts) != 3 or parts[2] <= 0 or parts[1] < parts[0]:
                raise ValueError
            start, stop, step = parts
            n = int(np.floor((stop - start) / step + 1e-9)) + 1
            return tuple(float(round(start + k * step, 9)) for k in range(n))
        values = tuple(float(p) for p in text.split(",") if p.strip())
        if not values:
            raise ValueError
        return values
    except ValueError:
        raise ValueError(f"delays {text!r}: expected start:stop:step (µs, stop inclusive, step > 0) "
                         "or a comma-separated list of numbers") from None


@dataclass(frozen=True)
class SynthConfig:
    """Everything that defines a synthetic sequence (defaults: the paper's colour ink at
    u1 = 70 µm/ms, u2 = 25 µm, a 640 x 1024 camera with 4.73 µm pixels).

    Attributes
    ----------
    u1_um_per_ms, u2_um : float
        Waveform control parameters.
    seed : int
        Seed of every random choice (noise, jitter, dust).
    width_px, height_px : int
        Image size (canonical: nozzle at the top, drops travel down).
    pixel_size_um : float
    tip_row, axis_col : float
        Sub-pixel position of the nozzle tip centre (pixel centres are integers); axis_col
        None = width_px / 2 - 0.4 (319.6 for 640 px).
    tilt_deg : float
        Nozzle axis tilt in the image plane (positive: leaning right going down).
    drift_mrad : float
        Drop trajectory angle relative to the nozzle axis (positive towards +x/right).
    delays_us : tuple of float
        Strobe delays after the firing trigger.
    repeats : int
        Frames per delay; each its own truth row.
    position_jitter_um : float or None
        Standard deviation of the random offset (along and across) of the detached bodies per
        frame; None = 1.5 µm when repeats > 1, else 0.
    satellites : int
        0 (tail merges into the drop), 1 or 2 satellites after break-up.
    dust : int
        Dark specks near (not on) the drop path; ``dust_far`` adds one on the far side.
    blur_px, falloff, noise : float
        Gaussian blur sigma (px); backlight fall-off (corner = (1 - falloff) x centre);
        noise scale (0 = noise-free, 1 = full well 10000 e-, read noise 8 e-; the shot and
        read noise standard deviations scale with it).
    bit_depth : int
        8, 12 or 16.
    format : str
        "png", "tiff" or "tiff-stack" (one multi-page TIFF).
    supersample : int
        Samples per pixel side at silhouette edges.
    physics : SynthPhysics
    shape : ShapeParams
    """

    u1_um_per_ms: float = 70.0
    u2_um: float = 25.0
    seed: int = 0
    width_px: int = 640
    height_px: int = 1024
    pixel_size_um: float = 4.73
    tip_row: float = 59.4
    axis_col: float | None = None
    tilt_deg: float = 0.0
    drift_mrad: float = 0.0
    delays_us: tuple = tuple(float(d) for d in range(0, 1801, 10))
    repeats: int = 1
    position_jitter_um: float | None = None
    satellites: int = 0
    dust: int = 2
    dust_far: bool = True
    blur_px: float = 0.8
    falloff: float = 0.1
    noise: float = 1.0
    full_well_e: float = 10000.0
    read_noise_e: float = 8.0
    backlight_level: float = 0.88
    liquid_transmission: float = 0.10
    nozzle_transmission: float = 0.07
    spot_transmission: float = 0.80
    bit_depth: int = 8
    format: str = "png"
    supersample: int = 8
    physics: SynthPhysics = field(default_factory=SynthPhysics)
    shape: ShapeParams = field(default_factory=ShapeParams)

    def __post_init__(self) -> None:
        def bad(name, why):
            raise ValueError(f"SynthConfig.{name}: {why}, got {getattr(self, name)!r}")

        object.__setattr__(self, "delays_us", tuple(float(d) for d in self.delays_us))
        if self.axis_col is None:
            object.__setattr__(self, "axis_col", self.width_px / 2.0 - 0.4)
        if not self.delays_us or not all(np.isfinite(d) and d >= 0 for d in self.delays_us):
            bad("delays_us", "need at least one finite delay >= 0")
        for name in ("width_px", "height_px"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 16:
                bad(name, "must be an integer >= 16")
        for name in ("pixel_size_um", "u1_um_per_ms", "u2_um", "full_well_e", "backlight_level"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) <= 0:
                bad(name, "must be > 0")
        for name in ("blur_px", "noise", "read_noise_e"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                bad(name, "must be >= 0")
        if not 0 <= self.falloff < 1:
            bad("falloff", "must be in [0, 1)")
        if not (0 <= self.tip_row < self.height_px and 0 <= self.axis_col < self.width_px):
            bad("tip_row", "the nozzle tip (tip_row, axis_col) must lie inside the image")
        if self.repeats < 1 or int(self.repeats) != self.repeats:
            bad("repeats", "must be an integer >= 1")
        if self.satellites not in (0, 1, 2):
            bad("satellites", "must be 0, 1 or 2")
        if self.dust < 0 or int(self.dust) != self.dust:
            bad("dust", "must be an integer >= 0")
        if self.bit_depth not in (8, 12, 16):
            bad("bit_depth", "must be 8, 12 or 16")
        if self.format not in FORMATS:
            bad("format", f"must be one of {', '.join(FORMATS)}")
        if self.supersample < 1 or int(self.supersample) != self.supersample:
            bad("supersample", "must be an integer >= 1")
        if abs(self.tilt_deg) > 20:
            bad("tilt_deg", "must be within ±20 degrees")
        if abs(self.drift_mrad) > 200:
            bad("drift_mrad", "must be within ±200 mrad")
        for name in ("liquid_transmission", "nozzle_transmission", "spot_transmission"):
            if not 0 <= getattr(self, name) <= 1:
                bad(name, "must be in [0, 1]")

    @property
    def jitter_um(self) -> float:
        if self.position_jitter_um is not None:
            return float(self.position_jitter_um)
        return 1.5 if self.repeats > 1 else 0.0

    def geometry(self) -> CameraGeometry:
        return CameraGeometry(self.pixel_size_um, (int(self.height_px), int(self.width_px)),
                              self.tip_row, self.axis_col, self.tilt_deg)

    def optics(self) -> Optics:
        scale = self.noise
        return Optics(
            blur_sigma_px=self.blur_px, falloff=self.falloff, backlight_level=self.backlight_level,
            liquid_transmission=self.liquid_transmission, nozzle_transmission=self.nozzle_transmission,
            spot_transmission=self.spot_transmission,
            full_well_e=self.full_well_e / scale**2 if scale > 0 else self.full_well_e,
            read_noise_e=self.read_noise_e, noise=scale > 0, bit_depth=self.bit_depth,
            supersample=self.supersample)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["delays_us"] = list(self.delays_us)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SynthConfig":
        """Inverse of :meth:`to_dict` (truth.json ``parameters.config``)."""
        d = dict(d)
        phys = SynthPhysics(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.pop("physics", {}).items()})
        shape = ShapeParams(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.pop("shape", {}).items()})
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"SynthConfig: unknown keys {sorted(unknown)}")
        return cls(physics=phys, shape=shape, **d)


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

    def to_dict(self) -> dict:
        return asdict(self)


def frames_table(rows) -> pd.DataFrame:
    """truth_frames.csv content as a DataFrame with :data:`TRUTH_COLUMNS`."""
    df = pd.DataFrame([r.to_dict() for r in rows], columns=list(TRUTH_COLUMNS))
    df["page"] = df["page"].astype("Int64")
    return df


@dataclass
class SynthPlan:
    """Everything derived from a config before rendering (cheap; no pixels)."""

    config: SynthConfig
    history: DropHistory
    model: DropShapeModel
    geometry: CameraGeometry
    dust: list
    frames: list  # (index, file, page, delay_us, repeat)


def _frame_name(index: int, delay_us: float, repeat: int, repeats: int, suffix: str) -> str:
    d = f"{int(round(delay_us)):05d}" if float(delay_us).is_integer() else f"{delay_us:09.3f}"
    rep = f"_r{repeat}" if repeats > 1 else ""
    return f"f_{index:04d}{rep}_{d}us{suffix}"


def _dust_positions(cfg: SynthConfig, model: DropShapeModel, geom: CameraGeometry) -> list:
    """Static specks: (row, col, sigma_px, depth). Near-path specks sit beside the drop path
    (outside the largest drop half-width plus a margin), below the pinch-off bulb."""
    rng = np.random.default_rng([int(cfg.seed), 3])
    H, W = geom.shape
    px = cfg.pixel_size_um
    r_px = model.r_inflight / px
    half_width = 1.25 * r_px + 1.3 * max(model.shape.pinchoff_elongation, 0.0) * r_px
    z_top = (model.c_p + 1.4 * model.r_inflight) / px
    t_last = max(cfg.delays_us)
    z_last = (model.drop_center_zx_um(max(t_last - model.tp, 0.0))[0] + model.r_inflight) / px
    z_lo, z_hi = z_top, max(z_top + 10, min(z_last, H - 10 - cfg.tip_row))
    ang = np.deg2rad(cfg.tilt_deg) + model.theta
    out = []
    for k in range(int(cfg.dust)):
        sigma = rng.uniform(0.8, 2.0)
        z = rng.uniform(z_lo, z_hi)
        side = 1 if k % 2 == 0 else -1
        off = half_width + rng.uniform(6.0, 20.0) + 3 * sigma
        row = cfg.tip_row + z * np.cos(ang) - side * off * np.sin(ang)
        col = cfg.axis_col + z * np.sin(ang) + side * off * np.cos(ang)
        out.append((float(row), float(col), float(sigma), float(rng.uniform(0.35, 0.75))))
    if cfg.dust > 0 and cfg.dust_far:
        sigma = rng.uniform(1.0, 2.5)
        far_right = cfg.axis_col < W / 2
        col = W - rng.uniform(8, 25) if far_right else rng.uniform(8, 25)
        row = rng.uniform(H / 3, H - 10)
        out.append((float(row), float(col), float(sigma), float(rng.uniform(0.4, 0.8))))
    return out


def plan(config: SynthConfig) -> SynthPlan:
    """Physics, shape model, geometry, dust and the frame list of a configuration."""
    cfg = config
    t_end = max(max(cfg.delays_us), cfg.physics.pinchoff_instant_us(cfg.u1_um_per_ms, cfg.u2_um)) + 50.0
    hist = drop_history(cfg.physics, cfg.u1_um_per_ms, cfg.u2_um, t_end_us=t_end)
    model = DropShapeModel(hist, cfg.physics, cfg.shape, drift_mrad=cfg.drift_mrad, satellites=cfg.satellites)
    geom = cfg.geometry()
    suffix = ".png" if cfg.format == "png" else ".tif"
    frames = []
    order = sorted(range(len(cfg.delays_us)), key=lambda i: cfg.delays_us[i])
    idx = 0
    for i in order:
        d = cfg.delays_us[i]
        for rep in range(int(cfg.repeats)):
            if cfg.format == "tiff-stack":
                frames.append((idx, STACK_FILE, idx, d, rep))
            else:
                frames.append((idx, _frame_name(idx, d, rep, cfg.repeats, suffix), None, d, rep))
            idx += 1
    return SynthPlan(cfg, hist, model, geom, _dust_positions(cfg, model, geom), frames)


def _in_view(state: ShapeState, geom: CameraGeometry, margin_px: float = 1.0) -> bool:
    body = state.main_body
    if body is None:
        return False
    lo, hi = body.profile.support
    rmax = body.profile.max_radius_um
    d, n = geom.direction(body.axis_angle_rad)
    r0, c0 = geom.to_pixel(body.origin_z_um, body.origin_x_um)
    H, W = geom.shape
    for s in (lo, hi):
        for y in (-rmax, rmax):
            r = r0 + (s * d[0] + y * n[0]) / geom.pixel_size_um
            c = c0 + (s * d[1] + y * n[1]) / geom.pixel_size_um
            if not (margin_px - 0.5 <= r <= H - 0.5 - margin_px and margin_px - 0.5 <= c <= W - 0.5 - margin_px):
                return False
    return True


def _want_progress(progress) -> bool:
    if progress is None:
        return bool(getattr(sys.stderr, "isatty", lambda: False)())
    return bool(progress)


def synthesize(config: SynthConfig, *, progress: bool | None = None,
               synth_plan: SynthPlan | None = None) -> Iterator[tuple[np.ndarray, FrameTruth]]:
    """Render the sequence frame by frame.

    Parameters
    ----------
    config : SynthConfig
    progress : bool or None
        tqdm progress bar on stderr; None = only when stderr is a terminal.
    synth_plan : SynthPlan, optional
        A precomputed :func:`plan` of the same config.

    Yields
    ------
    image : ndarray (height_px, width_px), uint8 or uint16
    truth : FrameTruth
    """
    from tqdm import tqdm

    p = synth_plan if synth_plan is not None else plan(config)
    cfg = p.config
    renderer = Renderer(p.geometry, cfg.optics(), cfg.physics.nozzle_outer_radius_um, p.dust)
    jitter = cfg.jitter_um
    cache: dict[float, ShapeState] = {}
    bar = tqdm(total=len(p.frames), desc="dropvision synth", unit="frame",
               disable=not _want_progress(progress), leave=False)
    try:
        for index, file, page, delay, rep in p.frames:
            state = cache.get(delay)
            if state is None:
                cache.clear()
                state = cache[delay] = p.model.state(delay)
            if jitter > 0 and state.main_body is not None:
                jr = np.random.default_rng([int(cfg.seed), 1, index])
                state = state.shifted(*(jr.normal(0.0, jitter, size=2)))
            img = renderer.render(state.bodies, np.random.default_rng([int(cfg.seed), 2, index]))
            truth = FrameTruth(
                file=file, page=page, delay_us=float(delay), repeat=int(rep), attached=state.attached,
                attached_volume_nl=state.attached_volume_nl, grown_volume_nl=state.grown_volume_nl,
                drop_volume_nl=state.drop_volume_nl, detached_volume_nl=state.detached_volume_nl,
                drop_z_um=state.drop_z_um, drop_x_um=state.drop_x_um, n_satellites=state.n_satellites,
                flow_velocity_m_s=state.flow_velocity_m_s, tail_attached=state.tail_attached,
                inflight=state.inflight, drop_in_view=_in_view(state, p.geometry))
            bar.update(1)
            yield img, truth
    finally:
        bar.close()


def sequence_truth(synth_plan: SynthPlan) -> dict:
    """truth.json content (interfaces.md) for a plan."""


    p = synth_plan
    cfg, h, m = p.config, p.history, p.model
    delays = np.array(sorted(set(f[3] for f in p.frames)))
    tp = h.pinchoff_instant_us
    detached = delays[delays >= tp]
    attached = delays[delays < tp]
    ecm = cfg.physics.ecm_parameters()
    coeffs = ecm.coefficients()
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
            "laws": {
                "pinchoff_us": "c0 + c_u1 (u1 - 70) + c_u2 (u2 - 25)",
                "pinchoff_coefficients": list(cfg.physics.pinchoff_law_us),
                "volume_adjuster_nl": "p00 + p10 u1 + p01 u2",
                "volume_adjuster_coefficients": list(cfg.physics.volume_adjuster_nl),
                "velocity_adjuster_m_s": "p00 + p10 u1 + p01 u2",
                "velocity_adjuster_coefficients": list(cfg.physics.velocity_adjuster_m_s),
                "inflight_volume": "grown volume at the pinch-off instant + volume adjuster",
                "jetting_velocity": "flow velocity at maximum stroke + velocity adjuster",
            },
            "history": h.summary(),
            "shape_model": m.describe(),
            "dust": [list(d) for d in p.dust],
            "position_jitter_um": cfg.jitter_um,
        },
        "versions": software_versions(),
    }

"""Synthetic strobe sequences: configuration, frame-by-frame synthesis and ground truth.

:func:`synthesize` is pure (no file I/O): it yields ``(image, FrameTruth)`` per frame in
sequence order. :func:`sequence_truth` gives the truth.json content for a configuration.
Writing to disk is :func:`dropvision.synth.writer.write_synthetic_sequence`.
"""

from __future__ import annotations

import sys
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Iterator

import numpy as np
import pandas as pd

from identify.physics import DropHistory, SynthPhysics, drop_history
from identify.versions import software_versions
from dropvision.synth.render import CameraGeometry, Optics, Renderer, Structure, body_coverage
from dropvision.synth.shapes import (SATELLITE_KINDS, DropShapeModel, PendantShapeModel, ShapeParams, ShapeState,
                                     cap_volume_um3)

__all__ = ["FORMATS", "TRUTH_COLUMNS", "BODY_COLUMNS", "BODY_CLASSES", "SCENES", "RIGS", "SynthConfig",
           "FrameTruth", "BodyTruth", "SynthPlan", "plan", "synthesize", "sequence_truth", "parse_delays",
           "truth_frames_table", "truth_bodies_table", "colour_gains"]

#: Output containers: one PNG per frame, one TIFF per frame, one multi-page TIFF, one JPEG
#: per frame (8-bit only).
FORMATS = ("png", "tiff", "tiff-stack", "jpeg")
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
#: Scenes: a jetting nozzle (drop formation model) or a static pendant drop on a needle.
SCENES = ("jetting", "pendant")
STACK_FILE = "stack.tif"
#: Colour gains of a colour sensor (R, G, B) relative to the grey scene, before the
#: normalisation that makes their BT.601 luma equal to the grey scene.
DEFAULT_COLOUR_GAINS = (1.0, 0.95, 0.85)
#: BT.601 luma weights (the readers' colour-to-grey rule, docs/FORMAT.md).
LUMA_WEIGHTS = (0.299, 0.587, 0.114)


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
        Shape knobs, including the realism tier's ``bead_um``, ``satellite_mode``
        ("separate", "touching", "dumbbell") and ``tail_bulb``.

    Realism tier (docs/SYNTH_REALISM.md; every default leaves the image bit-identical to the
    plain synthesizer):

    orientation : str
        Direction the drops travel in the stored frames: "down" (canonical), "up", "left",
        "right". Frames are rendered canonically (``width_px`` x ``height_px``) and stored
        with :func:`dropvision.orientation.from_canonical`; every truth position stays canonical.
    holder : bool or float
        Dark holder block / nozzle plate around the nozzle at the top: False/0 none, True
        5 x the nozzle outer diameter wide, a number > 0 its width in µm. It reaches from the
        top edge down to its face, ``nozzle_protrusion_um`` above the nozzle tip, and carries
        bright internal reflections and a dark wedge shadow beside it.
    nozzle_protrusion_um : float
        Length of nozzle below the holder face (0: the tip is the face).
    holder_blur_px : float
        The nozzle and the holder block lie out of the jet's focal plane: their extra Gaussian
        blur (px) on top of ``blur_px`` (0: in focus).  The liquid stays sharp.
    vignetting : float
        In [0, 0.95]: radial fall-off to (1 - vignetting) of the light in the corners.
    exposure : float
        Light gain (> 1 clips the bright background at full scale).
    clip_fraction : float or None
        Target fraction (0..0.99) of background pixels at full scale; sets the exposure from
        the noise-free background frame (overrides ``exposure``).
    colour : bool
        RGB frames (gains ``colour_gains`` normalised so that the BT.601 luma is the grey
        scene); ``demosaic_blur_px`` blurs R and B a little.
    jpeg_quality : int
        JPEG quality (``format="jpeg"``), 1..100.
    mist : int
        Out-of-focus mist droplets per frame (they drift: new positions every frame).
    path_dust : int
        Static dark specks ON the drop path (every frame).
    cuvette_wall : float or None
        Dark vertical cuvette-wall line at this fraction of the width (canonical frame).
    scene : str
        "jetting" or "pendant" (a static pendant drop: ``pendant_apex_radius_um``,
        ``pendant_bond``, needle of ``needle_diameter_um``, default the nozzle outer diameter).
    write_nozzle_diameters : bool
        False: sequence.json carries no nozzle diameters (pixel size only).
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
    orientation: str = "down"
    holder: bool | float = False
    nozzle_protrusion_um: float = 60.0
    holder_blur_px: float = 0.0
    vignetting: float = 0.0
    exposure: float = 1.0
    clip_fraction: float | None = None
    colour: bool = False
    colour_gains: tuple = DEFAULT_COLOUR_GAINS
    demosaic_blur_px: float = 0.0
    jpeg_quality: int = 95
    mist: int = 0
    path_dust: int = 0
    cuvette_wall: float | None = None
    scene: str = "jetting"
    pendant_apex_radius_um: float = 900.0
    pendant_bond: float = 0.2
    needle_diameter_um: float | None = None
    write_nozzle_diameters: bool = True

    def __post_init__(self) -> None:
        def bad(name, why):
            raise ValueError(f"SynthConfig.{name}: {why}, got {getattr(self, name)!r}")

        from dropvision.orientation import ORIENTATIONS

        object.__setattr__(self, "colour_gains", tuple(float(g) for g in self.colour_gains))
        if isinstance(self.orientation, str):
            object.__setattr__(self, "orientation", self.orientation.lower())
        if self.orientation not in ORIENTATIONS:
            bad("orientation", f"must be one of {', '.join(ORIENTATIONS)}")
        if isinstance(self.holder, bool):
            pass
        elif not (np.isfinite(self.holder) and self.holder >= 0):
            bad("holder", "must be a bool or a width >= 0 (µm)")
        elif self.holder and self.holder <= self.physics.nozzle_outer_diameter_um:
            bad("holder", "a holder block must be wider than the nozzle's outer diameter")
        for name in ("nozzle_protrusion_um", "demosaic_blur_px", "holder_blur_px"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                bad(name, "must be >= 0")
        if not 0 <= self.vignetting <= 0.95:
            bad("vignetting", "must be in [0, 0.95]")
        if not (np.isfinite(self.exposure) and self.exposure > 0):
            bad("exposure", "must be > 0")
        if self.clip_fraction is not None and not 0 <= self.clip_fraction <= 0.99:
            bad("clip_fraction", "must be in [0, 0.99] or None")
        if len(self.colour_gains) != 3 or not all(np.isfinite(g) and g > 0 for g in self.colour_gains):
            bad("colour_gains", "need three gains > 0")
        if int(self.jpeg_quality) != self.jpeg_quality or not 1 <= self.jpeg_quality <= 100:
            bad("jpeg_quality", "must be an integer in 1..100")
        for name in ("mist", "path_dust"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 0:
                bad(name, "must be an integer >= 0")
        if self.cuvette_wall is not None and not 0 < self.cuvette_wall < 1:
            bad("cuvette_wall", "must be a fraction of the width in (0, 1) or None")
        if self.scene not in SCENES:
            bad("scene", f"must be one of {', '.join(SCENES)}")
        if self.format == "jpeg" and self.bit_depth != 8:
            bad("format", "JPEG frames are 8-bit only (bit_depth 8)")
        if self.colour and self.format == "tiff-stack":
            bad("format", "colour frames cannot go into a (grey) multi-page TIFF stack")
        if self.scene == "pendant":
            if not (self.pendant_apex_radius_um > 0 and self.pendant_bond >= 0):
                bad("pendant_apex_radius_um", "a pendant drop needs an apex radius > 0 and a Bond number >= 0")
            if self.needle_diameter_um is not None and not self.needle_diameter_um > 0:
                bad("needle_diameter_um", "must be > 0")

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

    def optics(self, exposure: float | None = None) -> Optics:
        """Optics of the config (``exposure``: the effective exposure, see ``clip_fraction``)."""
        scale = self.noise
        return Optics(
            blur_sigma_px=self.blur_px, falloff=self.falloff, backlight_level=self.backlight_level,
            liquid_transmission=self.liquid_transmission, nozzle_transmission=self.nozzle_transmission,
            spot_transmission=self.spot_transmission,
            full_well_e=self.full_well_e / scale**2 if scale > 0 else self.full_well_e,
            read_noise_e=self.read_noise_e, noise=scale > 0, bit_depth=self.bit_depth,
            supersample=self.supersample, vignetting=float(self.vignetting),
            exposure=float(self.exposure if exposure is None else exposure),
            colour_gains=colour_gains(self.colour_gains) if self.colour else None,
            demosaic_blur_px=float(self.demosaic_blur_px), static_blur_px=float(self.holder_blur_px))

    @property
    def needle_outer_diameter_um(self) -> float:
        """Outer diameter of the nozzle (jetting) or needle (pendant) as rendered."""
        if self.scene == "pendant" and self.needle_diameter_um is not None:
            return float(self.needle_diameter_um)
        return float(self.physics.nozzle_outer_diameter_um)

    @property
    def holder_width_um(self) -> float:
        """Width of the holder block (0: none)."""
        if self.holder is True:
            return 5.0 * self.needle_outer_diameter_um
        return float(self.holder or 0.0)

    @property
    def stored_shape(self) -> tuple[int, int]:
        """(rows, cols) of the stored frames (rotated for left/right)."""
        H, W = int(self.height_px), int(self.width_px)
        return (W, H) if self.orientation in ("left", "right") else (H, W)

    @classmethod
    def for_rig(cls, name: str, **overrides) -> "SynthConfig":
        """The preset ``name`` of :data:`RIGS` with ``overrides`` (SynthConfig fields; a
        ShapeParams field name, or ``shape=dict(...)``, changes the preset's shape)."""
        if name not in RIGS:
            raise ValueError(f"unknown rig {name!r}: expected one of {', '.join(RIGS)}")
        d = dict(RIGS[name])
        shape = dict(d.pop("shape", {}))
        shape_fields = {f.name for f in fields(ShapeParams)}
        for k in list(overrides):
            if k in shape_fields:
                shape[k] = overrides.pop(k)
        sh = overrides.pop("shape", None)
        if isinstance(sh, ShapeParams):
            shape = {**sh.to_dict()}
        elif sh:
            shape.update(sh)
        d.update(overrides)
        return cls(shape=ShapeParams(**shape), **d)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["delays_us"] = list(self.delays_us)
        d["colour_gains"] = list(self.colour_gains)
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
        if isinstance(d.get("colour_gains"), list):
            d["colour_gains"] = tuple(d["colour_gains"])
        return cls(physics=phys, shape=shape, **d)


def colour_gains(gains=DEFAULT_COLOUR_GAINS) -> tuple[float, float, float]:
    """Channel gains scaled so that their BT.601 luma is 1 (the readers' grey rule then
    recovers the grey scene wherever no channel clips)."""
    k = sum(w * g for w, g in zip(LUMA_WEIGHTS, gains))
    return tuple(float(g / k) for g in gains)


#: Rig presets for :meth:`SynthConfig.for_rig` (SynthConfig keyword arguments; ``shape`` a
#: dict of ShapeParams fields). Frame sizes are the rigs'; tests shrink them by overrides.
RIGS: dict[str, dict] = {
    # today's default synthesizer
    "clean": {},
    # drop watcher seen from the side: stored 2048 x 1536 (W x H) with drops travelling right,
    # nozzle in a holder block, strong vignetting, colour JPEG, mist, touching + dumbbell
    # satellites, a long tail with a bulb, a bead left on the orifice
    "watcher-side": dict(
        orientation="right", width_px=1536, height_px=2048, tip_row=120.4, axis_col=767.6,
        pixel_size_um=4.73, holder=True, nozzle_protrusion_um=40.0, vignetting=0.6,
        format="jpeg", jpeg_quality=90, colour=True, demosaic_blur_px=0.5, mist=6,
        satellites=2, blur_px=1.0, dust=2, spot_transmission=0.8,
        shape=dict(satellite_mode="mixed", tail_bulb=True, bead_um=25.0)),
    # a drop watcher whose holder block is out of focus (the real rigs of issue 18): a wide holder
    # with the capillary face inside it (no protrusion), nozzle and holder blurred 8 px further
    # than the jet, small drops in a 2048 x 1536 frame, JPEG at quality 85 on a strongly vignetted
    # background with sensor noise, mist, two separate satellites behind the drop
    "watcher-blurred-holder": dict(
        orientation="right", width_px=1536, height_px=2048, tip_row=160.4, axis_col=767.6,
        pixel_size_um=4.73, holder=1500.0, nozzle_protrusion_um=0.0, holder_blur_px=8.0, vignetting=0.6,
        format="jpeg", jpeg_quality=85, colour=True, demosaic_blur_px=0.5, mist=6,
        satellites=2, blur_px=1.0, dust=2, spot_transmission=0.8,
        shape=dict(satellite_mode="separate")),
    # pendant-drop tensiometer: a large static pendant drop on a 0.72 mm needle, one frame,
    # 75 % of the background clipped, bright lens spot, a cuvette wall, colour JPEG
    "pendant-saturated": dict(
        scene="pendant", delays_us=(0.0,), width_px=640, height_px=480, tip_row=40.4, axis_col=319.6,
        pixel_size_um=10.0, needle_diameter_um=720.0, pendant_apex_radius_um=1000.0, pendant_bond=0.2,
        clip_fraction=0.75, spot_transmission=0.9, cuvette_wall=0.9, colour=True, format="jpeg",
        jpeg_quality=92, dust=1, vignetting=0.2, blur_px=1.0),
    # weak backlight contrast: liquid and nozzle at ~50 % transmission, noise sigma ~5 % of the
    # background (shot noise of 480 e- full well + 5 e- read noise), blur 1.8 px, dust on the path
    "low-contrast": dict(
        liquid_transmission=0.5, nozzle_transmission=0.5, spot_transmission=0.85, full_well_e=480.0,
        read_noise_e=5.0, blur_px=1.8, path_dust=2, dust=2),
    # tilted nozzle, 12-bit TIFF, dust on and beside the path, vignetting
    "tilted-dusty": dict(tilt_deg=1.5, format="tiff", bit_depth=12, path_dust=3, dust=3, vignetting=0.4),
    # one frame of a flying drop, no background sequence, sequence.json without nozzle diameters
    "single-frame": dict(delays_us=(1300.0,), write_nozzle_diameters=False),
}


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


@dataclass
class SynthPlan:
    """Everything derived from a config before rendering (cheap; no pixels)."""

    config: SynthConfig
    history: DropHistory
    model: DropShapeModel
    geometry: CameraGeometry
    dust: list
    frames: list  # (index, file, page, delay_us, repeat)
    path_dust: list = field(default_factory=list)
    structures: list = field(default_factory=list)
    exposure: float | None = None  # effective exposure (set on first use)
    background_clipped_fraction: float | None = None


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


def _path_dust_positions(cfg: SynthConfig, model, geom: CameraGeometry) -> list:
    """Static specks ON the drop path (within ±0.4 drop radii of the trajectory), below the
    pinch-off bulb: (row, col, sigma_px, depth)."""
    if not cfg.path_dust:
        return []
    rng = np.random.default_rng([int(cfg.seed), 5])
    H, _ = geom.shape
    px = cfg.pixel_size_um
    r_px = model.r_inflight / px
    z_top = (model.c_p + 1.4 * model.r_inflight) / px
    z_hi = max(z_top + 10, H - 10 - cfg.tip_row)
    ang = np.deg2rad(cfg.tilt_deg) + model.theta
    out = []
    for _ in range(int(cfg.path_dust)):
        sigma = rng.uniform(1.2, 2.5)
        z = rng.uniform(z_top, z_hi)
        off = rng.uniform(-0.4, 0.4) * r_px
        row = cfg.tip_row + z * np.cos(ang) - off * np.sin(ang)
        col = cfg.axis_col + z * np.sin(ang) + off * np.cos(ang)
        out.append((float(row), float(col), float(sigma), float(rng.uniform(0.3, 0.6))))
    return out


#: Transmission of the holder block, of its wedge shadow and of a cuvette wall.
HOLDER_TRANSMISSION, WEDGE_TRANSMISSION, WALL_TRANSMISSION = 0.04, 0.12, 0.35


def _structures(cfg: SynthConfig, geom: CameraGeometry) -> list:
    """Holder block (+ reflections, wedge) and cuvette wall as :class:`Structure` polygons."""
    out = []
    H, W = geom.shape
    px = cfg.pixel_size_um
    wh = cfg.holder_width_um
    if wh > 0:
        rng = np.random.default_rng([int(cfg.seed), 6])
        reach = (H + W) * px * 2.0
        face = -float(cfg.nozzle_protrusion_um)
        half = 0.5 * wh

        def poly(zx):
            r, c = geom.to_pixel(np.array([p[0] for p in zx]), np.array([p[1] for p in zx]))
            return tuple((float(a), float(b)) for a, b in zip(r, c))

        out.append(Structure("block", "block", poly([(-reach, -half), (-reach, half), (face, half), (face, -half)]),
                             HOLDER_TRANSMISSION))
        visible = max(cfg.tip_row * px + face, 4.0 * px)  # block height inside the image (µm)
        ro = 0.5 * cfg.needle_outer_diameter_um
        for k in range(3):  # thin bright streaks along the block, clear of the nozzle
            side = 1.0 if k % 2 == 0 else -1.0
            x = side * rng.uniform(ro + 0.15 * (half - ro), half - 0.1 * (half - ro))
            w = rng.uniform(1.5, 3.0) * px
            z0 = face - rng.uniform(0.05, 0.3) * visible
            z1 = face - rng.uniform(0.6, 1.2) * visible
            out.append(Structure("reflection", "reflection",
                                 poly([(z1, x - w / 2), (z1, x + w / 2), (z0, x + w / 2), (z0, x - w / 2)]),
                                 float(rng.uniform(0.3, 0.6))))
        side = -1.0 if rng.uniform() < 0.5 else 1.0  # one small patch
        x = side * rng.uniform(ro + 0.3 * (half - ro), half - 0.2 * (half - ro))
        a = rng.uniform(3.0, 6.0) * px
        zc = face - rng.uniform(0.3, 0.7) * visible
        out.append(Structure("reflection", "reflection",
                             poly([(zc - a, x), (zc, x + a), (zc + a, x), (zc, x - a)]), float(rng.uniform(0.3, 0.6))))
        spread = np.tan(np.deg2rad(25.0))
        out.append(Structure("wedge", "shadow",
                             poly([(face, half), (-reach, half), (-reach, half + spread * (reach + face))]),
                             WEDGE_TRANSMISSION))
    if cfg.cuvette_wall is not None:
        c = float(cfg.cuvette_wall) * W
        out.append(Structure("cuvette_wall", "shadow",
                             ((-10.0, c - 1.5), (-10.0, c + 1.5), (H + 10.0, c + 1.5), (H + 10.0, c - 1.5)),
                             WALL_TRANSMISSION))
    return out


def plan(config: SynthConfig) -> SynthPlan:
    """Physics, shape model, geometry, dust and the frame list of a configuration."""
    cfg = config
    t_end = max(max(cfg.delays_us), cfg.physics.pinchoff_instant_us(cfg.u1_um_per_ms, cfg.u2_um)) + 50.0
    hist = drop_history(cfg.physics, cfg.u1_um_per_ms, cfg.u2_um, t_end_us=t_end)
    if cfg.scene == "pendant":
        model = PendantShapeModel(cfg.pendant_apex_radius_um, cfg.pendant_bond,
                                  0.5 * cfg.needle_outer_diameter_um, cfg.shape)
    else:
        model = DropShapeModel(hist, cfg.physics, cfg.shape, drift_mrad=cfg.drift_mrad, satellites=cfg.satellites)
    geom = cfg.geometry()
    suffix = {"png": ".png", "jpeg": ".jpg"}.get(cfg.format, ".tif")
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
    return SynthPlan(cfg, hist, model, geom, _dust_positions(cfg, model, geom), frames,
                     path_dust=_path_dust_positions(cfg, model, geom), structures=_structures(cfg, geom))


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


def _renderer(p: SynthPlan) -> Renderer:
    """The plan's renderer with its effective exposure (``clip_fraction`` solved once)."""
    cfg = p.config
    rend = Renderer(p.geometry, cfg.optics(), 0.5 * cfg.needle_outer_diameter_um,
                    list(p.dust) + list(p.path_dust), structures=p.structures)
    if p.exposure is None or p.background_clipped_fraction is None:
        bg = rend.intensity(())  # noise-free background frame (no liquid), unit exposure
        thr = _clip_light(rend.optics.colour_gains, rend.max_dn)
        if cfg.clip_fraction is not None and cfg.clip_fraction > 0:
            p.exposure = float(thr / np.quantile(bg, 1.0 - cfg.clip_fraction))
        elif p.exposure is None:
            p.exposure = float(cfg.exposure)
        p.background_clipped_fraction = float(np.mean(bg * p.exposure >= thr))
    if p.exposure != rend.optics.exposure:
        rend.optics = replace(rend.optics, exposure=p.exposure)
    return rend


def _clip_light(gains, max_dn: float) -> float:
    """Light (fraction of full scale, after the exposure) from which a pixel's stored grey,
    or the BT.601 luma of its clipped colour channels, rounds to full scale."""
    target = 1.0 - 0.5 / max_dn
    if gains is None:
        return target
    from scipy.optimize import brentq

    def luma(light):
        return sum(w * min(g * light, 1.0) for w, g in zip(LUMA_WEIGHTS, gains)) - target

    return float(brentq(luma, 0.0, 1.0 / min(gains), xtol=1e-14))


def _mist(cfg: SynthConfig, model, index: int) -> list:
    """Mist droplets of frame ``index``: (row, col, diameter_px, sigma_px, attenuation, diameter_um);
    every third one on the drop path, the others anywhere."""
    if not cfg.mist:
        return []
    rng = np.random.default_rng([int(cfg.seed), 4, int(index)])
    H, W = int(cfg.height_px), int(cfg.width_px)
    px = cfg.pixel_size_um
    ang = np.deg2rad(cfg.tilt_deg) + model.theta
    out = []
    for k in range(int(cfg.mist)):
        d_um = rng.uniform(5.0, 40.0)
        sig = rng.uniform(3.0, 8.0)
        att = rng.uniform(0.1, 0.4)
        if k % 3 == 0:
            z = rng.uniform(0.0, H - cfg.tip_row)
            off = rng.uniform(-1.0, 1.0) * model.r_inflight / px
            r = cfg.tip_row + z * np.cos(ang) - off * np.sin(ang)
            c = cfg.axis_col + z * np.sin(ang) + off * np.cos(ang)
        else:
            r, c = rng.uniform(0, H - 1), rng.uniform(0, W - 1)
        out.append((float(r), float(c), float(d_um / px), float(sig), float(att), float(d_um)))
    return out


def _silhouette(body, geom: CameraGeometry, supersample: int):
    """Boolean mask (full frame) of the pixels a body covers at all, dilated by one pixel
    (8-neighbourhood): two silhouettes touch when one's dilated mask meets the other."""
    H, W = geom.shape
    m = np.zeros((H, W), bool)
    pc = body_coverage(body, geom, supersample)
    if pc is None:
        return m, m
    r0, c0, cov = pc
    m[r0:r0 + cov.shape[0], c0:c0 + cov.shape[1]] = cov > 0
    d = np.zeros((H, W), bool)
    rr, cc = np.nonzero(m)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            d[np.clip(rr + dr, 0, H - 1), np.clip(cc + dc, 0, W - 1)] = True
    return m, d


def _satellite_visibility(state: ShapeState, geom: CameraGeometry, supersample: int):
    """(countable per satellite, number of visible satellites, volume (nl) of the satellites
    touching the main drop): satellites are grouped with every other satellite whose
    silhouette touches theirs; each group is one visible satellite, as a person counts drops (a
    satellite touching the main drop is a drop of its own, a lobe of the drop's silhouette); a
    satellite is countable when it touches no other satellite."""
    sats = list(state.satellites)
    if not sats:
        return [], 0, 0.0
    bodies = [state.main_body] + sats
    masks = [_silhouette(b, geom, supersample) for b in bodies]
    n = len(bodies)
    parent = list(range(n))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    touches = [False] * n
    on_main = 0.0
    for i in range(n):
        for j in range(i + 1, n):
            if (masks[i][1] & masks[j][0]).any():
                if i == 0:  # touches the main drop: one silhouette with it, still a drop of its own
                    on_main += bodies[j].volume_nl()
                    continue
                touches[i] = touches[j] = True
                parent[find(i)] = find(j)
    visible_in_view = [masks[k][0].any() for k in range(n)]
    groups = {find(k) for k in range(1, n) if visible_in_view[k]}
    return [not touches[k] and visible_in_view[k] for k in range(1, n)], len(groups), on_main


def _pixel(geom: CameraGeometry, z_um: float, x_um: float) -> tuple[float, float]:
    r, c = geom.to_pixel(z_um, x_um)
    return float(r), float(c)


def _body_rows(p: SynthPlan, rend: Renderer, state: ShapeState, file: str, delay: float, rep: int,
               mist: list, sat_countable: list) -> tuple:
    cfg, g = p.config, p.geometry
    rows = []

    def add(cls, rc, vol, focus, countable, detail=""):
        rows.append(BodyTruth(file, float(delay), int(rep), cls, float(rc[0]), float(rc[1]),
                              float(vol), bool(focus), bool(countable), detail))

    nan = float("nan")
    add("nozzle", (cfg.tip_row, cfg.axis_col), nan, cfg.holder_blur_px == 0, False,
        "needle tip centre" if cfg.scene == "pendant" else "tip centre")
    for st, r, c in rend.structure_info:
        add(st.body_class, (r, c), nan, cfg.holder_blur_px == 0, False, st.name)
    b = state.attached_body
    if b is not None:
        vol = state.attached_volume_nl
        rc = _pixel(g, *b.centroid_zx_um()) if vol > 0 else (cfg.tip_row, cfg.axis_col)
        detail = "pendant drop" if cfg.scene == "pendant" else ("meniscus" if state.attached else "residual meniscus")
        if not state.attached and cfg.shape.bead_um > 0:
            detail += " + bead"
        add("attached", rc, vol, True, True, detail)
    m = state.main_body
    if m is not None:
        drop = m.profile.parts[0]
        v_all = m.profile.volume_um3()
        v_drop = drop.volume_um3() if len(m.profile.parts) > 1 else v_all
        th = m.axis_angle_rad
        add("main_drop", _pixel(g, m.origin_z_um, m.origin_x_um) if len(m.profile.parts) > 1
            else _pixel(g, *m.centroid_zx_um()), v_drop / 1e6, True, True,
            "with tail" if len(m.profile.parts) > 1 else "")
        if len(m.profile.parts) > 1 and v_all > v_drop:
            s_t = m.profile.centroid_um() * v_all / (v_all - v_drop)  # the drop's centroid is s = 0
            add("tail", _pixel(g, m.origin_z_um + s_t * np.cos(th), m.origin_x_um + s_t * np.sin(th)),
                (v_all - v_drop) / 1e6, True, False,
                "ligament with bulb" if cfg.shape.tail_bulb else "ligament")
    kinds = SATELLITE_KINDS[cfg.shape.satellite_mode]
    for k, sb in enumerate(state.satellites):
        detail = {"sphere": "separate"}.get(kinds[k], kinds[k])
        add("satellite", _pixel(g, *sb.centroid_zx_um()), sb.volume_nl(), True, sat_countable[k], detail)
    for r, c, _dpx, _sig, _att, d_um in mist:
        add("mist", (r, c), nan, False, False, f"diameter {d_um:.1f} um")
    n_near = int(cfg.dust)
    for k, (r, c, _sig, _depth) in enumerate(p.dust):
        add("dust", (r, c), nan, False, False, "beside the path" if k < n_near else "far from the path")
    for r, c, _sig, _depth in p.path_dust:
        add("dust", (r, c), nan, False, False, "on the path")
    return tuple(rows)


def _clipped_fraction(img: np.ndarray, max_dn: float) -> float:
    if img.ndim == 3:  # the readers' grey (BT.601 luma) of the stored colour pixels
        import cv2
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return float(np.mean(img >= max_dn))


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
    image : ndarray, uint8 or uint16
        The frame as stored: (height_px, width_px) canonically, rotated by
        :func:`dropvision.orientation.from_canonical` for ``orientation`` (left/right: (width_px,
        height_px)); (..., 3) RGB with ``colour``. JPEG compression happens in the writer.
    truth : FrameTruth
        Canonical-frame truth; ``truth.bodies`` holds the frame's truth_bodies.csv rows.
    """
    from tqdm import tqdm

    from dropvision.orientation import from_canonical

    p = synth_plan if synth_plan is not None else plan(config)
    cfg = p.config
    renderer = _renderer(p)
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
            mist = _mist(cfg, p.model, index)
            img = renderer.render(state.bodies, np.random.default_rng([int(cfg.seed), 2, index]),
                                  mist=[m[:5] for m in mist])
            countable, n_visible, on_main = _satellite_visibility(state, p.geometry, cfg.supersample)
            truth = FrameTruth(
                file=file, page=page, delay_us=float(delay), repeat=int(rep), attached=state.attached,
                attached_volume_nl=state.attached_volume_nl, grown_volume_nl=state.grown_volume_nl,
                drop_volume_nl=state.drop_volume_nl + on_main if on_main else state.drop_volume_nl,
                detached_volume_nl=state.detached_volume_nl,
                drop_z_um=state.drop_z_um, drop_x_um=state.drop_x_um, n_satellites=state.n_satellites,
                flow_velocity_m_s=state.flow_velocity_m_s, tail_attached=state.tail_attached,
                inflight=state.inflight, drop_in_view=_in_view(state, p.geometry),
                n_satellites_visible=n_visible, clipped_fraction=_clipped_fraction(img, renderer.max_dn),
                bodies=_body_rows(p, renderer, state, file, delay, rep, mist, countable))
            if cfg.orientation != "down":
                img = from_canonical(img, cfg.orientation)
            bar.update(1)
            yield img, truth
    finally:
        bar.close()


def sequence_truth(synth_plan: SynthPlan) -> dict:
    """truth.json content (interfaces.md) for a plan."""


    p = synth_plan
    cfg, h, m = p.config, p.history, p.model
    if p.exposure is None or p.background_clipped_fraction is None:
        _renderer(p)
    delays = np.array(sorted(set(f[3] for f in p.frames)))
    tp = h.pinchoff_instant_us if cfg.scene == "jetting" else float("inf")
    detached = delays[delays >= tp]
    attached = delays[delays < tp]
    ecm = cfg.physics.ecm_parameters()
    coeffs = ecm.coefficients()
    doc = _jetting_truth(p, delays, tp, attached, detached, ecm, coeffs)
    from dropvision.orientation import canonical_to_original

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
                           "(dropvision.orientation.from_canonical); stored_tip_row/stored_axis_col "
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


def _bead_dims(bead_um: float) -> tuple[float, float]:
    """(base radius, height) of the bead segment (see shapes.bead_segment)."""
    from dropvision.synth.shapes import bead_segment

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

"""Configuration of a synthetic strobe sequence: `SynthConfig` (scene, optics, sensor, realism
options, output format) with its rig presets `RIGS` (`SynthConfig.for_rig`), and `parse_delays`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

import numpy as np

from dropvision.io.orientation import ORIENTATIONS
from dropvision.synth.render import PSFS, CameraGeometry, Optics
from dropvision.synth.shapes import ShapeParams
from identify.physics import SynthPhysics


#: Output containers: one PNG per frame, one TIFF per frame, one multi-page TIFF, one JPEG
#: per frame (8-bit only).
FORMATS = ("png", "tiff", "tiff-stack", "jpeg")
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
        with :func:`dropvision.io.orientation.from_canonical`; every truth position stays canonical.
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
    psf, psf_radius_px : str, float
        A point-spread function that is not Gaussian, on top of ``blur_px`` (`PSFS`,
        `dropvision.synth.render.psf_kernel`): ``"airy"`` (diffraction rings; ``psf_radius_px``
        the first dark ring's radius) or ``"disc"`` (a defocus disc of that radius);
        ``"gaussian"`` (default) adds nothing.
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
    waveform : dict or None
        The drive as a waveform template (`identify.waveform`, issue 31): sequence.json's template
        form ``{"template": "three_pulse", "parameters": {"V1": 30, ...}, <constants>}`` plus,
        optionally, ``"laws"`` (`identify.physics.TemplateLaws` as a dict: pinch-off instant and
        adjusters linear in the parameters; default `identify.physics.DEFAULT_LAWS`). The flow comes
        from that drive through the ECM of ``physics`` (`identify.physics.drive_history`); the dead
        time is ``physics.dead_time_us``. None (default): the trapezoid of ``u1_um_per_ms``, ``u2_um``.
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
    psf: str = "gaussian"
    psf_radius_px: float = 0.0
    mist: int = 0
    path_dust: int = 0
    cuvette_wall: float | None = None
    scene: str = "jetting"
    pendant_apex_radius_um: float = 900.0
    pendant_bond: float = 0.2
    needle_diameter_um: float | None = None
    write_nozzle_diameters: bool = True
    waveform: dict | None = None

    def __post_init__(self) -> None:
        def bad(name, why):
            raise ValueError(f"SynthConfig.{name}: {why}, got {getattr(self, name)!r}")

        if self.waveform is not None:
            if not isinstance(self.waveform, dict) or "template" not in self.waveform:
                bad("waveform", "must be a template form {'template': ..., 'parameters': {...}}")
            if "dead_time_us" in self.waveform:
                bad("waveform", "carries no dead_time_us: the drive starts physics.dead_time_us after the trigger")
            try:
                drive, laws = self.drive(), self.laws()
                for law in (laws.pinchoff_us, laws.volume_adjuster_nl, laws.velocity_adjuster_m_s):
                    law.at(drive.values)
            except (ValueError, KeyError, TypeError) as exc:
                msg = str(exc)
                raise ValueError(msg if msg.startswith("SynthConfig") else f"SynthConfig.waveform: {msg}") from None

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
        if self.psf not in PSFS:
            bad("psf", f"must be one of {', '.join(PSFS)}")
        if self.psf != "gaussian" and not (np.isfinite(self.psf_radius_px) and 0 < self.psf_radius_px <= 20):
            bad("psf_radius_px", f"a {self.psf} point-spread function needs a radius in (0, 20] px")
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

    def drive(self):
        """The template drive (`identify.waveform.Drive`), None without ``waveform``."""
        if self.waveform is None:
            return None
        from dvcore.waveform import drive_from_document

        doc = {k: v for k, v in self.waveform.items() if k != "laws"}
        return drive_from_document({**doc, "dead_time_us": self.physics.dead_time_us}, "SynthConfig")

    def laws(self):
        """The template's synthetic laws (`identify.physics.TemplateLaws`), None without ``waveform``."""
        if self.waveform is None:
            return None
        from identify.physics import laws_for

        return laws_for(self.waveform["template"], self.physics, self.waveform.get("laws"))

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
            demosaic_blur_px=float(self.demosaic_blur_px), static_blur_px=float(self.holder_blur_px),
            psf=self.psf, psf_radius_px=float(self.psf_radius_px))

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

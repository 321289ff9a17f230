"""Synthetic printhead rows with per-nozzle truth (`dropvision synth --rig printhead-row`, issue 32).

A row of ``n_nozzles`` nozzles at ``pitch_um`` under a flat dark nozzle plate that spans the top of
the frame (side view: the orifices are not visible, a nozzle is where its liquid leaves the plate).
Every live nozzle fires a spherical main drop (and, when planted, a satellite behind it) that
flies in a straight line from the plate at the nozzle's own velocity and angle:

    s(t) = break_um + v (t - break_us)      (distance from the plate along the trajectory)
    centre = (plate_row + s cos(a) / px, nozzle_col + s sin(a) / px)

(a: angle from the plate normal, + towards increasing image column).  Nozzle-to-nozzle spread:
volume and velocity normal with ``volume_cv`` / ``velocity_cv``, angle normal with
``angle_sd_mrad``; planted states: ``missing`` (fires nothing), ``weak`` (``weak_volume`` x the
volume, ``weak_velocity`` x the velocity), ``deviated`` (``deviated_mrad`` added to its angle),
``satellites`` (a satellite of ``satellite_fraction`` x its volume trailing it).  Liquid at the
plate: ``meniscus_nl`` > 0 hangs a bulge of that volume (a half sphere) below the plate at every
live nozzle, centred on the nozzle's column (truth_bodies.csv class ``meniscus``): where a person
sees each nozzle's place in one frame, independent of the drops' angles; ``ligament_um`` > 0 hangs
a ligament still attached instead (a slender spheroid of that length below the plate and radius
``ligament_radius_um``, along the nozzle's trajectory; class ``ligament``).  Crosstalk:
``crosstalk`` names nozzles whose drop leans towards its right-hand neighbour by ``crosstalk_mrad``
(state ``deviated``), far enough to fly past the middle between the two columns.

Frames are rendered by `dropvision.synth.render.Renderer` (the plate as a "block" structure, its
optics and sensor noise).  ``scan=True`` writes the scanning variant: one frame per nozzle (the
nozzle index in the file name, ``nozzle_03.png``), that nozzle alone centred under the plate.

Truth files: truth.json (the configuration and conventions), truth_frames.csv (file, delay_us,
nozzle for a scan), truth_bodies.csv (one row per rendered body: file, delay_us, nozzle, class,
row, col, volume_nl; canonical frame) and truth_nozzles.csv (nozzle, state, volume_nl,
velocity_m_s, angle_mrad, satellite_volume_nl, col_px).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

ROW_RIGS = ("printhead-row", "printhead-scan")
NOZZLE_STATES = ("ok", "missing", "weak", "deviated", "satellites")
TRUTH_NOZZLE_COLUMNS = ("nozzle", "state", "volume_nl", "velocity_m_s", "angle_mrad", "satellite_volume_nl",
                        "col_px")


@dataclass(frozen=True)
class RowConfig:
    """A synthetic printhead row (canonical frame: plate at the top, drops travel down).

    ``planted`` maps nozzle index -> state ("missing", "weak", "deviated", "satellites")."""

    n_nozzles: int = 8
    pitch_um: float = 423.3  # 60 per inch
    width_px: int = 2048
    height_px: int = 768
    pixel_size_um: float = 2.0
    plate_row: float = 40.3
    delays_us: tuple = (120.0,)
    volume_nl: float = 0.1
    velocity_m_s: float = 5.0
    volume_cv: float = 0.015
    velocity_cv: float = 0.015
    angle_sd_mrad: float = 1.5
    planted: dict = field(default_factory=lambda: {2: "missing", 4: "weak", 5: "deviated", 6: "satellites"})
    weak_volume: float = 0.7
    weak_velocity: float = 0.75
    deviated_mrad: float = 40.0
    satellite_fraction: float = 0.12
    break_us: float = 30.0
    break_um: float = 120.0
    satellite_gap_um: float = 30.0
    satellite_velocity: float = 0.9
    seed: int = 0
    blur_px: float = 0.8
    noise: float = 1.0
    bit_depth: int = 8
    orientation: str = "down"
    format: str = "png"
    scan: bool = False
    write_pitch: bool = False
    supersample: int = 8
    meniscus_nl: float = 0.0
    ligament_um: float = 0.0
    ligament_radius_um: float = 4.0
    crosstalk: tuple = ()
    crosstalk_mrad: float = 250.0

    def __post_init__(self) -> None:
        def bad(name, why):
            raise ValueError(f"RowConfig.{name}: {why}, got {getattr(self, name)!r}")

        object.__setattr__(self, "delays_us", tuple(float(d) for d in self.delays_us))
        object.__setattr__(self, "planted", {int(k): str(v) for k, v in dict(self.planted).items()})
        object.__setattr__(self, "crosstalk", tuple(int(k) for k in self.crosstalk))
        for name in ("meniscus_nl", "ligament_um"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                bad(name, "must be >= 0")
        if self.meniscus_nl > 0 and self.ligament_um > 0:
            bad("ligament_um", "a meniscus or a ligament at the plate, not both")
        if not (np.isfinite(self.ligament_radius_um) and self.ligament_radius_um > 0):
            bad("ligament_radius_um", "must be > 0")
        for k in self.crosstalk:
            if not 0 <= k < self.n_nozzles - 1 or self.planted.get(k, "ok") != "ok":
                bad("crosstalk", f"nozzle indices 0..{self.n_nozzles - 2} (a right-hand neighbour) not planted otherwise")
        if int(self.n_nozzles) != self.n_nozzles or self.n_nozzles < 1:
            bad("n_nozzles", "must be an integer >= 1")
        for k, v in self.planted.items():
            if not 0 <= k < self.n_nozzles or v not in NOZZLE_STATES:
                bad("planted", f"nozzle indices 0..{self.n_nozzles - 1} with states among {', '.join(NOZZLE_STATES)}")
        for name in ("pitch_um", "pixel_size_um", "volume_nl", "velocity_m_s"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                bad(name, "must be > 0")
        if not self.delays_us or not all(np.isfinite(d) and d > self.break_us for d in self.delays_us):
            bad("delays_us", f"need delays after the break-off at {self.break_us} µs")
        span_px = (self.n_nozzles - 1) * self.pitch_um / self.pixel_size_um
        if not self.scan and span_px > self.width_px - 100:
            bad("pitch_um", f"{self.n_nozzles} nozzles at this pitch span {span_px:.0f} px, wider than the frame")
        if self.format not in ("png", "tiff"):
            bad("format", "must be png or tiff")

    @property
    def nozzle_cols(self) -> np.ndarray:
        """Canonical column of each nozzle (multi-nozzle frame): centred in the frame."""
        span = (self.n_nozzles - 1) * self.pitch_um / self.pixel_size_um
        return (self.width_px - 1) / 2.0 - span / 2.0 + 0.37 + np.arange(self.n_nozzles) * self.pitch_um / self.pixel_size_um

    def nozzle_truth(self) -> list[dict]:
        """Per nozzle: state, volume_nl, velocity_m_s, angle_mrad, satellite_volume_nl, col_px."""
        rng = np.random.default_rng([int(self.seed), 32])
        n = self.n_nozzles
        vol = self.volume_nl * (1.0 + self.volume_cv * np.clip(rng.standard_normal(n), -2, 2))
        vel = self.velocity_m_s * (1.0 + self.velocity_cv * np.clip(rng.standard_normal(n), -2, 2))
        ang = self.angle_sd_mrad * np.clip(rng.standard_normal(n), -2, 2)
        out = []
        for i in range(n):
            st = self.planted.get(i, "ok")
            v, u, a, sat = float(vol[i]), float(vel[i]), float(ang[i]), 0.0
            if st == "weak":
                v, u = v * self.weak_volume, u * self.weak_velocity
            elif st == "deviated":
                a += self.deviated_mrad * (1.0 if i % 2 == 0 else -1.0)
            elif st == "satellites":
                sat = v * self.satellite_fraction
            if i in self.crosstalk:
                st, a = "deviated", a + self.crosstalk_mrad
            nan = float("nan")
            out.append({"nozzle": i, "state": st, "volume_nl": nan if st == "missing" else v,
                        "velocity_m_s": nan if st == "missing" else u, "angle_mrad": nan if st == "missing" else a,
                        "satellite_volume_nl": sat, "col_px": float(self.nozzle_cols[i])})
        return out

    def to_dict(self) -> dict:
        d = asdict(self)
        d["delays_us"] = list(self.delays_us)
        d["planted"] = {str(k): v for k, v in self.planted.items()}
        d["crosstalk"] = list(self.crosstalk)
        return d


def for_rig(name: str, **overrides) -> RowConfig:
    """`RowConfig` of a row rig (`ROW_RIGS`) with ``overrides``."""
    if name not in ROW_RIGS:
        raise ValueError(f"unknown printhead rig {name!r}: expected one of {', '.join(ROW_RIGS)}")
    if "planted" not in overrides and "n_nozzles" in overrides:
        # the default plantings that fit inside a shorter row (none on its last nozzle: a missing
        # nozzle at a row's end is no gap in the pitch)
        default = RowConfig().planted
        overrides["planted"] = {k: v for k, v in default.items() if k < int(overrides["n_nozzles"]) - 1}
    return RowConfig(**{"scan": name == "printhead-scan", **overrides})


def _sphere(volume_nl: float, s_um: float, x_um: float, angle_rad: float):
    from dropvision.synth.profiles import LiquidBody, Profile, Spheroid

    r = (3.0 * volume_nl * 1e6 / (4.0 * np.pi)) ** (1.0 / 3.0)
    return LiquidBody("drop", Profile((Spheroid(0.0, r, r),)), s_um * np.cos(angle_rad),
                      x_um + s_um * np.sin(angle_rad), angle_rad)


def _bodies(cfg: RowConfig, truth: list[dict], delay: float, centre_col: float, cols) -> list:
    """(LiquidBody, nozzle, class, volume_nl) of the nozzles at ``cols`` at ``delay``."""
    out = []
    px = cfg.pixel_size_um
    for t, col in zip(truth, cols):
        if t["state"] == "missing":
            continue
        a = t["angle_mrad"] * 1e-3
        x = (col - centre_col) * px
        if cfg.meniscus_nl > 0:  # a half sphere below the plate (the upper half lies inside it)
            out.append((_sphere(2.0 * cfg.meniscus_nl, 0.0, x, 0.0), t["nozzle"], "meniscus", cfg.meniscus_nl))
        elif cfg.ligament_um > 0:  # a slender spheroid centred at the plate along the trajectory: its lower half
            from dropvision.synth.profiles import LiquidBody, Profile, Spheroid

            L, r = cfg.ligament_um, cfg.ligament_radius_um
            out.append((LiquidBody("drop", Profile((Spheroid(0.0, L, r),)), 0.0, x, a), t["nozzle"], "ligament",
                        2.0 / 3.0 * np.pi * r * r * L * 1e-6))
        s = cfg.break_um + t["velocity_m_s"] * (delay - cfg.break_us)
        out.append((_sphere(t["volume_nl"], s, x, a), t["nozzle"], "main_drop", t["volume_nl"]))
        if t["satellite_volume_nl"] > 0:
            r_m = (3.0 * t["volume_nl"] * 1e6 / (4.0 * np.pi)) ** (1.0 / 3.0)
            r_s = (3.0 * t["satellite_volume_nl"] * 1e6 / (4.0 * np.pi)) ** (1.0 / 3.0)
            s_sat = (cfg.break_um - r_m - cfg.satellite_gap_um - r_s
                     + cfg.satellite_velocity * t["velocity_m_s"] * (delay - cfg.break_us))
            out.append((_sphere(t["satellite_volume_nl"], s_sat, x, a), t["nozzle"], "satellite",
                        t["satellite_volume_nl"]))
    return out


def _renderer(cfg: RowConfig, centre_col: float):
    from dropvision.synth.render import CameraGeometry, Optics, Renderer, Structure

    H, W = int(cfg.height_px), int(cfg.width_px)
    geom = CameraGeometry(cfg.pixel_size_um, (H, W), cfg.plate_row, centre_col, 0.0)
    scale = cfg.noise
    optics = Optics(blur_sigma_px=cfg.blur_px, full_well_e=10000.0 / scale**2 if scale > 0 else 10000.0,
                    noise=scale > 0, bit_depth=cfg.bit_depth, supersample=cfg.supersample)
    plate = Structure("nozzle_plate", "block", ((-20.0, -20.0), (-20.0, W + 20.0), (cfg.plate_row, W + 20.0),
                                                (cfg.plate_row, -20.0)), 0.07, "holder")
    # the renderer's own nozzle (a needle above the tip) lies wholly inside the plate
    return Renderer(geom, optics, 1e-3, (), (plate,)), geom


def synthesize_row(cfg: RowConfig):
    """Yield (file, delay_us, nozzle or None, canonical image, body rows) per frame."""
    from dropvision.synth.render import CameraGeometry  # noqa: F401  (render imported once)

    truth = cfg.nozzle_truth()
    suffix = ".png" if cfg.format == "png" else ".tif"
    if cfg.scan:
        centre = (cfg.width_px - 1) / 2.0 + 0.37
        rend, geom = _renderer(cfg, centre)
        frames = [(f"nozzle_{i:02d}{suffix}", cfg.delays_us[0], i, [truth[i]], [centre])
                  for i in range(cfg.n_nozzles)]
    else:
        centre = float(cfg.nozzle_cols.mean())
        rend, geom = _renderer(cfg, centre)
        frames = [(f"frame_{k:03d}_{d:07.2f}us{suffix}", d, None, truth, list(cfg.nozzle_cols))
                  for k, d in enumerate(cfg.delays_us)]
    for k, (file, delay, noz, tr, cols) in enumerate(frames):
        bodies = _bodies(cfg, tr, delay, centre, cols)
        img = rend.render([b[0] for b in bodies], np.random.default_rng([int(cfg.seed), 2, k]))
        rows = []
        for b, i, cls, vol in bodies:
            r, c = geom.to_pixel(*b.centroid_zx_um())
            if cls == "meniscus":  # the half below the plate: its centroid 3/8 of the radius below the edge
                r += 3.0 / 8.0 * (3.0 * vol * 2e6 / (4.0 * np.pi)) ** (1.0 / 3.0) / cfg.pixel_size_um
            elif cls == "ligament":  # ... 3/8 of its length along its axis
                a = b.axis_angle_rad
                r += 3.0 / 8.0 * cfg.ligament_um * np.cos(a) / cfg.pixel_size_um
                c += 3.0 / 8.0 * cfg.ligament_um * np.sin(a) / cfg.pixel_size_um
            rows.append({"file": file, "delay_us": delay, "nozzle": i, "class": cls, "row": float(r),
                         "col": float(c), "volume_nl": vol})
        yield file, delay, noz, img, rows


def write_row(cfg: RowConfig, out_dir, *, overwrite: bool = False) -> Path:
    """Render ``cfg`` and write the folder (images, sequence.json, truth files) atomically."""
    import pandas as pd

    from dropvision.io.orientation import from_canonical
    from dropvision.io.sequence_writer import write_image, write_sequence_json
    from dvcore.atomic import atomic_dir, check_output_dir, write_json, write_text

    out = Path(out_dir)
    check_output_dir(out, overwrite="marked" if overwrite else False)
    frames, bodies = [], []
    with atomic_dir(out, overwrite="marked" if overwrite else False, kind="synthetic-sequence") as tmp:
        for file, delay, noz, img, rows in synthesize_row(cfg):
            if cfg.orientation != "down":
                img = from_canonical(img, cfg.orientation)
            write_image(tmp / file, img)
            frames.append({"file": file, "delay_us": delay, **({} if noz is None else {"nozzle": noz})})
            bodies.extend(rows)
        meta = {"pixel_size_um": float(cfg.pixel_size_um), "orientation": cfg.orientation,
                "bit_depth": int(cfg.bit_depth), "synthetic": True,
                "frames": [{"file": f["file"], "delay_us": f["delay_us"]} for f in frames]}
        if cfg.write_pitch:
            meta["nozzle_pitch_um"] = float(cfg.pitch_um)
        write_sequence_json(tmp, meta)
        truth = cfg.nozzle_truth()
        write_json(tmp / "truth.json", {
            "kind": "printhead-scan" if cfg.scan else "printhead-row", "parameters": {"config": cfg.to_dict()},
            "nozzles": truth,
            "conventions": {
                "nozzle": "index from 0 left to right in the stored image's canonical frame (scan: the file's label)",
                "angle_mrad": "trajectory angle from the plate normal, + towards increasing canonical column",
                "volume_nl": "the main drop's volume (a satellite's is satellite_volume_nl)",
                "velocity_m_s": "the main drop's constant velocity along its trajectory",
                "positions": "truth_bodies.csv rows and cols in the canonical frame (drops travel down)"}})
        write_text(tmp / "truth_nozzles.csv", pd.DataFrame(truth, columns=list(TRUTH_NOZZLE_COLUMNS))
                   .to_csv(index=False, float_format="%.9g"))
        write_text(tmp / "truth_frames.csv", pd.DataFrame(frames).to_csv(index=False, float_format="%.9g"))
        write_text(tmp / "truth_bodies.csv", pd.DataFrame(
            bodies, columns=["file", "delay_us", "nozzle", "class", "row", "col", "volume_nl"])
            .to_csv(index=False, float_format="%.9g"))
    return out

"""Planning a synthetic sequence: everything derived from a `SynthConfig` before any pixel is
rendered (`plan` -> `SynthPlan`: delays, file names, drop history, shape model, static structures,
dust), and the `Renderer` it configures (`renderer_for`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from dropvision.synth.config import STACK_FILE, LUMA_WEIGHTS, SynthConfig
from dropvision.synth.render import CameraGeometry, Renderer, Structure
from dropvision.synth.shapes import DropShapeModel, PendantShapeModel
from identify.physics import DropHistory, drive_history, drop_history


#: Transmission of the holder block, of its wedge shadow and of a cuvette wall.
HOLDER_TRANSMISSION, WEDGE_TRANSMISSION, WALL_TRANSMISSION = 0.04, 0.12, 0.35


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
    drive = cfg.drive()
    if drive is None:
        t_end = max(max(cfg.delays_us), cfg.physics.pinchoff_instant_us(cfg.u1_um_per_ms, cfg.u2_um)) + 50.0
        hist = drop_history(cfg.physics, cfg.u1_um_per_ms, cfg.u2_um, t_end_us=t_end)
    else:  # a waveform template: its drive through the ECM (issue 31)
        laws = cfg.laws()
        t_end = max(max(cfg.delays_us), laws.pinchoff_us.at(drive.values)) + 50.0
        hist = drive_history(cfg.physics, drive, laws, t_end_us=t_end)
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


def renderer_for(p: SynthPlan) -> Renderer:
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

"""Synthetic strobe sequences: frame-by-frame synthesis (`synthesize`).

:func:`synthesize` is pure (no file I/O): it yields ``(image, FrameTruth)`` per frame in
sequence order.  Its parts: the configuration (`dropvision.synth.config`), the plan
(`dropvision.synth.planning`) and the truth (`dropvision.synth.truth`, :func:`sequence_truth` gives
the truth.json content for a configuration); all their public names are also importable from
here.  Writing to disk is :func:`dropvision.synth.writer.write_synthetic_sequence`.
"""

from __future__ import annotations

import sys
from typing import Iterator

import numpy as np

from dropvision.io.orientation import from_canonical
from dropvision.synth.config import (FORMATS, RIGS, SCENES, STACK_FILE, SynthConfig, colour_gains,
                                     parse_delays)
from dropvision.synth.planning import SynthPlan, plan, renderer_for
from dropvision.synth.render import CameraGeometry, Renderer, body_coverage
from dropvision.synth.shapes import SATELLITE_KINDS, ShapeState
from dropvision.synth.truth import (BODY_CLASSES, BODY_COLUMNS, TRUTH_COLUMNS, BodyTruth, FrameTruth,
                                    sequence_truth, truth_bodies_table, truth_frames_table)


__all__ = ["FORMATS", "TRUTH_COLUMNS", "BODY_COLUMNS", "BODY_CLASSES", "SCENES", "RIGS", "SynthConfig",
           "FrameTruth", "BodyTruth", "SynthPlan", "plan", "synthesize", "sequence_truth", "parse_delays",
           "truth_frames_table", "truth_bodies_table", "colour_gains", "STACK_FILE"]


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
        :func:`dropvision.io.orientation.from_canonical` for ``orientation`` (left/right: (width_px,
        height_px)); (..., 3) RGB with ``colour``. JPEG compression happens in the writer.
    truth : FrameTruth
        Canonical-frame truth; ``truth.bodies`` holds the frame's truth_bodies.csv rows.
    """
    from tqdm import tqdm

    p = synth_plan if synth_plan is not None else plan(config)
    cfg = p.config
    renderer = renderer_for(p)
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

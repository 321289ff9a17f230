"""A backlight clipped at the sensor maximum is measured, not refused (issue 11 item 3): the
background level is estimated from the nozzle walls' edge profile and the edges are taken below
the clip."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from dropvision.measurement import measure_sequence
from dropvision.io.sequence import sequence_from_arrays
from dropvision.synth import SynthConfig, synthesize

from test_measure_sequence import PENDANT

DELAYS = tuple(float(d) for d in range(0, 1501, 30))


def _clip(img, exposure):
    return np.clip(np.rint(img.astype(np.float64) * exposure), 0, 255).astype(np.uint8)


def _render(blur_px):
    cfg = SynthConfig(width_px=320, height_px=700, delays_us=DELAYS, seed=8, satellites=1, blur_px=blur_px)
    frames, truths = zip(*synthesize(cfg, progress=False))
    return cfg, list(frames), pd.DataFrame([t.to_dict() for t in truths])


def _measure(cfg, frames, truth, exposure):
    clipped = [_clip(f, exposure) for f in frames]
    assert np.mean(clipped[0] == 255) > 0.5
    seq = sequence_from_arrays(clipped, delays_us=truth["delay_us"].to_numpy(), pixel_size_um=cfg.pixel_size_um,
                               nozzle_inner_diameter_um=2 * cfg.physics.nozzle_inner_radius_um,
                               nozzle_outer_diameter_um=2 * cfg.physics.nozzle_outer_radius_um)
    return measure_sequence(seq)


@pytest.fixture(scope="module")
def soft():
    """Edges blurred like a pendant-drop camera's (2 px)."""
    return _render(2.0)


@pytest.mark.parametrize("exposure", [1.25, 1.5])
def test_clipped_synthetic_sequence_is_measured(soft, exposure):
    cfg, frames, truth = soft
    r = _measure(cfg, frames, truth, exposure)
    f = r.frames
    assert f["quality"].str.contains("clipped_background").all()
    assert not f["quality"].str.contains("saturated").any()
    # the level at the nozzle: the unclipped frame's background there, times the exposure
    level = r.summary["calibration"]["clipped_background"]["level"]
    assert abs(level / (255 * exposure * cfg.backlight_level * 0.953) - 1) < 0.03
    att = truth["attached"]
    peak = truth["grown_volume_nl"].max()
    # the constant level under-reads the brighter backlight further from the nozzle (fall-off 0.1)
    assert ((f.loc[att, "grown_volume_nl"] - truth.loc[att, "grown_volume_nl"]).abs() / peak).max() < 0.01
    both = f["inflight"] & truth["inflight"]
    assert both.sum() >= 5
    assert ((f.loc[both, "drop_volume_nl"] / truth.loc[both, "drop_volume_nl"] - 1).abs()).max() < 0.015
    view = ~truth["attached"] & truth["drop_in_view"] & f["n_satellites"].notna()
    assert (f.loc[view, "n_satellites"].astype(int) == truth.loc[view, "n_satellites"]).all()


@pytest.mark.slow
def test_sharp_edges_against_a_clipped_background_are_measured_with_a_wider_uncertainty():
    """The level of a background clipped at 255 cannot be read off sharp edges: the sensor
    maximum is its lower bound, the volumes are measured and their uncertainty says why."""
    cfg, frames, truth = _render(0.8)
    r = _measure(cfg, frames, truth, 1.5)
    f = r.frames
    assert f["quality"].str.contains("clipped_background").all()
    assert not f["quality"].str.contains("saturated").any()
    assert any("could not be estimated" in n for n in r.summary["calibration"]["notes"])
    assert (f["volume_uncertainty_source"] == "clipped background").all()
    att = truth["attached"].to_numpy()
    assert f.loc[att, "attached_volume_nl"].notna().all() and att.sum() >= 20
    err = (f.loc[att, "attached_volume_nl"] - truth.loc[att, "attached_volume_nl"]).abs()
    u = f.loc[att, "attached_volume_uncertainty_nl"]
    assert (u > 0).all()
    assert (err <= 2 * u).mean() >= 0.95
    both = (f["inflight"] & truth["inflight"]).to_numpy()
    assert both.sum() >= 5
    err = (f.loc[both, "drop_volume_nl"] - truth.loc[both, "drop_volume_nl"]).abs()
    assert (err <= 2 * f.loc[both, "drop_volume_uncertainty_nl"]).mean() >= 0.95
    s = r.summary
    assert abs(s["inflight_volume_nl"] - truth.loc[both, "drop_volume_nl"].mean()) <= 2 * s["inflight_volume_uncertainty_nl"]


@pytest.mark.usefixtures("realdata_dir")
@pytest.mark.parametrize("exposure", [1.2, 1.4])
def test_clipped_pendant_drop_within_3_percent(tmp_path, exposure):
    img = cv2.imread(str(PENDANT / "gota_pendiente_1.png"), cv2.IMREAD_UNCHANGED)
    out = _clip(img, exposure)
    assert np.mean(out == 255) > 0.7
    cv2.imwrite(str(tmp_path / "gota_pendiente_1.png"), out)
    (tmp_path / "sequence.json").write_text((PENDANT / "sequence.json").read_text())
    truth = json.loads((PENDANT / "truth.json").read_text())
    r = measure_sequence(tmp_path)
    v = float(r.frames["attached_volume_nl"].iloc[0])
    assert abs(v / truth["attached_volume_nl"] - 1) * 100 < truth["tolerance_percent"]
    assert r.frames["quality"].iloc[0] == "clipped_background"


def _vignetted_clipped_frame(vignetting: float = 0.25, peak: float = 290.0, h: int = 240, w: int = 320):
    """A backlight ``peak (1 - vignetting rho^2)`` (rho 1 at the corners) clipped at 255, a dark nozzle
    from the top edge to row 40 at column 160 (40 px wide), nothing else; and the backlight itself."""
    rr = (np.arange(h) - 0.5 * (h - 1)) / (0.5 * (h - 1))
    cc = (np.arange(w) - 0.5 * (w - 1)) / (0.5 * (w - 1))
    light = peak * (1.0 - vignetting * 0.5 * (rr[:, None] ** 2 + cc[None, :] ** 2))
    img = np.minimum(light, 255.0)
    img[:41, 140:181] = 0.08 * light[:41, 140:181]
    return img.astype(np.float32), light


def test_backlight_under_the_clip_is_extrapolated_from_what_is_seen():
    """Against a known backlight (quadratic vignetting, 13 % over the clip at the centre): the
    offset `ClipIllumination` predicts at a body's place from the level read at the nozzle's walls is
    the backlight's own ratio (within 0.3 %), and the body's clipped term (`clip_level_px`) is that
    offset over the edge's slope, never less than the sequence's term."""
    from types import SimpleNamespace

    from dropvision.frame.bodies import clip_level_px, common_edge_sigma_px
    from dropvision.calibrate.calibration import ClippedBackground
    from dropvision.calibrate.calibration_pass import illumination_under_clip

    img, light = _vignetted_clipped_frame()
    assert 0.3 < np.mean(img >= 255.0) < 0.9
    cal = SimpleNamespace(clipped=ClippedBackground(fraction=0.5, level=280.0, level_uncertainty=0.5, max_value=255,
                                                    level_known=True),
                          nozzle_found=True, tip_row=40.0, axis_col=160.0, nozzle_outer_diameter_px=40.0)
    fit = illumination_under_clip(img, cal, 255)
    assert fit is not None
    walls = np.mean([light[r, c] for r in np.linspace(0, 40, 12).round().astype(int) for c in (137, 183)])
    for row, col in ((120, 160), (150, 100), (60, 250)):
        d2, d3 = fit.level_offsets(row, col)
        assert d2 == pytest.approx(light[row, col] / walls - 1.0, abs=0.003)
        assert abs(d3 - d2) < 0.003
    # the body's term: the relative offset over the edge's slope, sqrt(2 pi) sigma / (1 - T_liquid)
    def context(clip_term_px, edge_position_sigma_px):
        return SimpleNamespace(
            geometry=SimpleNamespace(row0_px=0, col0_px=0), photometry=SimpleNamespace(liquid_level=0.1),
            blur=SimpleNamespace(clip_light=fit, clip_term_px=clip_term_px, correction_sigma_px=1.0,
                                 edge_position_sigma_px=edge_position_sigma_px),
            config=SimpleNamespace(edge_position_floor_px=0.0))

    ctx = context(0.01, 0.02)
    body = SimpleNamespace(centroid_row=120.0, centroid_col=160.0)
    rel = fit.relative_error(120.0, 160.0)
    assert rel > 0.05  # the centre lies well above the level read at the nozzle
    assert clip_level_px(body, ctx) == pytest.approx(rel * np.sqrt(2.0 * np.pi) / 0.9, rel=1e-9)
    assert common_edge_sigma_px(ctx, body) == pytest.approx(
        np.sqrt(0.02**2 - 0.01**2 + clip_level_px(body, ctx) ** 2), rel=1e-9)
    # the sequence's term (the level's excess over the clip) is the least: where it is larger, it stays
    wide = context(0.5, 0.5)
    assert clip_level_px(body, wide) < 0.5 and common_edge_sigma_px(wide, body) == pytest.approx(0.5)
    # a background clipped everywhere shows nothing of its shape: no fit
    assert illumination_under_clip(np.minimum(img * 0 + 255.0, 255.0), cal, 255) is None


def test_clipped_background_record_writes_the_same_keys():
    """`ClippedBackground` (a frozen record, no dict read with defaults) writes summary.json's
    ``calibration.clipped_background`` with its keys in their order; ``edge_range_px`` only with an
    unknown level."""
    from dropvision.calibrate.calibration import ClippedBackground

    known = ClippedBackground(fraction=0.6, level=280.0, level_uncertainty=0.5, max_value=255, level_known=True)
    assert list(known.to_dict()) == ["fraction", "level", "level_uncertainty", "max_value", "method", "level_known",
                                     "used"]
    assert known.to_dict()["used"] is True and known.to_dict()["method"] == ClippedBackground.METHOD
    lower = ClippedBackground(fraction=0.9, level=255.0, level_uncertainty=float("nan"), max_value=255,
                              level_known=False, edge_range_px=1.25)
    assert list(lower.to_dict())[-1] == "edge_range_px" and lower.to_dict()["edge_range_px"] == 1.25
    with pytest.raises(AttributeError):
        known.level = 300.0  # frozen

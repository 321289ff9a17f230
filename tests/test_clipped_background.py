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
from dropvision.sequence import sequence_from_arrays
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

"""An out-of-focus holder (issue 29): what hangs below its face is liquid only when dark and in focus; a
frame without a nozzle still measures its drops.

The face rules are checked on small constructed transmission images whose geometry is exact (a blurred
face, a sharp liquid cap, a blurred bump of the holder, a grey sharp bump), the whole measurement on a
synthetic drop-watcher frame (`dropvision.synth`, truth known) and on a frame holding only a drop.
"""

from __future__ import annotations

import json
import math
import warnings

import cv2
import numpy as np
import pandas as pd
import pytest

from dropvision.measurement import measure_sequence
from dropvision.calibrate.nozzle import bottom_profile, fit_face_line, protruding_columns

H, W, FACE, AXIS = 80, 200, 20, 100
LEVEL, THR = 0.1, 0.55


def _blur(mask: np.ndarray, sigma: float) -> np.ndarray:
    return cv2.GaussianBlur(mask.astype(np.float32), (0, 0), sigma)


def _holder(bump_px: int = 0, sigma: float = 8.0) -> np.ndarray:
    """Transmission of a holder block above row FACE blurred by ``sigma`` (its face lower by ``bump_px``
    over columns 80-119: the holder's own shape, out of focus like it)."""
    m = np.zeros((H, W), bool)
    m[:FACE] = True
    m[:FACE + bump_px, 80:120] = True
    return 1.0 - (1.0 - 0.05) * _blur(m, sigma)


def _cap(radius: float, level: float = LEVEL) -> np.ndarray:
    """Transmission factor of a sharp liquid cap hanging from the face at the axis (blur 1 px)."""
    yy, xx = np.mgrid[0:H, 0:W]
    m = ((xx - AXIS) ** 2 + (yy - FACE) ** 2 <= radius ** 2) & (yy >= FACE)
    return 1.0 - (1.0 - level) * _blur(m, 1.0)


def _judge(t: np.ndarray):
    body = t < THR
    face = np.full(W, float(FACE))
    return protruding_columns(body, t, face, AXIS, 0.5 * (THR + LEVEL), focus_limit_px=1.5 * 1.2 + 0.25)


def test_nothing_below_a_blurred_face():
    assert _judge(_holder()) is None


def test_a_sharp_dark_cap_is_liquid():
    found = _judge(_holder() * _cap(10.0))
    assert found is not None and found.liquid, found
    assert found.first <= AXIS - 8 and found.last >= AXIS + 8


def test_a_blurred_bump_of_the_holder_is_no_liquid():
    """As dark as liquid 12 px inside its blurred edge, but as soft as the holder: the capillary's face."""
    found = _judge(_holder(bump_px=16))
    assert found is not None and not found.liquid
    assert "out of focus" in found.reason, found.reason


def test_a_grey_sharp_bump_is_no_liquid():
    found = _judge(_holder() * _cap(10.0, level=0.8))
    assert found is not None and not found.liquid
    assert "not dark" in found.reason, found.reason


def test_the_face_line_ignores_what_hangs():
    cols = np.arange(300)
    bottom = 40.0 + 0.05 * cols
    bottom[140:170] += 12.0  # liquid hanging from it
    a, b = fit_face_line(cols, bottom)
    assert a == pytest.approx(40.0, abs=0.05) and b == pytest.approx(0.05, abs=1e-3)
    mask = np.zeros((60, 5), bool)
    mask[:10, 1] = True
    mask[:3, 3] = True
    assert bottom_profile(mask)[0].tolist() == [1, 3] and bottom_profile(mask)[1].tolist() == [9.0, 2.0]


def test_a_frame_without_a_nozzle_measures_its_drop(tmp_path):
    """No dark body at the top edge: the drop is measured about its own axis (quality no_nozzle), the
    jet's axis is the drop's line (x 0), what needs the nozzle is NaN (attached volume, z)."""
    r_px, px_um = 20.0, 5.0
    yy, xx = np.mgrid[0:240, 0:200]
    disc = (xx - 100.3) ** 2 + (yy - 140.6) ** 2 <= r_px ** 2
    t = 1.0 - 0.9 * _blur(disc, 1.0)
    img = np.clip(200.0 * t + np.random.default_rng(0).normal(0.0, 0.5, t.shape), 0, 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "f_500us.png"), img)
    (tmp_path / "sequence.json").write_text(json.dumps(
        {"pixel_size_um": px_um, "orientation": "down", "frames": [{"file": "f_500us.png", "delay_us": 500.0}]}))
    r = measure_sequence(tmp_path)
    row = r.frames.iloc[0]
    assert row["quality"] == "no_nozzle"
    truth_nl = 4.0 / 3.0 * math.pi * (r_px * px_um) ** 3 * 1e-6
    assert row["drop_volume_nl"] == pytest.approx(truth_nl, rel=0.01)
    assert abs(row["drop_x_um"]) < 0.5 * px_um
    assert math.isnan(row["attached_volume_nl"]) and math.isnan(row["drop_z_um"])
    assert any("no nozzle found" in n for n in r.summary["calibration"]["notes"])


@pytest.mark.slow
def test_out_of_focus_holder_single_frame_against_truth(tmp_path):
    """A synthetic drop watcher with its holder out of focus (capillary face inside it), one frame: the
    jet's axis from the drops (their offset from it is the truth's), the attached volume what hangs below
    the face, within 2 of its stated uncertainties of the truth (the resting meniscus, 0.23 nl)."""
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    cfg = SynthConfig.for_rig("watcher-blurred-holder", width_px=640, height_px=1024, tip_row=160.4,
                              axis_col=319.6, delays_us=(1300.0,), write_nozzle_diameters=False, seed=38)
    seq = write_synthetic_sequence(cfg, tmp_path / "seq", progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour JPEG noted once
        r = measure_sequence(seq)
    row = r.frames.iloc[0]
    truth = pd.read_csv(seq / "truth_frames.csv").iloc[0]
    assert r.summary["calibration"]["nozzle_out_of_focus"]
    assert abs(row["drop_x_um"] - truth["drop_x_um"]) < 5.0, (row["drop_x_um"], truth["drop_x_um"])
    att, u = float(row["attached_volume_nl"]), float(row["attached_volume_uncertainty_nl"])
    assert math.isfinite(att) and math.isfinite(u), (att, u)
    assert abs(att - truth["attached_volume_nl"]) <= 2 * u, (att, u, truth["attached_volume_nl"])
    assert row["drop_volume_nl"] == pytest.approx(truth["drop_volume_nl"], rel=0.01)

"""Calibration finds the nozzle the way a person does (issue 11 item 5): in a holder block with a
dark wedge and reflections, drops flying right (colour JPEG), tilted either way; a nozzle barely
protruding is flagged, never silently wrong."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dropvision.measurement import measure_sequence
from dropvision.synth import SynthConfig, write_synthetic_sequence

# the rig writes colour JPEGs: their conversion to grey is announced once per sequence
pytestmark = pytest.mark.filterwarnings("ignore::dropvision.io.sequence.RGBConvertedWarning")

WATCHER = dict(width_px=640, height_px=1024, tip_row=120.4, axis_col=319.6)


def _measure(tmp_path, **kw):
    cfg = SynthConfig.for_rig("watcher-side", **{**WATCHER, **kw})
    write_synthetic_sequence(cfg, tmp_path / "seq", progress=False)
    truth = json.loads((tmp_path / "seq" / "truth.json").read_text())
    return measure_sequence(tmp_path / "seq"), truth


@pytest.mark.parametrize("tilt_deg", [0.0, 1.5, -2.0])
@pytest.mark.slow
def test_nozzle_in_a_holder_block(tmp_path, tilt_deg):
    r, truth = _measure(tmp_path, tilt_deg=tilt_deg, delays_us=(0.0, 100.0, 200.0), seed=3)
    cal = r.summary["calibration"]
    assert cal["orientation"] == "right"
    assert abs(cal["tip_row"] - truth["calibration"]["tip_row"]) < 0.2
    assert abs(cal["axis_col"] - truth["calibration"]["axis_col"]) < 0.3
    assert abs(cal["tilt_deg"] - tilt_deg) < 0.15  # short walls: from the holder's face
    assert abs(cal["pixel_size_disagreement_percent"]) < 0.5
    assert (r.frames["quality"] == "ok").all()


@pytest.mark.filterwarnings("ignore::dropvision.calibrate.calibration.CalibrationWarning")
@pytest.mark.slow
def test_nozzle_barely_protruding_is_flagged_not_guessed(tmp_path):
    r, truth = _measure(tmp_path, nozzle_protrusion_um=15.0, tilt_deg=1.5,
                        delays_us=tuple(float(d) for d in range(0, 1501, 100)), seed=3)
    assert not (r.frames["quality"] == "ok").any()
    assert np.isnan(r.summary["inflight_volume_nl"])


def test_small_dark_bodies_in_a_large_vignetted_frame_are_not_low_contrast():
    """A nozzle and drop covering well under 1 % of a frame with a little vignetting: the
    low-contrast rules must not take the background's fall-off for the bodies."""
    from dropvision.calibrate.calibration import calibrate_frames

    h = w = 1024
    yy, xx = np.mgrid[0:h, 0:w]
    rho2 = ((yy - h / 2) ** 2 + (xx - w / 2) ** 2) / (h / 2) ** 2
    img = 220.0 * (1.0 - 0.06 * rho2 / 2)
    img[:80, 502:522] = 15.0  # a 20 px needle
    img[(yy - 300) ** 2 + (xx - 512) ** 2 <= 100] = 20.0  # a drop, r = 10 px
    img = np.clip(img, 0, 255).astype(np.uint8)
    cal = calibrate_frames(img, [img], 5.0)
    assert abs(cal.axis_col - 511.5) < 0.5
    assert cal.liquid_level < 0.2

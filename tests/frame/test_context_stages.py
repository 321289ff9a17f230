"""Calibration-pass stages that take arrays and return a small result (dropvision/calibrate/calibration_pass.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from dropvision.calibrate.blur import edge_sigma_px
from dropvision.calibrate.calibration import EDGE_FLOOR_TERM, calibrate_frames, pixel_scale
from dropvision.config import MeasureConfig
from dropvision.calibrate.calibration_pass import (APPEARANCE_DTYPE, InFocusAxis, body_blur_reference,
                                                   calibration_uncertainty, focus_reference, noise_smoothing,
                                                   smoothed_sigma_px, wall_reference)
from dropvision.calibrate.frame_context import BlurReference, smoothing_kernel_sigma_px
from dropvision.frame.edges import edge_threshold
from dropvision.calibrate.nozzle import find_nozzle
from dropvision.synth import SynthConfig, synthesize


@pytest.fixture(scope="module")
def first_frame():
    cfg = SynthConfig(width_px=160, height_px=320, delays_us=(0.0,))
    img, _ = next(iter(synthesize(cfg, progress=False)))
    cal = calibrate_frames(img, [img], cfg.pixel_size_um)
    t = np.asarray(img, np.float32) / cal.background.background
    nozzle = find_nozzle(t, edge_threshold(cal.nozzle_level))
    return cal, nozzle, t, edge_sigma_px(t, nozzle)


def test_wall_reference_from_the_dry_walls(first_frame):
    cal, nozzle, t, sigma = first_frame
    config = MeasureConfig()
    ref = wall_reference(nozzle, cal.tip_row, cal.background.background, t, sigma, cal.liquid_level, config)
    assert ref is not None
    assert ref.rows.shape == ref.cols.shape == ref.inv_background.shape and ref.rows.shape[0] >= 4
    assert ref.inv_background.dtype == np.float32
    assert np.all(ref.rows <= cal.tip_row - 3)  # dry walls only
    assert ref.blur_sigma_px == pytest.approx(sigma) and ref.sharpness > 0
    assert ref.max_frame_blur_px == pytest.approx(min(config.max_blur_px, (1 + config.blur_change_tolerance) * sigma))
    assert 0 < ref.min_wall_contrast < 1


def test_wall_reference_none_without_a_blur_or_walls(first_frame):
    cal, nozzle, t, sigma = first_frame
    config = MeasureConfig()
    assert wall_reference(nozzle, cal.tip_row, cal.background.background, t, float("nan"), cal.liquid_level,
                          config) is None
    # the tip plane above every wall row: no dry wall
    assert wall_reference(nozzle, float(nozzle.rows.min()), cal.background.background, t, sigma, cal.liquid_level,
                          config) is None


def _found(*bodies):
    """Detached bodies (edge spread px, ESF sigma px) as `detached_appearances` returns them."""
    return np.array([(0, 100, 0.2, spread, sigma) for spread, sigma in bodies], APPEARANCE_DTYPE)


def test_body_blur_reference_only_when_the_walls_are_out_of_focus():
    config = MeasureConfig()
    found = _found((1.0, 0.9), (2.0, 1.8))
    limit = config.mist_blur_factor * 1.0 + config.mist_blur_offset_px
    assert body_blur_reference(found, limit, 1.1, config) is None  # walls as sharp as allowed
    assert body_blur_reference(_found(), 5.0, 1.1, config) is None  # no detached body
    ref = body_blur_reference(found, limit + 0.5, 1.1, config)
    assert ref.reference_spread_px == 1.0 and ref.calibrated_sigma_px == 0.9  # the sharpest body's
    assert ref.nozzle_sigma_px == 1.1  # the walls' own fit
    # no wall fit: the body's sigma scaled by the two spreads; no wall spread either: 3 x
    assert body_blur_reference(found, limit + 0.5, float("nan"), config).nozzle_sigma_px == pytest.approx(
        0.9 * (limit + 0.5) / 1.0)
    assert body_blur_reference(found, float("nan"), float("nan"), config).nozzle_sigma_px == pytest.approx(2.7)
    # the sharpest body without an ESF fit: its edge spread
    assert body_blur_reference(_found((1.0, float("nan"))), 5.0, 1.1, config).calibrated_sigma_px == 1.0


def _noisy(std, shape=(200, 80), seed=0):
    return (1.0 + np.random.default_rng(seed).normal(0.0, std, shape)).astype(np.float32)


def test_noise_smoothing_smooths_only_noisy_frames():
    config = MeasureConfig()
    quiet = noise_smoothing(_noisy(0.2 * config.smooth_noise_limit), 1.0, config, default_noise_transmission=0.01)
    assert quiet.noise_transmission == pytest.approx(0.2 * config.smooth_noise_limit, rel=0.1)
    assert quiet.smoothing_sigma_px == 0.0 and quiet.correction_sigma_px == 1.0  # blur correction untouched
    noisy = noise_smoothing(_noisy(3.0 * config.smooth_noise_limit), 1.0, config, default_noise_transmission=0.01)
    assert noisy.noise_transmission > config.smooth_noise_limit
    assert noisy.smoothing_sigma_px == config.smooth_px > 0
    # the truncated kernel's own standard deviation added in quadrature
    assert noisy.correction_sigma_px == pytest.approx(math.hypot(1.0, smoothing_kernel_sigma_px(config.smooth_px)))
    # without a blur correction (sigma 0) the smoothing adds none
    assert noise_smoothing(_noisy(3.0 * config.smooth_noise_limit), 0.0, config, default_noise_transmission=0.01).correction_sigma_px == 0.0
    # too few bright pixels to measure: the default
    dark = np.full((50, 50), 0.5, np.float32)
    assert noise_smoothing(dark, 1.0, config, default_noise_transmission=0.0123).noise_transmission == 0.0123


def test_smoothed_sigma_hand_values():
    assert smoothed_sigma_px(1.5, 0.0) == 1.5
    assert smoothed_sigma_px(0.0, 2.0) == 0.0
    # the kernel is truncated at +-2 sigma: narrower than the nominal sigma
    assert 0.8 * 2.0 < smoothing_kernel_sigma_px(2.0) < 2.0
    assert smoothed_sigma_px(1.5, 2.0) == pytest.approx(math.hypot(1.5, smoothing_kernel_sigma_px(2.0)))


def test_focus_reference_walls_in_focus_keep_their_references():
    config = MeasureConfig()
    found = _found((1.0, 0.9))
    limit = config.mist_blur_factor * 1.0 + config.mist_blur_offset_px
    ref = focus_reference(found, limit, 1.1, 1.3, 2.0, config)
    assert not ref.nozzle_out_of_focus and ref.note is None
    assert (ref.reference_spread_px, ref.blur_reference) == (limit, BlurReference.NOZZLE_WALLS)
    assert ref.mist_blur_factor == config.mist_blur_factor
    assert ref.calibrated_sigma_px == 1.1 and ref.correction_sigma_px == 1.3 and ref.nozzle_sigma_px == 0.0


def test_focus_reference_walls_out_of_focus_take_the_sharpest_body():
    config = MeasureConfig()
    found = _found((1.0, 0.9), (2.0, 1.8))
    ref = focus_reference(found, 4.0, 1.1, 1.3, 0.0, config)
    assert ref.nozzle_out_of_focus and "out of focus (edge spread 4.00 px against 1.00 px" in ref.note
    assert ref.reference_spread_px == 1.0 and ref.blur_reference is BlurReference.SHARPEST_BODY
    assert ref.mist_blur_factor == config.mist_blur_factor_bodies
    assert ref.calibrated_sigma_px == 0.9 and ref.correction_sigma_px == 0.9 and ref.nozzle_sigma_px == 1.1
    # smoothed frames: the kernel added to the body's blur; no blur correction: none
    assert focus_reference(found, 4.0, 1.1, 1.3, 2.0, config).correction_sigma_px == pytest.approx(
        math.hypot(0.9, smoothing_kernel_sigma_px(2.0)))
    off = MeasureConfig(blur_correction=False)
    assert focus_reference(found, 4.0, 1.1, 0.0, 2.0, off).correction_sigma_px == 0.0


def test_the_calibration_is_frozen_and_a_stage_gives_a_new_one(first_frame):
    """No attribute is assigned on a calibration: a stage's result (`InFocusAxis`) gives a new one."""
    cal = first_frame[0]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cal.tip_row = 0.0
    stage = InFocusAxis(axis_col=cal.axis_col + 2.0, axis_source="drops", tip_row=cal.tip_row + 1.0, tip_source="face",
                        liquid_level=0.2, threshold=edge_threshold(0.2), face=(10.0, 0.0), notes=("moved",))
    new = stage.applied_to(cal)
    assert (new.axis_col, new.tip_row) == (cal.axis_col + 2.0, cal.tip_row + 1.0)
    assert (new.axis_source, new.tip_source, new.liquid_level) == ("drops", "face", 0.2)
    assert new.threshold == pytest.approx(0.6)  # half-way between the liquid's 0.2 and 1
    assert new.notes == cal.notes + ("moved",) and new.background is cal.background
    assert cal.axis_source != "drops" and "moved" not in cal.notes  # the input unchanged


def test_pixel_scale_against_the_outer_diameter(first_frame):
    cal, nozzle = first_frame[:2]
    d_px = nozzle.outer_diameter_px
    off = pixel_scale(nozzle, 2.0, 1.1 * 2.0 * d_px, from_nozzle=False, tolerance=0.02, edge_position_floor_px=0.05)
    assert off.ratio == pytest.approx(1.1) and off.disagreement_percent == pytest.approx(100 * (1 / 1.1 - 1))
    assert off.pixel_size_um == 2.0 and off.note is not None and "disagrees by -9.1 %" in off.note
    assert off.ratio_uncertainty > 0
    assert pixel_scale(nozzle, 2.0, 1.01 * 2.0 * d_px, from_nozzle=False, tolerance=0.02,
                       edge_position_floor_px=0.05).note is None
    own = pixel_scale(nozzle, 1.0, 500.0, from_nozzle=True, tolerance=0.02, edge_position_floor_px=0.05)
    assert own.pixel_size_um == pytest.approx(500.0 / d_px) and own.outer_diameter_um == pytest.approx(500.0)
    assert math.isnan(own.ratio) and own.note is None and own.source.startswith("nozzle outer diameter 500 um / ")


def test_calibration_uncertainty_with_a_pixel_size_from_the_needle(first_frame):
    cal, nozzle, _, sigma = first_frame
    config = MeasureConfig()
    given = calibration_uncertainty(cal, nozzle, sigma, config)
    assert given.pixel_size == {} and given.nozzle_width_terms_px == {}
    assert given.edge_position_terms_px[EDGE_FLOOR_TERM] == config.edge_position_floor_px
    assert given.edge_position_uncertainty_px == pytest.approx(math.hypot(*given.edge_position_terms_px.values()))
    needle = calibration_uncertainty(dataclasses.replace(cal, pixel_size_from_nozzle=True), nozzle, sigma, config)
    u_width = math.hypot(*needle.nozzle_width_terms_px.values())
    u = needle.pixel_size["pixel_size_uncertainty_um"]
    assert u > 0 and u == pytest.approx(cal.pixel_size_um * u_width / cal.nozzle_outer_diameter_px)
    out = dataclasses.replace(cal, **needle.calibration_fields())
    assert out.pixel_size_ratio == 1.0 and out.pixel_size_ratio_uncertainty == pytest.approx(u / cal.pixel_size_um)
    assert out.pixel_size_relative_uncertainty == pytest.approx(u / cal.pixel_size_um)
    assert out.pixel_size_source.startswith(cal.pixel_size_source + " = ")

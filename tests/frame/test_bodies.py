"""bodies.parquet: every dark body classified with its reason; out-of-focus mist and static dust
never counted as satellites (`dropvision.output.bodies_table`)."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest

from dropvision.config import MeasureConfig
from dropvision.measurement import measure_sequence
from dropvision.io.sequence import sequence_from_arrays
from dropvision.synth import SynthConfig, synthesize
from dvcore import schema

DELAYS = tuple(float(d) for d in range(0, 1501, 30))


def _blob(shape, row, col, radius_px, sigma_px, depth):
    """Multiplicative attenuation of an out-of-focus droplet (disc blurred by ``sigma_px``)."""
    disc = np.zeros(shape, np.float32)
    cv2.circle(disc, (int(round(col)), int(round(row))), int(round(radius_px)), 1.0, -1)
    disc = cv2.GaussianBlur(disc, (0, 0), sigma_px)
    return 1.0 - depth * disc / max(float(disc.max()), 1e-6)


@pytest.fixture(scope="module")
def misty():
    cfg = SynthConfig(u1_um_per_ms=62, u2_um=30, satellites=2, width_px=320, height_px=700, delays_us=DELAYS,
                      seed=5, dust=0)
    frames, truths = [], []
    rng = np.random.default_rng(1)
    static = _blob((700, 320), 520, 175, 6, 3.5, 0.75)  # dust on a window, beside the jet
    mist = []
    for img, t in synthesize(cfg, progress=False):
        att = static.copy()
        k = len(frames)
        for _ in range(2):  # drifting mist: a new place in every frame
            r, c = rng.uniform(200, 660), rng.uniform(110, 210)
            att *= _blob(img.shape, r, c, rng.uniform(4, 8), rng.uniform(3.0, 6.0), rng.uniform(0.7, 0.9))
            mist.append((k, r, c))
        frames.append(np.clip(img.astype(np.float32) * att, 0, 255).astype(np.uint8))
        truths.append(t)
    seq = sequence_from_arrays(frames, delays_us=[t.delay_us for t in truths], pixel_size_um=cfg.pixel_size_um,
                               nozzle_inner_diameter_um=cfg.physics.nozzle_inner_radius_um * 2,
                               nozzle_outer_diameter_um=cfg.physics.nozzle_outer_radius_um * 2)
    return measure_sequence(seq), truths, mist


@pytest.mark.slow
def test_bodies_table_follows_its_schema(misty):
    result, _, _ = misty
    schema.check_table(result.bodies, schema.BODIES, "bodies.parquet")
    assert set(result.bodies["body_class"]) <= set(schema.BODY_CLASSES)
    assert (result.bodies["reason"].str.len() > 0).all()


def test_n_satellites_is_the_counted_bodies(misty):
    result, _, _ = misty
    counted = result.bodies.groupby(["file", "delay_us", "repeat"])["counted"].sum()
    f = result.frames.set_index(["file", "delay_us", "repeat"])
    known = f["n_satellites"].notna()
    assert (counted.reindex(f.index[known]).fillna(0).astype(int) == f.loc[known, "n_satellites"].astype(int)).all()


def test_mist_and_dust_never_counted_and_satellites_exact(misty):
    result, truths, mist = misty
    b = result.bodies
    soft = b[b["body_class"].isin(["mist", "dust"])]
    assert len(soft) >= len(mist) // 2  # most blobs are dark enough to be segmented at all
    assert not soft["counted"].any()
    # the static blob is folded into the background by the calibration (or listed as dust); the
    # drifting ones are mist
    near_static = np.hypot(b["row_px"] - 520, b["col_px"] - 175) < 4
    assert b.loc[near_static, "body_class"].isin(["dust"]).all()
    assert (soft.loc[~np.hypot(soft["row_px"] - 520, soft["col_px"] - 175).lt(4), "body_class"] == "mist").all()
    # no blob was taken for liquid: satellites exact wherever the truth's drop is in view
    f = result.frames
    t = pd.DataFrame([x.to_dict() for x in truths])
    view = (~t["attached"]) & t["drop_in_view"] & f["n_satellites"].notna()
    assert view.sum() >= 5
    assert (f.loc[view, "n_satellites"].astype(int) == t.loc[view, "n_satellites"]).all()
    inflight = f["inflight"] & t["inflight"]
    err = (f.loc[inflight, "drop_volume_nl"] / t.loc[inflight, "drop_volume_nl"] - 1).abs()
    assert err.max() < 0.01


def test_in_focus_bodies_are_not_mist(misty):
    result, _, _ = misty
    b = result.bodies
    liquid = b[b["body_class"].isin(["main_drop", "satellite"])]
    ref = float(b["edge_blur_ref_px"].iloc[0])
    limit = MeasureConfig().mist_blur_factor * ref + MeasureConfig().mist_blur_offset_px
    assert liquid["edge_blur_px"].max() < limit - 0.1 * ref  # a margin of 10 % of the walls' spread
    soft = b[b["body_class"] == "mist"]
    assert soft["edge_blur_px"].min() > limit

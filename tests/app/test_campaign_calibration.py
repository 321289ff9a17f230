"""The campaign's calibration checks reach identify through the dataset, in its declared columns.

``dropvision campaign`` copies each sequence's pixel-size check and in-flight frame count from
its summary.json into summary.parquet (`dvcore.schema.DATASET_SUMMARY`); identify reads them
there (`identify.dataset.campaign_calibration`) and never the campaign's shard layout.
"""

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from dropvision.app.campaign import run_campaign, synth_campaign
from dvcore import schema
from identify.dataset import CALIBRATION_COLUMNS, campaign_calibration
from identify.dataset_checks import load_dataset
from identify.measurement_uncertainty import measurement_uncertainty, sequence_standard_errors
from identify.synthetic_dataset import make_synthetic_dataset

SMALL = {"width_px": 128, "height_px": 448, "tip_row": 30.3, "axis_col": 63.6,
         "delays_us": tuple(float(d) for d in range(0, 1501, 10)), "noise": 0.3, "dust": 1}


def test_calibration_columns_are_declared():
    declared = {c.name for c in schema.DATASET_SUMMARY.columns}
    assert set(CALIBRATION_COLUMNS) <= declared


@pytest.mark.slow
def test_campaign_writes_the_checks_into_the_dataset(tmp_path):
    synth_campaign(tmp_path / "grid", [70.0], [25.0, 30.0], workers=1, progress=False, overrides=SMALL)
    run_campaign(tmp_path / "grid", tmp_path / "ds", workers=1, progress=False)
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    su = pd.read_parquet(tmp_path / "ds" / "summary.parquet")
    assert len(su) == 2
    expected = []
    for sid in su["sequence_id"]:
        shard = tmp_path / "ds" / "shards" / manifest["sequences"][str(sid)]["shard"]
        s = json.loads((shard / "summary.json").read_text())
        expected.append([s["calibration"]["pixel_size_ratio"], s["calibration"]["pixel_size_ratio_uncertainty"],
                         s["inflight_frames"]])
    expected = np.array(expected, float)
    assert np.isfinite(expected).all()  # the synthetic nozzle gives a pixel-size check
    # the dataset alone carries them: identify reads the same values with the shards gone
    shutil.rmtree(tmp_path / "ds" / "shards")
    cal = campaign_calibration(load_dataset(tmp_path / "ds", min_controls=2))
    np.testing.assert_array_equal(cal[list(CALIBRATION_COLUMNS)].to_numpy(float), expected)


def test_dataset_columns_set_the_measurement_term(tmp_path):
    """NaN where a sequence has no check: the others set the pixel-size term and the standard
    errors; a dataset whose columns hold no value has no campaign calibration."""
    d = tmp_path / "ds"
    make_synthetic_dataset(d, grid=[(a, b) for a in (55.0, 65.0, 75.0) for b in (20.0, 27.5, 35.0)],
                           noise_percent=0.5, seed=3)
    meta = json.loads((d / "dataset.json").read_text())
    meta.pop("measurement_uncertainty", None)
    (d / "dataset.json").write_text(json.dumps(meta))
    su = pd.read_parquet(d / "summary.parquet")
    for c in CALIBRATION_COLUMNS:
        su[c] = np.nan
    su["inflight_volume_std_nl"] = 0.004
    su.to_parquet(d / "summary.parquet", index=False)
    assert campaign_calibration(load_dataset(d)) is None
    su.loc[1:, "pixel_size_ratio"] = 0.9998
    su.loc[1:, "pixel_size_ratio_uncertainty"] = 0.0009
    su.loc[1:, "inflight_frames"] = 16.0
    su.to_parquet(d / "summary.parquet", index=False)
    ds = load_dataset(d)
    cal = campaign_calibration(ds)
    assert np.isnan(cal["pixel_size_ratio"].iloc[0]) and (cal["pixel_size_ratio"].iloc[1:] == 0.9998).all()
    m = measurement_uncertainty(ds)
    assert m["pixel_size_rel"] == pytest.approx(np.hypot(0.0002, 0.0009))
    assert "8 sequence(s)" in m["source"]
    se = sequence_standard_errors(ds)["inflight_volume_nl"]
    assert np.isnan(se[0]) and se[1:] == pytest.approx(0.001)

"""identify.dataset: synthetic generator and validation errors."""

import json

import numpy as np
import pandas as pd
import pytest

from identify.dataset import DatasetError, default_physics
from identify.dataset_checks import load_dataset
from identify.synthetic_dataset import make_synthetic_dataset

GRID = [(u1, u2) for u1 in (50.0, 65.0, 80.0) for u2 in (20.0, 27.5, 35.0)]


@pytest.fixture(scope="module")
def ds_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("ds") / "ds"
    make_synthetic_dataset(d, grid=GRID, noise_percent=0.0, seed=0)
    return d


def _copy(ds_dir, tmp_path, ts=None, su=None, meta=None):
    out = tmp_path / "bad"
    out.mkdir()
    t = pd.read_parquet(ds_dir / "timeseries.parquet")
    s = pd.read_parquet(ds_dir / "summary.parquet")
    m = json.loads((ds_dir / "dataset.json").read_text())
    (ts or (lambda x: x))(t).to_parquet(out / "timeseries.parquet")
    (su or (lambda x: x))(s).to_parquet(out / "summary.parquet")
    (out / "dataset.json").write_text(json.dumps((meta or (lambda x: x))(m)))
    return out


def test_roundtrip_and_truth(ds_dir):
    ds = load_dataset(ds_dir)
    assert ds.n_sequences == len(GRID)
    assert ds.dead_time_us == 220.0 and ds.sample_interval_us == 10.0
    ph = default_physics()
    row = ds.summary.set_index(["u1_um_per_ms", "u2_um"]).loc[(65.0, 27.5)]
    # noise-free: pinch-off law and Eq. (16)/(17) adjusters hold exactly
    assert row["pinchoff_us"] == pytest.approx(1050 - 14 * (65 - 70) + 10.2 * 2.5)
    assert row["inflight_volume_nl"] - row["grown_volume_at_pinchoff_nl"] == pytest.approx(0.16 + 0.014 * 65 + 0.0037 * 27.5)
    assert row["jetting_velocity_m_s"] - row["flow_velocity_at_max_stroke_m_s"] == pytest.approx(-0.155 + 0.0025 * 65 + 0.0008 * 27.5)
    # the team's reference point: ~18.5 nl peak near 1000 us, 1.30 m/s at max stroke (u1=70, u2=25)
    p = ph.ecm_parameters()
    assert p.damping_ratio() == pytest.approx(0.2, abs=0.01)
    assert p.natural_frequency_hz() == pytest.approx(800.0)
    hyd = ds.hydraulics()
    assert hyd.LN == pytest.approx(p.LN) and hyd.RR == pytest.approx(p.RR)
    # attached rows have finite volumes, detached rows NaN
    ts = ds.timeseries
    assert ts.loc[ts.attached, "grown_volume_nl"].notna().all()
    assert ts.loc[~ts.attached, "grown_volume_nl"].isna().all()


@pytest.mark.parametrize(
    "mutate, match",
    [
        (dict(ts=lambda t: t.drop(columns=["grown_volume_nl"])), r"timeseries\.parquet: missing column\(s\) grown_volume_nl"),
        (dict(su=lambda s: s.drop(columns=["pinchoff_us"])), r"summary\.parquet: missing column\(s\) pinchoff_us"),
        (dict(su=lambda s: s.assign(inflight_volume_nl=-s.inflight_volume_nl)), r"inflight_volume_nl has negative volumes"),
        (dict(ts=lambda t: t.assign(u1_um_per_ms=-t.u1_um_per_ms), su=lambda s: s.assign(u1_um_per_ms=-s.u1_um_per_ms)),
         r"u1_um_per_ms must be > 0"),
        (dict(ts=lambda t: t.assign(delay_us=t.delay_us * 1.05)), r"delay_us .*(sampling grid|gaps)"),
        (dict(su=lambda s: s.assign(inflight_volume_nl=np.where(s.index == 2, np.inf, s.inflight_volume_nl))),
         r"summary\.parquet: column inflight_volume_nl has 1 inf"),
        (dict(ts=lambda t: t.assign(attached=t.attached.astype(int))), r"attached must be boolean"),
        (dict(ts=lambda t: t[t.sequence_id == 0], su=lambda s: s[s.sequence_id == 0]), r"only 1 sequence"),
        (dict(ts=lambda t: t[t.sequence_id < 2], su=lambda s: s[s.sequence_id < 2]), r"only 1 distinct|distinct \(u1_um_per_ms, u2_um\)"),
        (dict(meta=lambda m: {k: v for k, v in m.items() if k != "nozzle_inner_diameter_um"}), r"dataset\.json: missing key nozzle_inner_diameter_um"),
        (dict(meta=lambda m: m | {"sample_interval_us": "ten"}), r"sample_interval_us must be a number"),
    ],
)
def test_bad_input(ds_dir, tmp_path, mutate, match):
    bad = _copy(ds_dir, tmp_path, **mutate)
    with pytest.raises(DatasetError, match=match):
        load_dataset(bad)


def test_too_few_controls(ds_dir, tmp_path):
    # two sequences at the same (u1, u2): several sequences, but one control pair
    bad = _copy(ds_dir, tmp_path, ts=lambda t: t[t.sequence_id < 2].assign(u1_um_per_ms=50.0, u2_um=20.0),
                su=lambda s: s[s.sequence_id < 2].assign(u1_um_per_ms=50.0, u2_um=20.0))
    with pytest.raises(DatasetError, match=r"only 1 distinct \(u1_um_per_ms, u2_um\) pair"):
        load_dataset(bad)


def test_missing_folder_and_file(tmp_path):
    with pytest.raises(DatasetError, match="dataset folder not found"):
        load_dataset(tmp_path / "nope")
    with pytest.raises(DatasetError, match=r"timeseries\.parquet: missing file"):
        load_dataset(tmp_path)


def test_synthetic_dataset_truth_is_the_synthesizer_truth(tmp_path):
    """identify's synthetic datasets and dropvision's synthetic images share one physics."""
    from identify.physics import drop_history

    ph = default_physics()
    make_synthetic_dataset(tmp_path / "ds", grid=[(55.0, 22.5), (72.5, 31.0), (62.5, 35.0)], noise_percent=0.0, seed=0)
    su = load_dataset(tmp_path / "ds").summary
    for row in su.itertuples():
        h = drop_history(ph, row.u1_um_per_ms, row.u2_um)
        assert row.inflight_volume_nl == pytest.approx(h.inflight_volume_nl, rel=1e-3)
        assert row.jetting_velocity_m_s == pytest.approx(h.jetting_velocity_m_s, rel=1e-3)


@pytest.mark.parametrize("mutate", [
    dict(su=lambda s: s.assign(inflight_volume_nl=np.where(s.index == 2, np.nan, s.inflight_volume_nl))),
    dict(ts=lambda t: t.assign(grown_volume_nl=np.where(t.index == 5, np.nan, t.grown_volume_nl))),
    dict(ts=lambda t: pd.concat([t, t.iloc[[3]]])),
])
def test_irregular_input_is_accepted(ds_dir, tmp_path, mutate):
    """Issue 13 item 5: a NaN summary value (not measured), an attached frame without a volume
    (missing frame) and a repeated delay were refused before; the fits now drop or average
    them with a note (tests/app/test_irregular_campaigns.py)."""
    load_dataset(_copy(ds_dir, tmp_path, **mutate))

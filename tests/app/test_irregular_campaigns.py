"""Irregular campaigns (issue 13 item 5): the fit uses what is there, notes what it dropped and
why, and refuses only when nothing usable is left. Each irregularity is made by editing the
parquet files of a synthetic dataset."""

import shutil

import numpy as np
import pandas as pd
import pytest

from identify.dataset import DatasetError, default_physics
from identify.dataset_checks import load_dataset
from identify.synthetic_dataset import make_synthetic_dataset
from identify.hybrid_fit import fit_hybrid
from identify.physics import drop_history

#: seconds per test (fitted models, campaigns, subprocesses): left out of `make test-fast`
pytestmark = pytest.mark.slow

GRID = [(float(a), float(b)) for a in (50, 60, 70, 80) for b in (20, 25, 30, 35)]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    d = tmp_path_factory.mktemp("irr") / "ds"
    make_synthetic_dataset(d, grid=GRID, noise_percent=1.0, seed=4)
    return d


def _edit(base, tmp_path, ts=None, su=None):
    d = tmp_path / "edited"
    shutil.copytree(base, d)
    for name, fn in (("timeseries.parquet", ts), ("summary.parquet", su)):
        if fn is not None:
            fn(pd.read_parquet(d / name)).to_parquet(d / name, index=False)
    return d


def _check_predictions(rep):
    ph = default_physics()
    for u1, u2 in [(55.0, 22.0), (65.0, 28.0), (75.0, 32.0)]:
        p = rep.model.predict(u1, u2)
        h = drop_history(ph, u1, u2)
        assert p["inflight_volume_nl"] == pytest.approx(h.inflight_volume_nl, rel=0.01)
        assert p["jetting_velocity_m_s"] == pytest.approx(h.jetting_velocity_m_s, rel=0.02)


def test_gap_uses_contiguous_run(base, tmp_path):
    # sequence 5 misses the frames at 500 and 510 us
    d = _edit(base, tmp_path, ts=lambda t: t[~((t.sequence_id == 5) & t.delay_us.isin([500.0, 510.0]))])
    rep = fit_hybrid(load_dataset(d), arx=False)
    assert any("sequence 5: frames missing from 500 us" in n and "50 contiguous samples up to 490 us" in n for n in rep.notes)
    assert rep.ecm_fit.n_sequences == len(GRID)
    assert rep.pinchoff_selection.fit.n_samples == len(GRID)
    assert rep.model.to_dict()["notes"] == rep.notes
    _check_predictions(rep)


def test_early_gap_drops_sequence_from_time_series_fits(base, tmp_path):
    d = _edit(base, tmp_path, ts=lambda t: t[~((t.sequence_id == 2) & (t.delay_us == 30.0))])
    rep = fit_hybrid(load_dataset(d), arx=False)
    assert any("sequence 2: only 3 contiguous sample(s)" in n and "dropped from the ECM/ARX fits" in n
               for n in rep.notes)
    assert rep.ecm_fit.n_sequences == len(GRID) - 1
    assert rep.pinchoff_selection.fit.n_samples == len(GRID)  # summary values still used


def test_repeated_delays_are_averaged(base, tmp_path):
    def rep_rows(t):
        extra = t[(t.sequence_id == 3) & t.delay_us.isin([400.0, 410.0])].copy()
        extra["grown_volume_nl"] += 0.01
        return pd.concat([t, extra], ignore_index=True)
    rep = fit_hybrid(load_dataset(_edit(base, tmp_path, ts=rep_rows)), arx=False)
    assert any("sequence 3: 2 repeated delay(s) averaged" in n for n in rep.notes)
    assert rep.ecm_fit.n_sequences == len(GRID)
    _check_predictions(rep)


def test_failed_sequence_and_no_pinchoff(base, tmp_path):
    def su_edit(s):
        s = s.copy()
        s.loc[s.sequence_id == 7, ["pinchoff_us", "inflight_volume_nl", "grown_volume_at_pinchoff_nl"]] = np.nan
        return s
    # sequence 9 failed: no time-series rows; sequence 7: no pinch-off seen
    d = _edit(base, tmp_path, ts=lambda t: t[t.sequence_id != 9], su=su_edit)
    rep = fit_hybrid(load_dataset(d), arx=False)
    notes = "\n".join(rep.notes)
    assert "sequence 9: no time-series rows" in notes
    assert "pinchoff: 1 sequence(s) without pinchoff_us dropped (e.g. 7)" in notes
    assert "volume_adjuster: 1 sequence(s) without pinchoff_us dropped" in notes
    assert rep.pinchoff_selection.fit.n_samples == len(GRID) - 1
    assert rep.velocity_selection.fit.n_samples == len(GRID)
    assert rep.ecm_fit.n_sequences == len(GRID) - 1
    assert np.isnan(rep.training.set_index("sequence_id").loc[7, "volume_adjustment_nl"])
    _check_predictions(rep)


def test_attached_frame_without_volume_is_a_missing_frame(base, tmp_path):
    def ts_edit(t):
        t = t.copy()
        t.loc[(t.sequence_id == 4) & (t.delay_us == 600.0), "grown_volume_nl"] = np.nan
        return t
    rep = fit_hybrid(load_dataset(_edit(base, tmp_path, ts=ts_edit)), arx=False)
    assert any("sequence 4: 1 attached frame(s) without a volume treated as missing" in n for n in rep.notes)
    assert any("sequence 4: frames missing from 600 us" in n for n in rep.notes)


def test_refused_when_too_few_controls_usable(base, tmp_path):
    d = _edit(base, tmp_path, su=lambda s: s.assign(
        inflight_volume_nl=np.where(s.sequence_id < 2, s.inflight_volume_nl, np.nan)))
    with pytest.raises(DatasetError, match=r"only 2 distinct .* finite pinchoff_us, inflight_volume_nl"):
        load_dataset(d)


def test_refused_when_no_sequence_usable_for_the_ecm(base, tmp_path):
    d = _edit(base, tmp_path, ts=lambda t: t[t.delay_us != 10.0])
    with pytest.raises(DatasetError, match="no sequence usable for the ECM"):
        load_dataset(d)


def test_lies_are_still_refused(base, tmp_path):
    with pytest.raises(DatasetError, match="look swapped"):
        load_dataset(_edit(base, tmp_path, su=lambda s: s.assign(pinchoff_us=s.pinchoff_us.where(
            s.sequence_id == 0, 300.0))))


def test_design_region_leaves_out_controls_the_fit_dropped(base, tmp_path):
    from identify.design import Region, design

    def su_edit(s):  # the corner (80, 35) has no pinch-off: no polynomial was trained there
        s = s.copy()
        s.loc[s.sequence_id == 15, ["pinchoff_us", "inflight_volume_nl", "grown_volume_at_pinchoff_nl"]] = np.nan
        return s
    rep = fit_hybrid(load_dataset(_edit(base, tmp_path, su=su_edit)), arx=False)
    ctrl = {tuple(c) for c in rep.model.controls}
    assert (80.0, 35.0) not in ctrl and len(ctrl) == len(GRID) - 1
    assert any("training region: 1 (u1, u2)" in n and "(80, 35)" in n for n in rep.notes)
    region = Region(rep.model.controls)
    assert not region.inside(80.0, 35.0)[0] and region.inside(80.0, 30.0)[0]
    assert region.to_dict()["n_controls"] == len(GRID) - 1
    # the largest volume of the full grid lies at the dropped corner: unreachable now
    from identify.hybrid import ExtrapolationWarning

    with pytest.warns(ExtrapolationWarning, match="outside the training region"):  # issue 29 item 5
        target = rep.model.predict(80.0, 35.0)["inflight_volume_nl"]
    d = design(rep.model, target, samples=0)
    assert region.inside(d.u1_um_per_ms, d.u2_um)[0]
    assert (d.u1_um_per_ms, d.u2_um) != pytest.approx((80.0, 35.0), abs=0.5)

"""identify.hybrid: Eq. (8) identified from synthetic data with an exactly known truth."""

import json

import numpy as np
import pytest
from scipy import stats

from identify.dataset import default_physics
from identify.synthetic_dataset import ecm_truth, make_synthetic_dataset
from identify.dataset_checks import load_dataset
from identify.ecm import flow_velocity_m_s
from identify.hybrid import HybridModel, ModelFileError
from identify.hybrid_fit import fit_hybrid

GRID = [(a, b) for a in np.linspace(50, 80, 5) for b in np.linspace(20, 35, 5)]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    d = tmp_path_factory.mktemp("hyb") / "ds"
    make_synthetic_dataset(d, grid=GRID, noise_percent=1.0, seed=7, repeats=2)
    return load_dataset(d)


@pytest.fixture(scope="module")
def report(dataset):
    return fit_hybrid(dataset, arx=False)


def _truth(u1, u2):
    ph = default_physics()
    tp = float(ph.pinchoff_instant_us(u1, u2))
    _, _, vp, qm = ecm_truth(ph, u1, u2, np.arange(0.0, 100.0, 10.0), tp)
    return {
        "pinchoff_us": tp,
        "grown_volume_at_pinchoff_nl": vp,
        "inflight_volume_nl": vp + float(ph.volume_adjuster_nl_at(u1, u2)),
        "jetting_velocity_m_s": float(flow_velocity_m_s(qm, 200.0)) + float(ph.velocity_adjuster_m_s_at(u1, u2)),
    }


def test_held_out_accuracy(report):
    m = report.model
    rng = np.random.default_rng(11)
    for u1, u2 in zip(rng.uniform(52, 78, 12), rng.uniform(21, 34, 12)):  # controls not in the grid
        p, t = m.predict(u1, u2), _truth(u1, u2)
        assert p["inflight_volume_nl"] == pytest.approx(t["inflight_volume_nl"], rel=0.01)
        assert p["jetting_velocity_m_s"] == pytest.approx(t["jetting_velocity_m_s"], rel=0.02)
        assert p["pinchoff_us"] == pytest.approx(t["pinchoff_us"], abs=15)
    g = m.predict_grid([60.0, 70.0], [25.0, 30.0])
    assert g["inflight_volume_nl"].iloc[1] == pytest.approx(m.predict(70.0, 30.0)["inflight_volume_nl"], rel=1e-12)


@pytest.mark.slow
def test_polynomial_laws_recovered_within_intervals(dataset):
    rep = fit_hybrid(dataset, arx=False, orders=[(1, 1)], adjuster_reference="measured")
    laws = {
        "pinchoff": [1050 + 14 * 70 - 10.2 * 25, -14.0, 10.2],
        "volume_adjuster": [0.16, 0.014, 0.0037],  # Eq. (16)
        "velocity_adjuster": [-0.155, 0.0025, 0.0008],  # Eq. (17)
    }
    for name, truth in laws.items():
        fit = getattr(rep.model, name)
        assert fit.terms == [(0, 0), (1, 0), (0, 1)]
        # joint 99 % confidence region of the three coefficients (F distribution); the
        # per-coefficient 95 % interval coverage is checked in test_identify_polynomial.
        d = fit.coefficients - np.asarray(truth)
        stat = d @ np.linalg.solve(fit.covariance, d) / 3
        assert stat <= stats.f.ppf(0.99, 3, fit.dof), (name, fit.to_pandas())
        assert np.all(np.abs(d) <= 2 * fit.ci95), (name, fit.to_pandas())


def test_tables_and_json_roundtrip(report, tmp_path):
    tabs = report.tables()
    for k in ("pinchoff", "volume_adjuster", "velocity_adjuster"):
        assert list(tabs[k].columns) == ["n1", "n2", "n_terms", "train_rmse", "val_rmse", "selected"]
    assert tabs["pinchoff"].loc[tabs["pinchoff"].selected, ["n1", "n2"]].values.tolist() == [[1, 1]]
    m = report.model
    path = m.save(tmp_path / "model.json")
    d = json.loads(path.read_text())
    assert set(d["ecm"]["coefficients"]) == {"A3", "A2", "A1", "A0", "B1", "B0"}
    assert np.asarray(d["ecm"]["coefficient_covariance"]).shape == (6, 6)
    assert d["dead_time_us"] == 220.0 and d["nozzle_area_m2"] == pytest.approx(np.pi * 1e-8)
    assert {"value", "ci95_low", "ci95_high"} <= set(d["ecm"]["parameters"]["Ra"])
    assert "numpy" in d["versions"] and "identify" in d["versions"]
    m2 = HybridModel.from_json(path)
    assert m2.predict(63.0, 27.0) == pytest.approx(m.predict(63.0, 27.0), rel=1e-12)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(ModelFileError, match="bad.json"):
        HybridModel.from_json(tmp_path / "bad.json")


def test_monte_carlo(report):
    m = report.model
    r = m.monte_carlo(70.0, 25.0, samples=4000, seed=1, band=True, band_samples=500)
    s = r.summary()
    nom = m.predict(70.0, 25.0)
    for k, v in s.items():
        assert v["parameters_only_low"] < v["mean"] < v["parameters_only_high"]
        assert v["mean"] == pytest.approx(nom[k], abs=3 * v["std"] / np.sqrt(4000) + 1e-3 * abs(nom[k]))
    # pinch-off polynomial is linear in its coefficients: sample std equals the delta-method std
    assert s["pinchoff_us"]["std"] == pytest.approx(float(m.pinchoff.predict_std(70.0, 25.0)), rel=0.05)
    b = r.band
    assert {"delay_us", "volume_low_nl", "volume_high_nl", "flow_velocity_mean_m_s"} <= set(b.columns)
    assert np.all(b["volume_low_nl"] <= b["volume_high_nl"] + 1e-12)
    one = m.monte_carlo(70.0, 25.0, samples=1)
    assert one.summary()["inflight_volume_nl"]["std"] == 0.0


def test_intervals_stored_and_used(report, tmp_path):
    """Issue 13: model.json keeps the drop scatter (repeats here) and the pinch-off / volume
    cross-covariance; predict gives a confidence and a wider prediction interval; a model
    without ``intervals`` (older file) still loads and predicts."""
    import json

    from identify.hybrid import HybridModel, ModelFileError

    m = report.model
    sc = m.intervals["scatter"]
    for k in ("pinchoff_us", "inflight_volume_nl", "jetting_velocity_m_s"):
        assert sc[k]["source"] == "repeats" and sc[k]["drop_std"] > 0 and sc[k]["dof"] >= 2
    # 1 % noise on ~19 nl and ~1.4 m/s drops
    assert 0.1 < sc["inflight_volume_nl"]["drop_std"] < 0.35
    assert 0.007 < sc["jetting_velocity_m_s"]["drop_std"] < 0.025
    path = m.save(tmp_path / "model.json")
    m2 = HybridModel.from_json(path)
    assert m2.intervals == json.loads(json.dumps(m.intervals))
    iv = m2.interval_prediction(70.0, 25.0, samples=2000, seed=0)
    for k in ("inflight_volume_nl", "jetting_velocity_m_s"):
        e = iv[k]
        assert e["one_drop_low"] < e["mean_drop_low"] < e["mean"] < e["mean_drop_high"] < e["one_drop_high"]
        assert e["mean_drop_std"] > 0
    d = json.loads(path.read_text())
    d.pop("intervals")
    old = HybridModel.from_dict(d)
    e = old.interval_prediction(70.0, 25.0, samples=2000, seed=0)["inflight_volume_nl"]
    assert not e["one_drop_available"] and e["one_drop_low"] == e["mean_drop_low"]
    bad = json.loads(path.read_text())
    bad["intervals"]["scatter"]["inflight_volume_nl"]["drop_std"] = -1
    with pytest.raises(ModelFileError, match="drop_std"):
        HybridModel.from_dict(bad)
    bad = json.loads(path.read_text())
    bad["intervals"]["pinchoff_volume_cross_covariance"] = [[1.0]]
    with pytest.raises(ModelFileError, match="cross_covariance"):
        HybridModel.from_dict(bad)

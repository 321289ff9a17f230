"""The quantiles of `identify.hybrid.HybridModel.interval_prediction`, pinned to tabulated values.

Both the mean-drop (confidence) and the one-drop (prediction) interval use Student's t with the
degrees of freedom of the drop scatter (``intervals.scatter[output].dof``; Welch-Satterthwaite
dof where a stated measurement term, counted as known, adds to the variance), the normal
quantile only when none is stored.  The coverage
study (tests/analysis/test_intervals.py) has dof of 20 or more, where t and the normal quantile differ by
less than its band, so a prediction interval built with the normal quantile (tools/mutants.py
``prediction_t_quantile``) survived it.  References: t(0.975; 4) = 2.776445, t(0.95; 4) =
2.131847, t(0.975; 16) = 2.119905, z(0.975) = 1.959964 (statistical tables).
"""

from __future__ import annotations

import numpy as np
import pytest

from identify.dataset_checks import load_dataset
from identify.hybrid import INTERVAL_OUTPUTS, HybridModel
from identify.hybrid_fit import fit_hybrid
from identify.montecarlo import OUTPUTS, MonteCarloResult
from identify.synthetic_dataset import make_synthetic_dataset

GRID3 = [(a, b) for a in (55.0, 65.0, 75.0) for b in (20.0, 27.5, 35.0)]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    d = tmp_path_factory.mktemp("quantiles") / "ds"
    make_synthetic_dataset(d, grid=GRID3, noise_percent=0.5, seed=3)
    return fit_hybrid(load_dataset(d), arx=False, orders=[(1, 1)]).model


def _intervals(model, scatter, level=0.95, pinchoff_std_us=0.0):
    m = HybridModel.from_dict(model.to_dict())
    m.intervals["scatter"] = {k: dict(scatter) for k in m.intervals["scatter"]}
    m.intervals["measurement"] = {"volume_rel": 0.0, "velocity_rel": 0.0, "pinchoff_std_us": pinchoff_std_us,
                                  "source": "test"}
    nom = m.predict(65.0, 27.5)
    mc = MonteCarloResult(65.0, 27.5, {k: np.full(50, nom[k]) for k in OUTPUTS}, nom)  # no parameter spread
    return m.interval_prediction(65.0, 27.5, mc=mc, level=level)


@pytest.mark.parametrize("level, t4, z", [(0.95, 2.776445, 1.959964), (0.90, 2.131847, 1.644854)])
def test_both_intervals_use_student_t_of_the_scatter_dof(model, level, t4, z):
    iv = _intervals(model, {"drop_std": 0.3, "dof": 4, "model_std": 0.4}, level)
    for k in INTERVAL_OUTPUTS:
        e = iv[k]
        assert e["mean_drop_std"] == pytest.approx(0.4, rel=1e-12) and e["one_drop_std"] == pytest.approx(0.5, rel=1e-12)
        assert (e["mean_drop_high"] - e["mean"]) / 0.4 == pytest.approx(t4, abs=1e-6), k
        assert (e["mean"] - e["mean_drop_low"]) / 0.4 == pytest.approx(t4, abs=1e-6), k
        assert (e["one_drop_high"] - e["mean"]) / 0.5 == pytest.approx(t4, abs=1e-6), k
        assert (e["mean"] - e["one_drop_low"]) / 0.5 == pytest.approx(t4, abs=1e-6), k


def test_one_drop_interval_without_dof_uses_the_normal_quantile(model):
    iv = _intervals(model, {"drop_std": 0.3, "model_std": 0.4})
    for k in INTERVAL_OUTPUTS:
        assert (iv[k]["one_drop_high"] - iv[k]["mean"]) / 0.5 == pytest.approx(1.959964, abs=1e-6)


def test_stated_measurement_term_takes_welch_satterthwaite_dof(model):
    """Pinch-off: model_std 0.4 (dof 4) and a stated measurement std 0.4: the mean-drop variance is
    twice the estimated part, so nu = 4 x 2² = 16; the one-drop one (0.3² + 0.4² estimated, 0.4²
    known) nu = 4 x (0.41/0.25)² = 10.7584; a measurement term far larger gives the normal quantile."""
    from scipy import stats  # the independent reference for the non-tabulated dof

    e = _intervals(model, {"drop_std": 0.3, "dof": 4, "model_std": 0.4}, pinchoff_std_us=0.4)["pinchoff_us"]
    s = np.sqrt(0.32)
    assert e["mean_drop_std"] == pytest.approx(s, rel=1e-12)
    assert (e["mean_drop_high"] - e["mean"]) / s == pytest.approx(2.119905, abs=1e-6)
    assert (e["one_drop_high"] - e["mean"]) / np.sqrt(0.41) == pytest.approx(stats.t.ppf(0.975, 4 * (0.41 / 0.25) ** 2),
                                                                              abs=1e-9)
    e = _intervals(model, {"drop_std": 0.3, "dof": 4, "model_std": 0.4}, pinchoff_std_us=400.0)["pinchoff_us"]
    assert (e["mean_drop_high"] - e["mean"]) / e["mean_drop_std"] == pytest.approx(1.959964, abs=1e-5)

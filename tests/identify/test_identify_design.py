"""identify.design: inverse design inside the printable region."""

import numpy as np
import pytest

from identify.dataset_checks import load_dataset
from identify.synthetic_dataset import make_synthetic_dataset
from identify.design import design
from identify.hybrid_fit import fit_hybrid

GRID = [(a, b) for a in np.linspace(50, 80, 4) for b in np.linspace(20, 35, 4)]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    d = tmp_path_factory.mktemp("des") / "ds"
    make_synthetic_dataset(d, grid=GRID, noise_percent=0.5, seed=2)
    return fit_hybrid(load_dataset(d), arx=False, orders=[(1, 1)]).model


@pytest.mark.slow
def test_volume_and_velocity_target_recovers_controls(model):
    p = model.predict(62.0, 31.0)
    r = design(model, p["inflight_volume_nl"], p["jetting_velocity_m_s"], tolerance_percent=0.2, samples=500)
    assert r.feasible
    assert r.u1_um_per_ms == pytest.approx(62.0, abs=0.5) and r.u2_um == pytest.approx(31.0, abs=0.5)
    assert r.spread["inflight_volume_nl"]["parameters_only_low"] < r.spread["inflight_volume_nl"]["parameters_only_high"]


def test_volume_only(model):
    r = design(model, 18.0, samples=0)
    assert r.feasible and abs(r.error_percent["volume"]) <= 1.0
    assert 50 <= r.u1_um_per_ms <= 80 and 20 <= r.u2_um <= 35
    assert model.predict(r.u1_um_per_ms, r.u2_um)["inflight_volume_nl"] == pytest.approx(18.0, rel=0.01)


def test_infeasible_target(model):
    r = design(model, 500.0, samples=0)
    assert not r.feasible
    assert "infeasible" in r.message and "nearest achievable" in r.message
    # nearest achievable is the largest drop: at the top of the stroke range
    assert r.u2_um == pytest.approx(35.0, abs=0.5)
    with pytest.raises(ValueError, match="^volume_nl must be a positive number"):
        design(model, -1.0)

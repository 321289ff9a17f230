"""identify.tuning: a volume-and-velocity target closes on plants whose laws curve away from the model.

The plants are the model's own laws times smooth quadratic factors (different for the volume and
the velocity: a bias that changes over (u1, u2)); each target is the plant's drop at a setting
inside the region, so a setting meeting both tolerances exists. Before the trust-region step the
loop solved the corrected targets anew over the whole region after each shot and alternated
between far points on such plants (tools/tune_curved.py: 13 of 18 targets met in 5 shots; both
cases below among the misses).
"""

from __future__ import annotations

import numpy as np
import pytest

from identify.dataset_checks import load_dataset
from identify.hybrid_fit import fit_hybrid
from identify.synthetic_dataset import make_synthetic_dataset
from identify.tuning import tune

GRID = [(a, b) for a in np.linspace(50, 80, 4) for b in np.linspace(20, 35, 4)]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    d = tmp_path_factory.mktemp("curved") / "ds"
    make_synthetic_dataset(d, grid=GRID, noise_percent=0.5, seed=2)
    return fit_hybrid(load_dataset(d), arx=False, orders=[(1, 1)]).model


def _plant(model, fv, fw):
    def truth(u1, u2):
        a, b = (u1 - 65.0) / 15.0, (u2 - 27.5) / 7.5
        p = model.predict(u1, u2)
        return p["inflight_volume_nl"] * fv(a, b), p["jetting_velocity_m_s"] * fw(a, b)
    return truth


BOWL = (lambda a, b: 1.06 + 0.08 * a * a - 0.03 * b, lambda a, b: 0.96 + 0.05 * b * b + 0.03 * a)
TILT = (lambda a, b: 1.03 + 0.05 * a + 0.06 * b * b, lambda a, b: 1.02 - 0.03 * b + 0.04 * a * a)


@pytest.mark.parametrize("plant, at", [(BOWL, (53.0, 21.3)), (BOWL, (75.0, 33.0)), (TILT, (58.0, 24.0))])
@pytest.mark.slow
def test_two_output_target_closes_on_a_curved_plant(model, plant, at):
    truth = _plant(model, *plant)
    v, w = truth(*at)
    res = tune(model, lambda u1, u2: truth(u1, u2), v, w, shots=5, samples=200, seed=0)
    df = res.to_pandas()
    assert res.converged, res.message
    assert abs(df.volume_error_percent.iloc[-1]) <= 0.5 and abs(df.velocity_error_percent.iloc[-1]) <= 1.0
    assert abs(df.volume_error_percent.iloc[0]) > 0.5 or abs(df.velocity_error_percent.iloc[0]) > 1.0  # open loop off


def test_noisy_curved_plant_still_closes(model):
    """0.1 % drop-to-drop scatter on both outputs: the loop still closes within the budget."""
    truth = _plant(model, *BOWL)
    rng = np.random.default_rng(1)
    v, w = truth(62.0, 31.0)

    def fire(u1, u2):
        a, b = truth(u1, u2)
        return a * (1 + 0.001 * rng.standard_normal()), b * (1 + 0.001 * rng.standard_normal())

    res = tune(model, fire, v, w, shots=5, samples=200, seed=0)
    assert res.converged, res.message

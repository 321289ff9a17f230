"""Fits at every level of prior knowledge (issue 13 item 2): physical parameters with the full
geometry and ink; ECM coefficients A3..B0 directly with only the nozzle diameter."""

import json

import numpy as np
import pytest

from identify.dataset_checks import load_dataset
from identify.synthetic_dataset import make_synthetic_dataset
from identify.hybrid import HybridModel
from identify.hybrid_fit import fit_hybrid
from identify.physics import drop_history
from identify.dataset import default_physics

#: seconds per test (fitted models, campaigns, subprocesses): left out of `make test-fast`
pytestmark = pytest.mark.slow

GRID = [(float(a), float(b)) for a in (50, 57.5, 65, 72.5, 80) for b in (20, 23.75, 27.5, 31.25, 35)]
HELD_OUT = [(53.0, 21.0), (61.0, 26.0), (68.0, 30.0), (76.0, 33.0), (66.0, 24.0)]


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    root = tmp_path_factory.mktemp("levels")
    make_synthetic_dataset(root / "full", grid=GRID, noise_percent=1.0, seed=2)
    out = {"physical": fit_hybrid(load_dataset(root / "full"), arx=False)}
    for name, strip in (("no_ink", lambda m: m.pop("ink")),
                        ("no_reservoir", lambda m: m["nozzle"].pop("reservoir_channel_radius_um"))):
        d = root / name
        d.mkdir()
        for f in ("timeseries.parquet", "summary.parquet"):
            (d / f).write_bytes((root / "full" / f).read_bytes())
        meta = json.loads((root / "full" / "dataset.json").read_text())
        strip(meta)
        (d / "dataset.json").write_text(json.dumps(meta))
        out[name] = fit_hybrid(load_dataset(d), arx=False)
    return out


def test_level_recorded_in_model_and_notes(fits, tmp_path):
    assert fits["physical"].ecm_fit.level == "physical"
    for name in ("no_ink", "no_reservoir"):
        rep = fits[name]
        assert rep.ecm_fit.level == "coefficients" and rep.ecm_fit.parameters is None
        assert rep.model.ecm_parameters is None
        assert any("ECM level: coefficients" in n and "not identifiable" in n for n in rep.notes)
        d = rep.model.to_dict()
        assert d["ecm"]["level"] == "coefficients" and "not identifiable" in d["ecm"]["parameters_note"]
        back = HybridModel.from_json(rep.model.save(tmp_path / f"{name}.json"))
        assert back.ecm_level == "coefficients" and back.notes == rep.notes
    assert fits["physical"].model.to_dict()["ecm"]["level"] == "physical"
    assert any("ECM level: physical" in n for n in fits["physical"].notes)


def test_older_model_without_level_loads(fits):
    d = fits["physical"].model.to_dict()
    del d["ecm"]["level"], d["notes"]
    m = HybridModel.from_dict(d)
    assert m.ecm_level is None and m.notes is None


def test_bad_level_is_refused(fits):
    from identify.hybrid import ModelFileError
    d = fits["physical"].model.to_dict()
    d["ecm"]["level"] = "guessed"
    with pytest.raises(ModelFileError, match="ecm.level"):
        HybridModel.from_dict(d)


@pytest.mark.parametrize("level", ["physical", "no_ink", "no_reservoir"])
def test_held_out_predictions_at_each_level(fits, level):
    ph = default_physics()
    m = fits[level].model
    for u1, u2 in HELD_OUT:
        p = m.predict(u1, u2)
        h = drop_history(ph, u1, u2)
        assert p["inflight_volume_nl"] == pytest.approx(h.inflight_volume_nl, rel=0.01)
        assert p["jetting_velocity_m_s"] == pytest.approx(h.jetting_velocity_m_s, rel=0.02)


def test_levels_agree(fits):
    a = fits["physical"].model.predict_grid(*np.array(HELD_OUT).T)
    for name in ("no_ink", "no_reservoir"):
        b = fits[name].model.predict_grid(*np.array(HELD_OUT).T)
        np.testing.assert_allclose(b["inflight_volume_nl"], a["inflight_volume_nl"], rtol=0.005)
        np.testing.assert_allclose(b["jetting_velocity_m_s"], a["jetting_velocity_m_s"], rtol=0.01)
        np.testing.assert_allclose(b["pinchoff_us"], a["pinchoff_us"], rtol=1e-9)

"""`identify` console script end to end on a small synthetic dataset."""

import json

import numpy as np
import pytest

from identify.app.cli import main
from identify.synthetic_dataset import make_synthetic_dataset

GRID = [(a, b) for a in np.linspace(50, 80, 4) for b in np.linspace(20, 35, 4)]
KEYS = {"pinchoff_us", "grown_volume_at_pinchoff_nl", "inflight_volume_nl", "jetting_velocity_m_s"}


def _bare_low_high(doc, path="") -> list:
    """Paths of every bare "low"/"high" key in a JSON document (issue 19 item 5: none allowed)."""
    if isinstance(doc, dict):
        return [f"{path}.{k}" for k in doc if k in ("low", "high")] + \
            [p for k, v in doc.items() for p in _bare_low_high(v, f"{path}.{k}")]
    if isinstance(doc, list):
        return [p for i, v in enumerate(doc) for p in _bare_low_high(v, f"{path}[{i}]")]
    return []


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    make_synthetic_dataset(root / "ds", grid=GRID, noise_percent=0.5, seed=4)
    return root


@pytest.mark.slow
def test_fit_predict_design(fitted, capsys):
    model = fitted / "model.json"
    assert main(["fit", str(fitted / "ds"), "--out", str(model), "--folds", "5"]) == 0
    out = capsys.readouterr().out
    assert "10-fold CV" in out and "val_rmse" in out and "ARX" in out and "wrote" in out
    d = json.loads(model.read_text())
    assert d["arx_structure"] is not None and set(d["arx_structure"]) == {"na", "nb", "nk"}
    assert main(["predict", str(model), "--u1", "70", "--u2", "25", "--samples", "2000", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert KEYS <= set(res)
    assert isinstance(res["pinchoff_us"], float) and isinstance(res["grown_volume_at_pinchoff_nl"], float)
    for k in ("inflight_volume_nl", "jetting_velocity_m_s", "pinchoff_us_mc", "grown_volume_at_pinchoff_mc_nl"):
        v = res[k]
        assert {"mean", "std", "parameters_only_low", "parameters_only_high"} <= set(v) and v["parameters_only_low"] <= v["mean"] <= v["parameters_only_high"]
    assert res["pinchoff_us_mc"]["parameters_only_low"] <= res["pinchoff_us"] <= res["pinchoff_us_mc"]["parameters_only_high"]
    assert 15 < res["inflight_volume_nl"]["mean"] < 23
    # issue 19 item 5: every interval named for what it covers, no bare low/high anywhere in the JSON
    assert not _bare_low_high(res), _bare_low_high(res)
    for k in ("inflight_volume_nl", "jetting_velocity_m_s", "pinchoff_us_intervals"):
        v = res[k]
        assert v["parameters_only_low"] < v["mean"] < v["parameters_only_high"]
        assert v["mean_drop_std"] >= v["parameter_std"] > 0
        assert v["mean_drop_dominant_term"] in ("parameters", "model_discrepancy", "measurement")
        assert v["one_drop_dominant_term"] in ("parameters", "model_discrepancy", "measurement", "drop_scatter")
        assert sum(v["variance_shares"].values()) == pytest.approx(1.0)
    # issue 13: two intervals, named, with their level; prediction wider than confidence, none degenerate
    assert res["level"] == 0.95 and "prediction" in res["interval_note"]
    for k in ("inflight_volume_nl", "jetting_velocity_m_s", "pinchoff_us_intervals"):
        v = res[k]
        assert v["one_drop_available"] and v["level"] == 0.95
        assert v["one_drop_low"] < v["mean_drop_low"] < v["mean"] < v["mean_drop_high"] < v["one_drop_high"]
        assert v["mean_drop_high"] - v["mean_drop_low"] > 1e-4 * abs(v["mean"])
    assert main(["predict", str(model), "--u1", "70", "--u2", "25", "--samples", "500"]) == 0
    text = capsys.readouterr().out
    assert "mean drop 95 % (confidence)" in text and "one drop 95 % (prediction)" in text
    assert main(["predict", str(model), "--u1", "70", "--u2", "25", "--samples", "500"]) == 0
    assert "inflight_volume_nl" in capsys.readouterr().out
    assert main(["design", str(model), "--volume-nl", str(res["inflight_volume_nl"]["mean"]), "--samples", "200", "--json"]) == 0
    des = json.loads(capsys.readouterr().out)
    assert not _bare_low_high(des), _bare_low_high(des)
    assert des["feasible"] and abs(des["error_percent"]["volume"]) < 1
    assert main(["design", str(model), "--volume-nl", "900"]) == 1
    assert "infeasible" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, match",
    [
        (["fit", "/nonexistent/ds", "--out", "x.json"], "dataset folder not found"),
        (["predict", "/nonexistent/model.json", "--u1", "70", "--u2", "25"], "model file not found"),
        (["predict", "m.json", "--u1", "-70", "--u2", "25"], "--u1 must be > 0"),
        (["design", "m.json"], "--volume-nl"),
    ],
)
def test_bad_input_exit_2(argv, match, capsys):
    with pytest.raises(SystemExit) if "-70" in argv else _nullcontext() as exc:
        code = main(argv)
    if exc is not None and hasattr(exc, "value"):
        code = exc.value.code
    assert code == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1


class _nullcontext:
    def __enter__(self):
        return None

    def __exit__(self, *a):
        return False


def test_paper_command(capsys):
    pytest.importorskip("identify.paper")
    assert main(["paper", "--u1", "70", "--u2", "25", "--samples", "2000", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res) == KEYS | {"estimate"} and res["estimate"] == "expectation"
    assert not _bare_low_high(res), _bare_low_high(res)
    assert main(["paper", "--u1", "70", "--u2", "25", "--scheme-draw", "--samples", "2000", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["estimate"] == "scheme_draw"


def test_paper_command_text_output(capsys):
    assert main(["paper", "--u1", "70", "--u2", "25", "--samples", "2000"]) == 0
    out = capsys.readouterr().out
    assert "pinchoff_us" in out and "inflight_volume_nl" in out and "note:" in out
    assert "estimate: EXPECTATION" in out
    assert main(["paper", "--u1", "70", "--u2", "25", "--samples", "2000", "--scheme-draw"]) == 0
    assert "estimate: ONE draw of the paper's Monte Carlo scheme" in capsys.readouterr().out


@pytest.mark.slow
def test_fit_and_predict_write_rerun_recordings(fitted, tmp_path, capsys):
    from rrdtools import Rrd

    model = tmp_path / "model.json"
    rrd_fit, rrd_pred = tmp_path / "fit.rrd", tmp_path / "pred.rrd"
    assert main(["fit", str(fitted / "ds"), "--out", str(model), "--folds", "4", "--rerun", str(rrd_fit)]) == 0
    assert main(["predict", str(model), "--u1", "70", "--u2", "25", "--samples", "500", "--rerun", str(rrd_pred)]) == 0
    capsys.readouterr()
    fit = Rrd(rrd_fit)
    measured = [e for e in fit.entities() if e.startswith("/identify/volume_nl/") and e.endswith("/measured")]
    simulated = [e for e in fit.entities() if e.startswith("/identify/volume_nl/") and e.endswith("/simulated")]
    assert len(measured) == len(simulated) == len(GRID)
    assert "/identify/cv/table" in fit.entities()
    # measured values logged are the dataset's grown volumes (first sequence, first attached delays)
    vals = fit.series(sorted(measured)[0], "Scalars:scalars")["value"].map(lambda v: v[0]).to_numpy()
    assert np.all(np.isfinite(vals)) and vals.max() > 5
    pred = Rrd(rrd_pred)
    band = {e for e in pred.entities() if e.startswith("/identify/monte_carlo/")}
    assert any(e.endswith("/low") for e in band) and any(e.endswith("/high") for e in band)
    lo = pred.series(sorted(e for e in band if "volume_nl" in e and e.endswith("/low"))[0], "Scalars:scalars")
    hi = pred.series(sorted(e for e in band if "volume_nl" in e and e.endswith("/high"))[0], "Scalars:scalars")
    assert np.all(np.concatenate(hi["value"]) >= np.concatenate(lo["value"]) - 1e-12)


@pytest.mark.slow
def test_fit_searches_the_whole_structure_grid(fitted):
    """Structure selection covers na 1-7, nb 1-4, nk 0..40 (the issue's grid), not a prior."""
    from identify.dataset_checks import load_dataset
    from identify.hybrid_fit import fit_hybrid

    rep = fit_hybrid(load_dataset(fitted / "ds"), folds=4)
    t = rep.arx_selection.table
    assert set(t.na) == set(range(1, 8)) and set(t.nb) == set(range(1, 5))
    assert t.nk.min() == 0 and t.nk.max() >= 40
    na, nb, nk = rep.arx_selection.selected
    assert 21 <= nk <= 24  # the 220 us dead time at 10 us (MATLAB convention: 22 or 23)
